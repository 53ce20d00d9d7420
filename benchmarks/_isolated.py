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
import tomllib
from pathlib import Path

# The repository's root, for ``tests.synthetic`` (the scene the benchmarks make), whatever the working folder.
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


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


def tree_at(commit: str | None, workdir: Path) -> tuple[Path, dict[str, str]]:
    """The tree that runs a job (this one; or *commit* checked out in a worktree under *workdir*) and the
    environment that runs its pipeline (its code first on the path, its plugin)."""
    if commit is None:
        tree = ROOT
    else:
        tree = workdir / f"tree-{commit}"
        if not tree.exists():
            subprocess.run(["git", "worktree", "add", "--detach", str(tree), commit], cwd=ROOT, check=True)
    with open(tree / "pyproject.toml", "rb") as fh:
        (spec,) = tomllib.load(fh)["project"]["entry-points"]["pipeline.plugins"].values()
    return tree, dict(os.environ, PYTHONPATH=str(tree), PIPELINE_PLUGIN=spec)
