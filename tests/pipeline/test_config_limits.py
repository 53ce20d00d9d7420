"""A configuration path or a ``--set`` value that would hang or blow up the loader (issue 38).

A FIFO with no writer blocked the run until it was killed; a ``--set``
value nested 3,000 deep ended in ``RecursionError`` (exit 1).  Both are one
sentence and exit 2 now, at once.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.cli import main
from pipeline.config import MAX_DEPTH

ROOT = Path(__file__).resolve().parents[2]


def _validate(toy, capsys, *args: str) -> tuple[int, str]:
    code = main(["validate", str(toy.path), *args])
    return code, capsys.readouterr().err


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


@pytest.mark.parametrize(
    "value",
    [
        "[" * 3000 + "]" * 3000,  # RecursionError in the YAML parser before
        "{a: " * 3000 + "1" + "}" * 3000,
        "[" * 70 + "]" * 70,  # parsed, but deeper than a file may nest
    ],
    ids=["lists-3000", "mappings-3000", "lists-70"],
)
def test_a_set_value_nested_too_deep_is_one_sentence(toy, capsys, value):
    code, err = _validate(toy, capsys, "--set", f"stages.scale.factor={value}")
    assert code == 2
    assert err.startswith("pipeline: error: --set stages.scale.factor=")
    assert err.endswith(f": the configuration nests mappings or lists more than {MAX_DEPTH} levels deep.\n")
    assert len(err) < 250 and "Traceback" not in err and "Recursion" not in err


def test_the_key_counts_towards_the_depth_of_a_set_value(toy, capsys):
    keys = ".".join(["a"] * 10)
    code, err = _validate(toy, capsys, "--set", f"{keys}={'[' * 60 + ']' * 60}")  # 10 + 60 > 64
    assert code == 2 and "more than 64 levels deep" in err
    code, err = _validate(toy, capsys, "--set", f"{keys}={'[' * 40 + ']' * 40}")  # fine in depth: an unknown key
    assert code == 2 and "unknown key" in err


def test_a_dotted_key_3000_deep_is_one_short_sentence(toy, capsys):
    code, err = _validate(toy, capsys, "--set", ".".join(["a"] * 3000) + "=1")
    assert code == 2
    assert err.endswith(f": the key nests 3000 levels deep; a configuration nests at most {MAX_DEPTH}.\n")
    assert len(err) < 250


def test_an_alias_bomb_in_a_set_value_is_refused(toy, capsys):
    bomb = "[&a [1,1,1,1,1,1,1,1,1,1], &b [*a,*a,*a,*a,*a,*a,*a,*a,*a,*a], &c [*b,*b,*b,*b,*b,*b,*b,*b,*b,*b], "
    bomb += "&d [*c,*c,*c,*c,*c,*c,*c,*c,*c,*c], &e [*d,*d,*d,*d,*d,*d,*d,*d,*d,*d]]"
    code, err = _validate(toy, capsys, "--set", f"stages.scale.factor={bomb}")
    assert code == 2
    assert "expand to more than 100,000 values" in err and err.startswith("pipeline: error: --set stages.scale")


def test_a_valid_set_value_still_reads_as_yaml(toy, capsys):
    code, err = _validate(toy, capsys, "--set", "stages.scale.factor=2.5", "--set", "stages.histogram.bins=# none")
    assert (code, err) == (2, err)  # bins: null is refused by its model, not by the loader
    assert "stages.histogram.bins" in err
    code, err = _validate(toy, capsys, "--set", "stages.scale.factor=2.5")
    assert (code, err) == (0, "")
