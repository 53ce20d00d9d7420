"""Run the LAS job on every real file in ``../shared/data/real/`` and print a table.

For each file: points, exit code, seconds, DTM cells, ground share, bridge-deck
points (class 17), building points (6) and the first
line the run printed on failure (or its warnings).  The job is
``configs/las.yaml`` pointed at the file, with the per-file keys of
``OVERRIDES`` (the two files whose header CRS is unusable need one).  Used for
issue 22's before/after table; the test ``tests/stages/parse/test_real_files.py``
asserts the outcomes.

    python benchmarks/real_files.py [--timeout 120] [--only NAME ...] [--md]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np
import rasterio

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.shared_data import REAL  # noqa: E402

#: Keys a user needs on the command line for a file (the way out its message names).
OVERRIDES: dict[str, list[str]] = {
    "lone-star.laz": ["input.override_crs=EPSG:26912"],
    "warsaw_small.las": ["input.override_crs=EPSG:2180"],
    "sample_c.las": ["input.crs=EPSG:2994"],
    "1.2-with-color.las": ["input.crs=EPSG:2992"],
}


def run_file(path: Path, work: Path, timeout: float, extra: list[str] | None = None) -> dict:
    """Run the LAS job on one file; return what a table row needs."""
    out, cache = work / "out", work / "cache"
    sets = [
        f"input.paths=[{path}]",
        f"output={out}",
        f"cache={cache}",
        "stages.accuracy.enabled=false",
        *(OVERRIDES.get(path.name, []) if extra is None else extra),
    ]
    cmd = [sys.executable, "-m", "pipeline", "run", str(ROOT / "configs" / "las.yaml"), "-q"]
    for s in sets:
        cmd += ["--set", s]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        code, err = proc.returncode, (proc.stderr.strip().splitlines() or [""])
    except subprocess.TimeoutExpired:
        code, err = None, [f"stopped after {timeout:.0f} s"]
    seconds = time.perf_counter() - t0
    row = {
        "file": f"{path.parent.name}/{path.name}",
        "exit": code,
        "seconds": round(seconds, 1),
        "message": err[-1][:160],
    }
    try:
        row["points"] = int(laspy.open(path).header.point_count)
    except Exception as exc:  # the file's own problem is what the run's message reports
        row["points"] = f"unreadable ({type(exc).__name__})"
    dtm = out / "dtm.tif"
    if code == 0 and dtm.exists():
        with rasterio.open(dtm) as src:
            a = src.read(1, masked=True)
            row["dtm_cells"] = f"{src.width} x {src.height}"
            row["dtm_valid"] = int(a.count())
        las = out / "points.laz"
        if las.exists():
            cls = laspy.read(las).classification
            row["ground_pct"] = round(100 * float(np.mean(np.asarray(cls) == 2)), 1)
            row["deck_points"] = int(np.sum(np.asarray(cls) == 17))  # bridge decks found (no shared file has one)
            row["building_points"] = int(np.sum(np.asarray(cls) == 6))
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--timeout", type=float, default=120.0)
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--md", action="store_true", help="print a Markdown table")
    ap.add_argument("--no-overrides", action="store_true", help="run every file with no per-file keys")
    args = ap.parse_args(argv)
    files = sorted(p for p in REAL.rglob("*") if p.suffix.lower() in (".las", ".laz"))
    if args.only:
        files = [p for p in files if p.name in args.only]
    rows = []
    for p in files:
        with tempfile.TemporaryDirectory(prefix="realfile-") as tmp:
            rows.append(run_file(p, Path(tmp), args.timeout, [] if args.no_overrides else None))
        r = rows[-1]
        if not args.md:
            print(json.dumps(r), flush=True)
    if args.md:
        print("| file | points | exit | s | DTM cells | ground % | message |")
        print("|---|---|---|---|---|---|---|")
        for r in rows:
            print(
                f"| {r['file']} | {r['points']} | {r['exit']} | {r['seconds']} | {r.get('dtm_cells', '—')} "
                f"| {r.get('ground_pct', '—')} | {r['message'] if r['exit'] != 0 else ''} |"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
