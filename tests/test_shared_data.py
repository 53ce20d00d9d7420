"""One setting for where the data beside the repository is (tests/shared_data.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRINT = "from tests.shared_data import DATA, ISPRS, REAL; print(DATA); print(ISPRS); print(REAL)"


def _paths(**env: str) -> list[Path]:
    environ = {k: v for k, v in os.environ.items() if k != "SHARED_DIR"} | env
    out = subprocess.run([sys.executable, "-c", PRINT], cwd=ROOT, env=environ, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    return [Path(line) for line in out.stdout.splitlines()]


def test_shared_dir_names_the_shared_folder(tmp_path):
    assert _paths(SHARED_DIR=str(tmp_path)) == [tmp_path / "data", tmp_path / "data/isprs", tmp_path / "data/real"]


def test_without_it_the_shared_folder_is_beside_the_clone():
    beside = (ROOT.parent / "shared").resolve()
    assert _paths() == [beside / "data", beside / "data/isprs", beside / "data/real"]
    assert _paths(SHARED_DIR="") == _paths()
