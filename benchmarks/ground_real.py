"""Ground classification on the shared real and ISPRS files: scores and the DTM check (issue 16).

For each file, the run's own ``denoise`` + ``classify_ground`` (through
``commands.evaluate.command.evaluate_ground``, stage defaults) classify the points;
then, against the provider's ground (class 2):

- Type I / Type II / total error / kappa (per cent), as ``pipeline evaluate ground``;
- the DTM check of ``pipeline evaluate ground`` (``commands.evaluate.scores.dtm_check``):
  the pipeline's TIN of our ground points and of the provider's on the same
  1 m cells, compared where both are defined and the reference is dense
  (triangle edges up to 20 m): RMS of (ours - provider), % of cells more
  than 0.5 m and 2 m above it, and the largest difference above.  Metres (a
  survey in feet is converted).

Run from the repository root (paths are relative to it)::

    python benchmarks/ground_real.py [--json OUT.json] [FILE ...]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import laspy
import numpy as np
from pyproj import CRS

from commands.evaluate.command import evaluate_ground, reference_ground
from commands.evaluate.scores import dtm_check as check
from lidar import glossary
from lidar.clouds import cloud_crs
from lidar.units import Units

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
from tests.shared_data import DATA as SHARED  # noqa: E402

#: File -> CRS to give it (None: its header's).
FILES = {
    "real/lidR/Megaplot.laz": None,
    "real/lidR/MixedConifer.laz": None,
    "real/lidR/Topography.laz": None,
    "real/pdal/autzen_trim.las": None,
    "real/pdal/sample_c.las": "EPSG:2994",
    "isprs/samp11.laz": None,
    "isprs/samp31.laz": None,
    "isprs/samp51.laz": None,
}


def dtm_check(xyz: np.ndarray, ours: np.ndarray, reference: np.ndarray, cell: float = 1.0) -> dict:
    """The DTM check of ``pipeline evaluate ground`` (:func:`commands.evaluate.scores.dtm_check`) as table columns."""
    c = check(xyz, reference, ours, cell=cell)
    if not c.n:
        return {"cells": 0}
    return {
        "cells": c.n,
        "rms_m": round(c.rms, 3),
        "above_0_5_pct": round(100.0 * c.above_0_5, 2),
        "above_2_pct": round(100.0 * c.above_2, 2),
        "max_m": round(c.max_above, 2),
    }


def coordinates(path: Path, crs: str | None) -> np.ndarray:
    """The file's coordinates in metres (its header's CRS units, or *crs*'s)."""
    with laspy.open(str(path)) as reader:
        found = CRS.from_user_input(crs) if crs else cloud_crs(reader)
        las = reader.read()
    xyz = np.column_stack((np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)))
    return Units.of(found).to_metres(xyz) if found is not None else xyz


def measure(path: Path, crs: str | None) -> dict:
    """Scores and DTM check of the run's default classification of *path*."""
    start = time.perf_counter()
    rows, classes = evaluate_ground(path, crs=crs)
    seconds = time.perf_counter() - start
    row = rows[0]
    ours = next(iter(classes.values())) == glossary.GROUND
    out = {
        "file": str(path.relative_to(SHARED)),
        "points": row["n"],
        "type_1": round(100 * row["type_1"], 2),
        "type_2": round(100 * row["type_2"], 2),
        "total": round(100 * row["total"], 2),
        "kappa": round(100 * row["kappa"], 1),
        "seconds": round(seconds, 1),
    }
    out.update(dtm_check(coordinates(path, crs), ours, reference_ground(path)))
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", help="files under ../shared/data (default: all of FILES)")
    parser.add_argument("--json", type=Path, help="also write the figures here")
    args = parser.parse_args(argv)
    names = args.files or list(FILES)
    results = []
    for name in names:
        path = SHARED / name
        if not path.exists():
            print(f"{path}: not found, skipped", file=sys.stderr)
            continue
        r = measure(path, FILES.get(name))
        results.append(r)
        dtm = (
            f"DTM RMS {r['rms_m']:.3f} m, >0.5 m {r['above_0_5_pct']:.2f} %, >2 m {r['above_2_pct']:.2f} %, "
            f"max {r['max_m']:+.2f} m"
            if r.get("cells")
            else "no DTM check"
        )
        print(
            f"{r['file']:<28} T1 {r['type_1']:6.2f}  T2 {r['type_2']:6.2f}  total {r['total']:6.2f}  "
            f"kappa {r['kappa']:5.1f}  | {dtm}  ({r['seconds']} s)",
            flush=True,
        )
    isprs = [r["total"] for r in results if r["file"].startswith("isprs/")]
    if len(isprs) == 3:
        print(f"ISPRS mean total error {np.mean(isprs):.2f} %")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
