"""A project of 1,024 small files, run whole, then again after one file changed.

    .venv/bin/python benchmarks/bench_project.py [--workdir /tmp/bench_project] [--side 1600] [--files 32]

The survey is the synthetic scene of :mod:`tests.synthetic` (1 pulse/m2,
``side`` x ``side`` metres), cut into ``files`` x ``files`` delivered tiles
(LAZ, one per square cell: 1,024 files of 50 m, about 2,700 points each by
default).  The job is the LAS job's defaults (noise, SMRF, TIN DTM, LAZ
export) with 200 m processing tiles, without the map products.  Three runs,
each a whole ``pipeline run`` process:

1. ``full``: every file, on an empty cache;
2. ``incremental``: one file in the middle changed (its heights raised
   0.5 m), on the first run's cache;
3. ``scratch``: the same files as 2, on an empty cache.

Printed: each run's wall seconds, the stages' seconds and, for the tiled
stages, the tiles run and reused; whether 2's products equal 3's, byte for
byte (SHA-256 in run.json); the machine's load.  Markdown rows for
docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from tests.synthetic import make_scene, write_scene_las  # noqa: E402

TILED = ("denoise", "classify_ground", "rasterize")


def make_files(work: Path, side: float, files: int) -> list[Path]:
    """The scene cut into files x files LAZ files under ``work/files``; their paths, row by row."""
    folder = work / "files"
    if folder.exists() and len(list(folder.glob("*.laz"))) == files * files:
        return sorted(folder.glob("*.laz"))
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    whole = work / "survey.laz"
    write_scene_las(make_scene(width=side, height=side, density=1.0, n_trees=int(side * side / 4000)), whole)
    las = laspy.read(whole)
    x, y = np.asarray(las.x), np.asarray(las.y)
    cell = side / files
    col = np.clip(((x - x.min()) // cell).astype(int), 0, files - 1)
    row = np.clip(((y - y.min()) // cell).astype(int), 0, files - 1)
    paths = []
    for r in range(files):
        for c in range(files):
            part = laspy.LasData(las.header)
            part.points = las.points[(row == r) & (col == c)]
            paths.append(folder / f"tile_{r:02d}_{c:02d}.laz")
            part.write(paths[-1])
    whole.unlink()
    return paths


def config(work: Path, paths: list[Path], name: str, cache: str) -> Path:
    path = work / f"{name}.yaml"
    path.write_text(
        "input: {format: las, paths: [" + ", ".join(str(p) for p in paths) + "]}\n"
        f"output: {work / name}\ncache: {work / cache}\n"
        "tiling: {size: 200}\n"
        "stages:\n  strip_adjust: {enabled: false}\n  hillshade: {enabled: false}\n"
        "  contours: {enabled: false}\n  report: {enabled: false}\n  export_las: {compress: true}\n"
    )
    return path


def run(work: Path, paths: list[Path], name: str, cache: str) -> tuple[float, dict]:
    cfg = config(work, paths, name, cache)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pipeline", "run", str(cfg), "-q"], cwd=ROOT)
    seconds = time.perf_counter() - t0
    if done.returncode != 0:
        raise SystemExit(f"{name}: exit {done.returncode}")
    return seconds, json.loads((work / name / "run.json").read_text())


def change(path: Path) -> None:
    las = laspy.read(path)
    las.z = np.asarray(las.z) + 0.5
    las.write(path)


def row(name: str, seconds: float, manifest: dict) -> str:
    stages = {s["name"]: s for s in manifest["stages"]}
    cells = []
    for stage in ("parse", *TILED, "export_las"):
        s = stages[stage]
        t = s.get("metrics", {}).get("tiling")
        tiles = f" ({t['ran']} run, {t['reused']} reused)" if t and "ran" in t else ""
        cells.append(f"{s.get('seconds') or 0:.1f}{tiles}")
    return f"| {name} | {seconds:.1f} | " + " | ".join(cells) + f" | {os.getloadavg()[0]:.1f} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/bench_project"))
    parser.add_argument("--side", type=float, default=1600.0)
    parser.add_argument("--files", type=int, default=32)
    args = parser.parse_args()
    work = args.workdir
    work.mkdir(parents=True, exist_ok=True)
    for old in ("full", "incremental", "scratch", "cache", "cache-scratch"):
        shutil.rmtree(work / old, ignore_errors=True)
    paths = make_files(work, args.side, args.files)
    points = sum(int(__import__("laspy").open(p).header.point_count) for p in paths)
    print(f"{len(paths)} files, {points:,} points; machine: {os.cpu_count()} cores; {time.strftime('%Y-%m-%d %H:%M')}")
    print("| run | wall s | parse s | denoise s | classify_ground s | rasterize s | export_las s | load |")
    print("|---|---|---|---|---|---|---|---|")
    full = run(work, paths, "full", "cache")
    print(row("full (empty cache)", *full), flush=True)
    changed = paths[len(paths) // 2 + args.files // 2]
    change(changed)
    again = run(work, paths, "incremental", "cache")
    print(row(f"incremental ({changed.name} changed)", *again), flush=True)
    scratch = run(work, paths, "scratch", "cache-scratch")
    print(row("from scratch (same files)", *scratch), flush=True)
    a = {n: p["sha256"] for n, p in again[1]["products"].items()}
    b = {n: p["sha256"] for n, p in scratch[1]["products"].items()}
    print(f"products of the incremental run equal the run from scratch: {a == b} ({len(a)} products)")


if __name__ == "__main__":
    main()
