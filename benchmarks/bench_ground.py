"""Seconds to classify ground on simulated surveys: the default (SMRF) vs CSF, and PMF.

    .venv/bin/python benchmarks/bench_ground.py --points 1e6 1e7 [--timeout 1200]

Each (size, algorithm) runs in its own process (so peak memory and a time
limit apply to it alone) on the synthetic scene of tests.synthetic at
1.5 pulses/m2 over a square area sized for the point count.  Times cover the
algorithm only (scene generation excluded), and also the denoise step.
Prints a Markdown table for docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _isolated import emit, machine, run_child

# from this tree: importing _isolated put it first on sys.path
from tests.synthetic import make_scene

ALGORITHMS = ["denoise", "smrf", "pmf", "csf"]


def _one(points: float, algorithm: str) -> None:
    side = float(np.sqrt(points / 1.6))  # about 1.6 points per pulse-m2 with tree returns
    scene = make_scene(width=side, height=side, density=1.5, n_trees=int(side * side / 4000))
    xyz = np.column_stack([scene.x, scene.y, scene.z])
    t0 = time.perf_counter()
    # lazy: each child imports only the algorithm it measures (its peak memory counts its imports)
    if algorithm == "denoise":
        from stages.denoise.noise_classes import noise_classes
        from stages.denoise.params import DenoiseParams

        noise_classes(xyz, DenoiseParams())
    elif algorithm == "smrf":
        from stages.classify_ground.smrf import smrf

        smrf(xyz)
    elif algorithm == "pmf":
        from stages.classify_ground.pmf import pmf

        pmf(xyz)
    else:
        from stages.classify_ground.csf import csf

        csf(xyz)
    seconds = time.perf_counter() - t0
    emit(points=len(xyz), seconds=seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=float, nargs="+", default=[1e6, 1e7])
    parser.add_argument("--algorithms", nargs="+", default=ALGORITHMS)
    parser.add_argument("--timeout", type=float, default=1200.0)
    parser.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        _one(float(args.one[0]), args.one[1])
        return
    print(machine())
    print("| points | algorithm | seconds | points/s | peak RSS (MB) |")
    print("|---|---|---|---|---|")
    for points in args.points:
        for algorithm in args.algorithms:
            r = run_child(__file__, str(points), algorithm, timeout=args.timeout)
            if r is None:
                print(f"| {points:,.0f} | {algorithm} | > {args.timeout:.0f} (stopped) | | |", flush=True)
                continue
            rate = r["points"] / r["seconds"]
            print(
                f"| {r['points']:,} | {algorithm} | {r['seconds']:.1f} | {rate:,.0f} | {r['peak_mb']:,.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
