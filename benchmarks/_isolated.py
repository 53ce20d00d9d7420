"""Shared by the benchmark scripts: run one measurement in a fresh process.

A measurement in its own process has its own peak memory and can be stopped
by a time limit without losing the others.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

# The repository's root, for ``tests.synthetic`` (the scene the benchmarks make), whatever the working folder.
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def machine() -> str:
    """One line naming the machine and the date, for docs/BENCHMARKS.md."""
    return f"machine: {platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}; date {time.strftime('%Y-%m-%d')}"


def emit(**figures) -> None:
    """In the child: print the figures and the peak RSS as one JSON line."""
    figures["peak_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps(figures))


def run_child(script: str, *args: str, timeout: float | None = None) -> dict | None:
    """Run ``script --one ARGS`` in a new interpreter; its JSON line, or None on time-out."""
    try:
        done = subprocess.run(
            [sys.executable, script, "--one", *args], capture_output=True, text=True, timeout=timeout, check=True
        )
    except subprocess.TimeoutExpired:
        return None
    return json.loads(done.stdout.strip().splitlines()[-1])
