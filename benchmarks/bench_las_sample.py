"""Wall time of configs/las.yaml: cold run, cached re-run, resolution-only re-run.

    .venv/bin/python benchmarks/bench_las_sample.py [--repeat 5]

Each timing is a whole `pipeline run` command in a fresh process (interpreter
start and imports included), with its own empty output and cache folders.
Prints a Markdown table row per measurement for docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PIPELINE = Path(sys.executable).with_name("pipeline")


def _run(config: Path, out: Path, *extra: str) -> tuple[float, dict]:
    cmd = [str(PIPELINE), "run", str(config), "-q", "--set", f"output={out / 'out'}", "--set", f"cache={out / 'cache'}"]
    t0 = time.perf_counter()
    subprocess.run([*cmd, *extra], check=True)
    seconds = time.perf_counter() - t0
    return seconds, json.loads((out / "out" / "run.json").read_text())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--config", type=Path, default=ROOT / "configs" / "las.yaml")
    args = parser.parse_args()
    cold, cached, partial, stage_times = [], [], [], []
    for _ in range(args.repeat):
        out = Path(tempfile.mkdtemp(prefix="bench-"))
        try:
            s, m = _run(args.config, out)
            cold.append(s)
            stage_times.append({st["name"]: st.get("seconds", 0.0) for st in m["stages"]})
            cached.append(_run(args.config, out)[0])
            partial.append(_run(args.config, out, "--set", "stages.rasterize.resolution=2.0")[0])
        finally:
            shutil.rmtree(out, ignore_errors=True)
    med = statistics.median
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    )
    print(
        f"date: {time.strftime('%Y-%m-%d')}; config: {args.config.relative_to(ROOT)}; repeats: {args.repeat} (median)"
    )
    print("| measurement | seconds |")
    print("|---|---|")
    print(f"| cold run (all stages) | {med(cold):.2f} |")
    for name in stage_times[0]:
        print(f"| &nbsp;&nbsp;stage `{name}` | {med(t[name] for t in stage_times):.2f} |")
    print(f"| cached re-run (nothing changed) | {med(cached):.2f} |")
    print(f"| re-run after changing only the resolution | {med(partial):.2f} |")


if __name__ == "__main__":
    main()
