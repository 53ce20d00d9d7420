"""SMRF, CSF and their consensus (AND, OR of the ground points) on the shared files (issue 16).

Each file is classified by the run's stages (``commands.evaluate.command.evaluate_ground``:
noise step, then SMRF and CSF with their defaults, CSF with each class
threshold asked for); the two ground masks are combined, and each
combination is scored against the provider's ground (total error, Type I,
Type II, per cent) with the DTM check (RMS m, % of cells more than 2 m
above the provider's ground).  ``veto<t>``: SMRF's ground less the points
CSF rejects where the slope of SMRF's ground surface (2 m cells) is under
*t* (t = 0.05, 0.1, 0.2, 0.3).  Results in docs/GROUND.md ("Tried for issue
16 and not kept").  Run from the repository root::

    python benchmarks/ground_consensus.py [--threshold 0.5] [--threshold 2] [FILE ...]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from commands.evaluate.command import evaluate_ground, reference_ground
from commands.evaluate.scores import dtm_check, score
from lidar import glossary
from stages.classify_ground.csf import CsfParams
from stages.classify_ground.smrf import SmrfParams
from stages.classify_ground.surface import index_points, inpaint, min_grid, slope_grid

sys.path.insert(0, str(Path(__file__).resolve().parent))

from ground_real import FILES, SHARED, coordinates  # noqa: E402


def flat_slope(xyz: np.ndarray, ground: np.ndarray, cell: float = 2.0) -> np.ndarray:
    """At each point, the slope of the surface of the lowest *ground* point per cell (inpainted)."""

    idx = index_points(xyz[:, :2], cell)
    lowest = min_grid(np.where(ground, xyz[:, 2], np.inf), idx)  # cells without ground: NaN
    return slope_grid(inpaint(lowest), cell)[idx.row, idx.col]


def measure(name: str, crs: str | None, threshold: float) -> dict[str, tuple]:
    """Scores of SMRF, CSF, AND and OR on one file: {label: (total, type 1, type 2, DTM RMS, % > 2 m)}."""

    path = SHARED / name
    algorithms = [SmrfParams(name="smrf"), CsfParams(name="csf", class_threshold=threshold)]
    _, classes = evaluate_ground(path, algorithms, crs=crs, dtm=False)
    reference, xyz = reference_ground(path), coordinates(path, crs)
    smrf, csf = classes["smrf"] == glossary.GROUND, classes["csf"] == glossary.GROUND
    out = {}
    slope = flat_slope(xyz, smrf)
    variants = [("smrf", smrf), ("csf", csf), ("and", smrf & csf), ("or", smrf | csf)]
    variants += [(f"veto{t}", smrf & ~(~csf & (slope < t))) for t in (0.05, 0.1, 0.2, 0.3)]
    for label, ground in variants:
        s, d = score(reference, ground), dtm_check(xyz, reference, ground)
        dtm = (round(d.rms, 3), round(100 * d.above_2, 2)) if d.n else (None, None)
        out[label] = (round(100 * s.total, 2), round(100 * s.type_1, 2), round(100 * s.type_2, 2), *dtm)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", nargs="*", help="files under ../shared/data (default: those of ground_real.py)")
    parser.add_argument("--threshold", type=float, action="append", help="CSF class threshold, m (default 0.5)")
    args = parser.parse_args()
    names = args.files or list(FILES)
    for threshold in args.threshold or [0.5]:
        print(f"CSF class threshold {threshold} m: (total, type I, type II, DTM RMS m, % > 2 m)")
        totals: dict[str, list[float]] = {}
        for name in names:
            row = measure(name, FILES.get(name), threshold)
            print(f"  {name:<28} " + "  ".join(f"{k} {v}" for k, v in row.items()), flush=True)
            if name.startswith("isprs/"):
                for k, v in row.items():
                    totals.setdefault(k, []).append(v[0])
        for k, v in totals.items():
            print(f"  ISPRS mean total error, {k}: {np.mean(v):.2f} %")


if __name__ == "__main__":  # the runs start worker processes (spawn): they import this module
    main()
