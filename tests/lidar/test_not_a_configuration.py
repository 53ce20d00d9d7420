"""A LAS/LAZ file given where a configuration is read: one sentence saying what it is and how to run it."""

from __future__ import annotations

import os

from lidar.input_files import not_a_configuration
from pipeline.cli import main


def test_a_las_file_given_as_the_configuration_says_how_to_run_it(tmp_path, capsys, monkeypatch):
    monkeypatch.delenv("PIPELINE_PLUGIN", raising=False)  # the product's plugin, whose hook this is
    las = tmp_path / "tile.laz"
    las.write_bytes(b"LASF" + bytes(371))  # a LAS header's signature: binary, not YAML
    for command in ("run", "validate"):
        assert main([command, str(las)]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and "Traceback" not in err
        assert "tile.laz: a LAS/LAZ point cloud, not a configuration" in err
        assert f"--set 'input.paths=[{las}]'" in err and "stages.accuracy.enabled=false" in err
        assert "not UTF-8" not in err


def test_other_files_are_left_to_the_configuration_reader(tmp_path):
    text = tmp_path / "job.yaml"
    text.write_text("name: job\n")
    assert not_a_configuration(text) is None and not_a_configuration(tmp_path / "none.yaml") is None
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    assert not_a_configuration(fifo) is None  # not opened: it would block
