"""A flight too short for one line: one sentence naming the log (exit 3), or products with keep_turns; never a crash."""

from __future__ import annotations

import gzip
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from stages.georeference.strips import segment_strips
from tests.conftest import run_stages

ROOT = Path(__file__).resolve().parents[3]
LOG = ROOT / "data_samples" / "flight_ldmrs" / "ldmrs" / "acquisition.log.gz"


def cut_log(folder: Path, size: int, *, compressed: bool) -> Path:
    """The sample's LD-MRS log cut after *size* bytes of its text, or of its gzip stream."""
    if compressed:
        path = folder / "cut.log.gz"
        path.write_bytes(LOG.read_bytes()[:size])
    else:
        path = folder / "cut.log"
        with gzip.open(LOG, "rb") as fh:
            path.write_bytes(fh.read(size))
    return path


def run(tmp_path: Path, log: Path, *sets: str) -> int:
    args = ["run", str(ROOT / "configs" / "flight.yaml"), "-q", "--until", "georeference"]
    for s in (f"input.paths=[{log}]", f"output={tmp_path / 'out'}", f"cache={tmp_path / 'cache'}", *sets):
        args += ["--set", s]
    return main(args)


@pytest.mark.parametrize("compressed", [False, True])
def test_a_log_cut_after_12345_bytes_is_one_sentence(tmp_path, capsys, compressed):
    """Three scans, under a second: no line of strips.min_line_s, so no point would be kept: exit 3 naming the log."""
    log = cut_log(tmp_path, 12_345, compressed=compressed)
    assert run(tmp_path, log) == 3
    err = capsys.readouterr().err
    assert f"{log}: not enough trajectory for a flight line: its " in err
    assert "stages.georeference.strips.min_line_s (10 s)" in err and "internal error" not in err
    assert "same flight" not in err  # not blamed on mismatched files


def test_a_one_epoch_flight_with_its_turns_kept_is_georeferenced(tmp_path):
    """The lone epoch (doubled for interpolating) no longer trips the flight-line writer."""
    log = cut_log(tmp_path, 12_345, compressed=False)
    assert run(tmp_path, log, "stages.georeference.strips.keep_turns=true") == 0
    metrics = run_stages(tmp_path / "out")["georeference"]["metrics"]
    assert metrics["trajectory_epochs"] == 1 and metrics["points"] > 0 and metrics["dropped_in_turns"] == 0


def test_fewer_than_three_epochs_make_a_line_only_if_long_enough():
    assert segment_strips(np.array([0.0]), np.array([90.0])).tolist() == [0]
    assert segment_strips(np.array([0.0, 0.5]), np.array([90.0, 90.0])).tolist() == [0, 0]
    assert segment_strips(np.array([0.0, 12.0]), np.array([90.0, 90.0])).tolist() == [1, 1]
    assert segment_strips(np.array([]), np.array([])).tolist() == []
