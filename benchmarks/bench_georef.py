"""Georeferencing and raw-format parsing speed.

    .venv/bin/python benchmarks/bench_georef.py [--pulses 10000000] [--flight-pulses 5000000]

1. ``georeference()`` alone (the algorithm, no I/O): a 200 Hz trajectory and
   N pulses in memory, 1 and 2 threads, best of 3.
2. A simulated flight of at least ``--flight-pulses`` pulses in formats 3.B
   and 3.C (RIEGL stream at 50 kHz) and 3.A (LD-MRS log), then
   ``pipeline run --until georeference`` on each: the parse and georeference
   stages' own times from run.json, as pulses per second.

Prints Markdown rows for docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pyproj

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _isolated import machine  # noqa: E402

from lidar.geodesy import MapTransform  # noqa: E402
from lidar.georeferencing import Mounting, georeference, prepare_trajectory  # noqa: E402
from tests.flights import lines as flight_lines  # noqa: E402
from tests.flights import simulate_flight  # noqa: E402


def bench_core(n: int) -> list[tuple[int, float]]:
    m = 200 * 600  # 10 minutes at 200 Hz
    t = np.arange(m) / 200.0
    traj = prepare_trajectory(
        t, 40.4 + t * 5e-6, -3.7 + t * 1e-6, 1000 + 0 * t, np.sin(t), 1 + 0 * t, 30 + t * 0.01, "NED"
    )
    rng = np.random.default_rng(0)
    tp = np.sort(rng.uniform(0, t[-1], n))
    theta = rng.uniform(-0.5, 0.5, n)
    r = rng.uniform(300, 500, n)
    cols = (np.zeros(n), np.sin(theta) * r, np.cos(theta) * r)
    lo = traj.position.min(axis=0) - 600
    hi = traj.position.max(axis=0) + 600

    to_map = MapTransform(traj.frame, pyproj.CRS.from_epsg(32630), lo, hi)
    out = []
    for workers in (1, 2):
        best = min(
            _time(
                lambda w=workers: georeference(
                    traj, tp, cols, Mounting(np.eye(3), np.zeros(3)), to_map.columns, workers=w
                )
            )
            for _ in range(3)
        )
        out.append((workers, best))
    return out


def _time(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def bench_flights(pulses: int, tmp: Path) -> list[tuple[str, int, float, float]]:
    rate = 50_000
    seconds = pulses / rate * 1.15
    lines = 4
    speed = 60.0
    length = seconds / lines * speed
    t0 = time.perf_counter()
    scanner = {"preset": "q280", "pulse_rate_hz": rate, "scan_rate_hz": 80}
    flight = flight_lines(400, speed, lines, length)
    simulate_flight(tmp / "rg", seed=1, formats=["lmsq_nmea", "lmsq_sbet"], scanner=scanner, flight=flight)
    print(f"simulated the RIEGL flight in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    scans = pulses / (81 * 4 * 12.5) * 1.1
    t0 = time.perf_counter()
    scanner = {"preset": "ldmrs", "angle_step_deg": 1.0}
    simulate_flight(
        tmp / "ld", seed=1, formats=["ldmrs_mtig"], scanner=scanner, flight=flight_lines(60, 10, 1, scans * 10)
    )
    print(f"simulated the LD-MRS flight in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
    rows = []
    inputs = {
        "lmsq_nmea": f"format: lmsq_nmea, paths: [{tmp}/rg/lmsq/scan.lmsq], nmea: {tmp}/rg/lmsq/nav.nmea, "
        f"ins: {tmp}/rg/lmsq/ins.csv",
        "lmsq_sbet": f"format: lmsq_sbet, paths: [{tmp}/rg/lmsq/scan.lmsq], sbet: {tmp}/rg/lmsq/trajectory.sbet",
        "ldmrs_mtig": f"format: ldmrs_mtig, paths: [{tmp}/ld/ldmrs/acquisition.log.gz], mounting: cb5000",
    }
    for fmt, block in inputs.items():
        extra = "" if fmt == "ldmrs_mtig" else ", boresight_deg: [0, 0, 0], lever_arm_m: [0, 0, 0]"
        config = tmp / f"{fmt}.yaml"
        config.write_text(
            f"input: {{{block}{extra}}}\noutput: out-{fmt}\ncache: cache-{fmt}\n"
            "executor: {kind: local, workers: 2}\nstages: {georeference: {strips: {keep_turns: true}}}\n"
        )
        subprocess.run(
            [sys.executable, "-m", "pipeline", "run", str(config), "-q", "--until", "georeference"],
            check=True,
            cwd=ROOT,
        )
        stages = {s["name"]: s for s in json.loads((tmp / f"out-{fmt}" / "run.json").read_text())["stages"]}
        n = stages["georeference"]["metrics"]["pulses"]
        rows.append((fmt, n, stages["parse"]["seconds"], stages["georeference"]["seconds"]))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--pulses", type=int, default=10_000_000)
    parser.add_argument("--flight-pulses", type=int, default=5_000_000)
    args = parser.parse_args()
    print(machine())
    print("\n| pulses | threads | seconds | pulses/s |\n|---|---|---|---|")
    for workers, sec in bench_core(args.pulses):
        print(f"| {args.pulses:,} | {workers} | {sec:.2f} | {args.pulses / sec / 1e6:.1f} M |")
    with tempfile.TemporaryDirectory() as tmp:
        rows = bench_flights(args.flight_pulses, Path(tmp))
    print("\n| format | pulses | parse s | parse pulses/s | georeference s | georeference pulses/s |")
    print("|---|---|---|---|---|---|")
    for fmt, n, parse_s, geo_s in rows:
        print(f"| {fmt} | {n:,} | {parse_s:.1f} | {n / parse_s / 1e6:.2f} M | {geo_s:.1f} | {n / geo_s / 1e6:.2f} M |")


if __name__ == "__main__":
    main()
