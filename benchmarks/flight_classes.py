"""The main job's classes against the simulator's class of every echo: recall and precision per class.

The sample flight is simulated, so each echo's true class is known: the
simulator writes it to ``truth/points.laz`` (the echo's exact position,
class, GPS time, scan angle, channel and return number), which the sample
in ``data_samples/`` leaves out.  This script regenerates the sample in a
temporary folder (same seed, same bytes) and matches each output point of
``configs/flight.yaml`` to its echo by GPS time, scan angle, channel and
return number (one echo each), then scores buildings (6), bridge decks
(17), ground (2 and 20) and water (9).

Run from the repository root after ``pipeline run configs/flight.yaml``::

    python benchmarks/flight_classes.py [--out out/flight-ldmrs]
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
#: Scored kinds: the simulator's class, and ours that count as it.
KINDS = {"ground": ((2,), (2, 20)), "building": ((6,), (6,)), "bridge deck": ((17,), (17,)), "water": ((9,), (9,))}


def echo_keys(las: laspy.LasData) -> np.ndarray:
    """One integer per point from its GPS time (ms), return number, channel and scan angle (0.006° units)."""
    ms = np.round(np.asarray(las.gps_time) * 1e3).astype(np.int64)
    key = (ms * 8 + np.asarray(las.return_number, np.int64)) * 16 + np.asarray(las.scanner_channel, np.int64)
    return key * 100_000 + (np.asarray(las.scan_angle, np.int64) + 50_000)


def true_classes(truth: laspy.LasData, output: laspy.LasData) -> tuple[np.ndarray, np.ndarray]:
    """The simulator's class of each output point's echo, and which output points found one."""
    kt, ko = echo_keys(truth), echo_keys(output)
    order = np.argsort(kt, kind="stable")
    if np.any(np.diff(kt[order]) == 0):
        raise SystemExit("two echoes of the truth share a key: the match would be ambiguous")
    at = np.clip(np.searchsorted(kt[order], ko), 0, len(kt) - 1)
    found = kt[order][at] == ko
    return np.asarray(truth.classification)[order][at], found


def scores(truth: np.ndarray, ours: np.ndarray) -> dict[str, tuple[float | None, float | None]]:
    """Recall and precision (%) per kind."""
    out = {}
    for kind, (t, o) in KINDS.items():
        is_t, is_o = np.isin(truth, t), np.isin(ours, o)
        hit = np.sum(is_t & is_o)
        out[kind] = (
            100.0 * hit / is_t.sum() if is_t.any() else None,
            100.0 * hit / is_o.sum() if is_o.any() else None,
        )
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "flight-ldmrs", help="the job's output folder")
    args = parser.parse_args(argv)
    output = laspy.read(str(args.out / "points.laz"))
    with tempfile.TemporaryDirectory() as tmp:
        pipeline = Path(sys.executable).with_name("pipeline")  # the venv's command
        simulate = ["simulate", str(ROOT / "configs" / "simulate.yaml"), "--only", "flight_ldmrs", "--out", tmp, "-q"]
        subprocess.run([str(pipeline), *simulate], check=True, cwd=ROOT)
        truth = laspy.read(str(Path(tmp) / "flight_ldmrs" / "truth" / "points.laz"))
    cls, found = true_classes(truth, output)
    ours = np.asarray(output.classification)
    print(f"{found.sum():,} of {len(found):,} output points matched to their echo")
    print("| class | recall % | precision % |\n|---|---|---|")
    for kind, (r, p) in scores(cls[found], ours[found]).items():
        print(f"| {kind} | {'–' if r is None else f'{r:.2f}'} | {'–' if p is None else f'{p:.2f}'} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
