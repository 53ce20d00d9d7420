"""Prove that two commits make the same products, byte for byte.

    python scripts/same_products.py OLD NEW [--jobs NAME ...] [--keep DIR]

Each commit is checked out into a temporary worktree and runs every job below
from it (``PYTHONPATH`` set to that tree, the plugin named by its own
``pyproject.toml``), each job with a fresh output and cache folder.  Every
product file is then compared by SHA-256; ``run.json`` is left aside (it holds
times and the code's version).  Exit 0 when every product of every job is
identical, 1 otherwise, with one line per difference.

The jobs: the four shipped configurations, the NMEA flight with the mounting
calibration, the LAS sample cut in 200 m tiles, the LAS sample with each run
mode of the one-grid stages forced (the grid in windows, tiles of points),
three real files of ``../shared/data/real/`` (with the COPC output and DTM
tiles switched on for one, so that those writers are compared too) and a
real project of four files.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import re
import shutil
import subprocess
import sys
import tempfile
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.shared_data import REAL  # noqa: E402

#: job name -> (configuration relative to the tree, --set overrides)
JOBS: dict[str, tuple[str, list[str]]] = {
    "flight": ("configs/flight.yaml", []),
    "flight_nmea": ("configs/flight_nmea.yaml", []),
    "flight_sbet": ("configs/flight_sbet.yaml", []),
    "las": ("configs/las.yaml", []),
    "flight_mounting": ("configs/flight_nmea.yaml", ["stages.strip_adjust.model=mounting"]),
    "las_tiled": (
        "configs/las.yaml",
        ["tiling.size=200", "stages.classify_ground.one_grid_cells=0", "stages.export_las.copc=true"],
    ),
    "autzen": (
        "configs/las.yaml",
        [
            f"input.paths=[{REAL / 'pdal' / 'autzen_trim.las'}]",
            "stages.accuracy.enabled=false",
            "stages.export_las.copc=true",
            "stages.export_tiles.tile_size=500",
        ],
    ),
    "topography": (
        "configs/las.yaml",
        [f"input.paths=[{REAL / 'lidR' / 'Topography.laz'}]", "stages.accuracy.enabled=false"],
    ),
    "sample_c": (
        "configs/las.yaml",
        [f"input.paths=[{REAL / 'pdal' / 'sample_c.las'}]", "input.crs=EPSG:2994", "stages.accuracy.enabled=false"],
    ),
    # the run modes of the one-grid stages, forced on the LAS sample (a 385 x 512 grid of 1 m cells for the
    # ground, 192 x 256 of 2 m for the objects) cut in 100 m tiles: the grid in the tiles' windows on the
    # workers (caps under the grid, within 4 times it), and tiles of points (caps 0); "las" is the whole grid
    "las_windows": (
        "configs/las.yaml",
        [
            "tiling.size=100",
            "stages.classify_ground.one_grid_cells=100000",
            "stages.classify_objects.one_grid_cells=20000",
        ],
    ),
    "las_points": (
        "configs/las.yaml",
        ["tiling.size=100", "stages.classify_ground.one_grid_cells=0", "stages.classify_objects.one_grid_cells=0"],
    ),
    # a project of four files, 2.8 M points: the one-grid stages write their classes on the workers
    "bcts": (
        "configs/las.yaml",
        [
            "input.paths=[" + ",".join(str(REAL / "lasR" / f"bcts_{i}.laz") for i in range(1, 5)) + "]",
            "stages.accuracy.enabled=false",
        ],
    ),
}

SKIP = {"run.json"}
MADE = re.compile(rb"made \d{4}-\d\d-\d\d \d\d:\d\d UTC")


def plugin_spec(tree: Path) -> str:
    """The ``module:attr`` of the tree's ``pipeline.plugins`` entry point."""
    with open(tree / "pyproject.toml", "rb") as fh:
        project = tomllib.load(fh)
    (spec,) = project["project"]["entry-points"]["pipeline.plugins"].values()
    return spec


