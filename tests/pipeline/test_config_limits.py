"""A configuration path that would hang the loader (issue 38).

A FIFO with no writer blocked the run until it was killed: it is one
sentence and exit 2 now, at once.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

from pipeline.cli import main

ROOT = Path(__file__).resolve().parents[2]


def test_a_fifo_with_no_writer_is_refused_at_once(tmp_path):
    fifo = tmp_path / "job.yaml"
    os.mkfifo(fifo)
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PIPELINE_PLUGIN": "tests.pipeline.toy:plugin"}
    # in a process of its own: a regression blocks there, and the timeout fails the test instead of hanging it
    done = subprocess.run(
        [sys.executable, "-m", "pipeline", "validate", str(fifo)], env=env, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 2
    assert done.stderr == (
        f"pipeline: error: {fifo}: not a configuration file but a FIFO (named pipe), which would block until "
        "something writes to it; give the path of a YAML file.\n"
    )


def test_a_folder_is_named_as_one(toy, capsys):
    code = main(["validate", str(toy.root)])
    err = capsys.readouterr().err
    assert code == 2
    assert err == f"pipeline: error: {toy.root}: not a configuration file but a folder; give the path of a YAML file.\n"
