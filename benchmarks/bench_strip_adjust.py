"""Strip adjustment speed on a simulated survey of about 10 M points in 6 strips.

    .venv/bin/python benchmarks/bench_strip_adjust.py [--rate 80000]

Simulates (format 3.D LAS, RIEGL Q280 at ``--rate`` pulses/s, five 1.5 km
lines at 50 % sidelap and a cross line, 0.5 m / 0.05 degree per-line
errors), then runs ``pipeline run --until strip_adjust`` and reports the
stage's own seconds (run.json), points/s and the overlap RMS before and after.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from _isolated import machine  # noqa: E402

from tests.flights import PERFECT_NAVIGATION, lines, simulate_flight  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rate", type=float, default=80_000)
    args = parser.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        t0 = time.perf_counter()
        simulate_flight(
            tmp / "sim",
            seed=5,
            formats=["las"],
            scanner={"preset": "q280", "pulse_rate_hz": args.rate, "scan_rate_hz": 80, "range_noise_m": 0.03},
            navigation=PERFECT_NAVIGATION,
            flight=lines(300, 60, 5, 1500, sidelap=0.5, cross_line=True),
            faults={"strip_bias_m": 0.5, "strip_rotation_deg": 0.05, "error_free_lines": [1]},
        )
        print(f"simulated in {time.perf_counter() - t0:.0f} s", file=sys.stderr)
        config = tmp / "adjust.yaml"
        config.write_text(
            f"input: {{format: las, paths: [{tmp}/sim/las/points.laz]}}\noutput: {tmp}/out\n"
            "stages: {strip_adjust: {reference_strip: 1}}\n"
        )
        t0 = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "pipeline", "run", str(config), "-q", "--until", "strip_adjust"],
            check=True,
            cwd=ROOT,
        )
        wall = time.perf_counter() - t0
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
        stages = {s["name"]: s for s in json.loads((tmp / "out" / "run.json").read_text())["stages"]}
        m = stages["strip_adjust"]["metrics"]
        n = stages["parse"]["metrics"]["points_read"]
        sec = stages["strip_adjust"]["seconds"]
        print(machine())
        print(
            "| points | strips | parse s | strip_adjust s | points/s | iterations | overlap RMS before → after (m) | peak RSS (MB) |"
        )
        print("|---|---|---|---|---|---|---|---|")
        print(
            f"| {n:,} | {m['strips']} | {stages['parse']['seconds']:.1f} | {sec:.1f} | {n / sec / 1e6:.2f} M | "
            f"{m['iterations']} | {m['overlap_rms_before_m']:.3f} → {m['overlap_rms_after_m']:.3f} | {peak:,.0f} |"
        )
        print(f"whole command {wall:.1f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