def run_jobs(tree: Path, dest: Path, jobs: list[str]) -> None:
    """Run every job from *tree*, products under ``dest/<job>/``.

    Both commits run from the same tree and output paths, so that the paths
    the products quote (the input files in the report and ``qc/debug.txt``)
    are the same.
    """
    env = dict(os.environ, PYTHONPATH=str(tree), PIPELINE_PLUGIN=plugin_spec(tree))
    for job in jobs:
        config, sets = JOBS[job]
        out, cache = dest / job, dest / f".cache-{job}"
        cmd = [sys.executable, "-m", "pipeline", "run", str(tree / config), "-q"]
        for s in [*sets, f"output={out}", f"cache={cache}"]:
            cmd += ["--set", s]
        proc = subprocess.run(cmd, env=env, cwd=tree, capture_output=True, text=True)
        if proc.returncode != 0:
            sys.exit(f"{tree.name}: job {job} failed (exit {proc.returncode}): {proc.stderr.strip()[-2000:]}")
        print(f"{tree.name}: {job} done", flush=True)


def digests(folder: Path) -> dict[str, str]:
    """Relative path -> SHA-256 of every product file in *folder*.

    The report's "made <date> <time> UTC" is the one figure that changes from
    run to run; it is masked before hashing.
    """
    out = {}
    for path in sorted(folder.rglob("*")):
        rel = path.relative_to(folder).as_posix()
        if path.is_file() and path.name not in SKIP and not rel.startswith("."):
            data = path.read_bytes()
            if path.suffix == ".html":
                data = MADE.sub(b"made (masked) UTC", data)
            out[rel] = hashlib.sha256(data).hexdigest()
    return out


def checkout(commit: str, where: Path) -> Path:
    """*commit* checked out at ``where/tree``: a detached worktree, or for
    ``WORKTREE`` a copy of the files git tracks or would track, as they are."""
    tree = where / "tree"
    if commit != "WORKTREE":
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), commit], cwd=ROOT, check=True)
        return tree
    files = subprocess.run(
        ["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
        cwd=ROOT,
        capture_output=True,
        check=True,
    ).stdout.split(b"\0")
    for name in filter(None, files):
        src = ROOT / os.fsdecode(name)
        if src.is_file():
            (tree / src.relative_to(ROOT)).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, tree / src.relative_to(ROOT))
    return tree


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("old", help="a commit, or WORKTREE for the files as they are")
    ap.add_argument("new", help="a commit, or WORKTREE for the files as they are")
    ap.add_argument("--jobs", nargs="+", choices=list(JOBS), default=list(JOBS))
    ap.add_argument("--keep", type=Path, help="keep the products in this folder")
    args = ap.parse_args(argv)
    work = Path(args.keep or tempfile.mkdtemp(prefix="same-products-"))
    work.mkdir(parents=True, exist_ok=True)
    try:
        results = []
        for label, commit in (("old", args.old), ("new", args.new)):
            tree = checkout(commit, work)
            run_jobs(tree, work / "run", args.jobs)
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, capture_output=True)
            shutil.rmtree(tree, ignore_errors=True)
            shutil.rmtree(work / label, ignore_errors=True)
            (work / "run").rename(work / label)
            results.append({job: digests(work / label / job) for job in args.jobs})
        differences = 0
        for job in args.jobs:
            old, new = results[0][job], results[1][job]
            for name in sorted(set(old) | set(new)):
                if old.get(name) != new.get(name):
                    differences += 1
                    state = "only in old" if name not in new else "only in new" if name not in old else "differs"
                    print(f"{job}/{name}: {state}")
            print(f"{job}: {len(old)} products, {sum(old.get(n) == new.get(n) for n in old)} identical")
        print("identical" if differences == 0 else f"{differences} products differ")
        return 0 if differences == 0 else 1
    finally:
        subprocess.run(["git", "worktree", "prune"], cwd=ROOT, capture_output=True)
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
