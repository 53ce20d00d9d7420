"""The flight's classes against the simulator's class of every echo (issue 34's targets: 9 and 17 at 95 %).

The simulator writes each echo's true class to ``truth/points.laz``, which
the shipped sample leaves out: the sample is simulated again (same seed)
into a temporary folder.  Each output point is matched to its echo by GPS
time, return number, channel and scan angle (``benchmarks/flight_classes.py``).
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from benchmarks.flight_classes import true_classes
from pipeline.cli import main
from tests.conftest import run_until

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_the_flight_finds_its_water_bridge_and_buildings(tmp_path):
    sim = ["simulate", str(ROOT / "configs" / "simulate.yaml"), "--only", "flight_ldmrs", "--out", str(tmp_path)]
    assert main([*sim, "-q"]) == 0
    truth = laspy.read(str(tmp_path / "flight_ldmrs" / "truth" / "points.laz"))
    run_until(ROOT / "configs" / "flight.yaml", "export_las", tmp_path / "out")
    ours = laspy.read(str(tmp_path / "out" / "points.laz"))
    true, found = true_classes(truth, ours)  # each output point's echo, matched by GPS time, channel, angle, return
    assert found.all()  # every output point is an echo of the flight
    got = np.asarray(ours.classification)
    for cls, least in ((9, 95.0), (17, 95.0), (6, 95.0)):
        hit = np.sum((true == cls) & (got == cls))
        assert 100.0 * hit / np.sum(true == cls) >= least, cls  # recall
        assert 100.0 * hit / np.sum(got == cls) >= least, cls  # precision
