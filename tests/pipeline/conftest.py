from __future__ import annotations

import json
from pathlib import Path

import pytest

from pipeline.cli import main


@pytest.fixture
def toy(tmp_path, monkeypatch):
    """A toy project: numbers.txt and a config; returns a helper object."""
    monkeypatch.setenv("PIPELINE_PLUGIN", "tests.pipeline.toy:plugin")
    (tmp_path / "numbers.txt").write_text("1\n2\n3 # three\n10\n")
    config = tmp_path / "toy.yaml"
    config.write_text(
        "name: toy\n"
        "source:\n"
        "  path: numbers.txt\n"
        "output: out\n"
        "stages:\n"
        "  scale: {factor: 3}\n"
        "  histogram:\n"
        "    bins: 2\n"
    )

    class Toy:
        root = tmp_path
        path = config

        def run(self, *args: str) -> int:
            return main(["run", str(config), "-q", *args])

        def manifest(self) -> dict:
            return json.loads((tmp_path / "out" / "run.json").read_text())

        def statuses(self) -> dict[str, str]:
            return {s["name"]: s["status"] for s in self.manifest()["stages"]}

        def product(self, name: str):
            return json.loads((tmp_path / "out" / name).read_text())

    return Toy()


def write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path
