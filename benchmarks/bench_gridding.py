"""Seconds to grid N ground points into a DTM, per method (tin, idw, nearest).

    .venv/bin/python benchmarks/bench_gridding.py --points 1e6 1e7

Ground points are drawn uniformly at 1.5 points/m2 on the synthetic terrain
(tests.synthetic.terrain) with 3 cm noise; the DTM has 1 m cells over the
same square.  Times cover interpolation onto the grid (not I/O), each in a
fresh process.  Prints a Markdown table for docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from _isolated import emit, machine, run_child

# from this tree: importing _isolated put it first on sys.path
from lidar.grid import Grid
from stages.rasterize.interpolate import idw, nearest, tin
from tests.synthetic import terrain


def _one(points: float, method: str) -> None:
    rng = np.random.default_rng(1)
    n = int(points)
    side = float(np.sqrt(n / 1.5))
    x, y = rng.uniform(0, side, n), rng.uniform(0, side, n)
    pts = np.column_stack([x + 440_000, y + 4_474_000, terrain(x, y) + rng.normal(0, 0.03, n)])
    grid = Grid.covering(440_000, 4_474_000, 440_000 + side, 4_474_000 + side, 1.0)
    fn = {"tin": tin, "idw": idw, "nearest": nearest}[method]
    t0 = time.perf_counter()
    fn(pts, grid, nodata_distance=50.0)
    seconds = time.perf_counter() - t0
    emit(points=n, cells=grid.rows * grid.cols, seconds=seconds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=float, nargs="+", default=[1e6, 1e7])
    parser.add_argument("--methods", nargs="+", default=["tin", "idw", "nearest"])
    parser.add_argument("--one", nargs=2, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        _one(float(args.one[0]), args.one[1])
        return
    print(machine())
    print("| ground points | cells | method | seconds | points/s | peak RSS (MB) |")
    print("|---|---|---|---|---|---|")
    for points in args.points:
        for method in args.methods:
            r = run_child(__file__, str(points), method)
            print(
                f"| {r['points']:,} | {r['cells']:,} | {method} | {r['seconds']:.1f} | {r['points'] / r['seconds']:,.0f} | {r['peak_mb']:,.0f} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
