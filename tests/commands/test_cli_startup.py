"""`pipeline --help` builds its parser without importing the stages or NumPy."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from stages.plugin import plugin

ROOT = Path(__file__).resolve().parents[2]

PROBE = """
import json, sys
from pipeline.cli import main
for argv in (["--help"], ["run", "--help"], ["evaluate", "ground", "--help"], ["--version"]):
    try:
        main(argv)
    except SystemExit:
        pass
print(json.dumps(sorted(sys.modules)))
"""


def test_help_imports_no_stage_nor_numpy():
    env = {**os.environ, "PYTHONPATH": str(ROOT), "PIPELINE_PLUGIN": "stages.plugin:plugin"}
    proc = subprocess.run([sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True)
    lines = proc.stdout.strip().splitlines()
    modules = set(json.loads(lines[-1]))
    assert "evaluate" in proc.stdout and "--algorithm" in proc.stdout and "dtm-pipeline" in proc.stdout
    assert not [m for m in modules if m.startswith("stages.") and m != "stages.plugin"]  # the plugin alone
    assert {"numpy", "pydantic", "pipeline.stage"}.isdisjoint(modules)


def test_the_plugin_loads_its_stages_on_first_use():

    assert plugin.name == "dtm-pipeline"
    names = [s.name for s in plugin.stages]
    assert names[0] == "parse" and names[-1] == "report" and plugin.stage("rasterize").name == "rasterize"
