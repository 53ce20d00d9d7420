"""A lazy plugin: the parser is built from its name and commands; its stages load on first use."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.cli import main
from tests.pipeline.lazy_toy import wrong_name

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import json, sys
from pipeline.cli import main
try:
    main(sys.argv[1:])
except SystemExit:
    pass
print(json.dumps(sorted(sys.modules)))
"""


def _modules(*argv: str) -> tuple[str, set[str]]:
    """The output of ``pipeline ARGV`` in a fresh interpreter, and the modules it imported."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PIPELINE_PLUGIN": "tests.pipeline.lazy_toy:plugin"}
    proc = subprocess.run([sys.executable, "-c", PROBE, *argv], env=env, capture_output=True, text=True, check=True)
    *text, modules = proc.stdout.strip().splitlines()
    return "\n".join(text), set(json.loads(modules))


def test_help_and_a_command_import_no_stage():
    text, modules = _modules("--help")
    assert "echo" in text and "print the words" in text
    assert "tests.pipeline.toy" not in modules
    assert {"pipeline.stage", "pipeline.config", "pipeline.runner", "pydantic"}.isdisjoint(modules)
    text, modules = _modules("echo", "a", "b")
    assert text == "echo: a b"
    assert "tests.pipeline.toy" not in modules


def test_run_loads_the_stages(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PIPELINE_PLUGIN", "tests.pipeline.lazy_toy:plugin")
    (tmp_path / "numbers.txt").write_text("1\n2\n")
    config = tmp_path / "toy.yaml"
    config.write_text("source: {path: numbers.txt}\noutput: out\nstages: {scale: {factor: 3}}\n")
    assert main(["run", str(config), "-q"]) == 0
    assert json.loads((tmp_path / "out" / "total.json").read_text())["total"] == 9
    with pytest.raises(SystemExit):  # argparse prints the version and exits
        main(["--version"])
    assert capsys.readouterr().out.strip().endswith("(toy)")


def test_a_loader_that_builds_another_plugin_is_an_error():
    with pytest.raises(ValueError, match="not-toy"):
        _ = wrong_name.stages
