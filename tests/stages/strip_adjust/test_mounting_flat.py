"""Calibration over flat ground at level attitude (issue 37): what the flight cannot determine is held.

Over a level surface, flown with roll and pitch 0, a pitch or yaw boresight error moves every point
horizontally (to first order), and overlapping planar patches see no horizontal move: no overlap can
determine pitch or yaw.  Roll tilts the swath, so opposite-direction lines see it.  The simulator flies
the same injected boresight error as test_mounting.py (0.05, -0.08, 0.15) deg over its flat scene.
The stage must hold pitch and yaw (saying what would determine them), apply nothing wrong, and leave
the points no farther from the truth than the configured boresight leaves them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from stages.report.sections import mounting_table
from tests.conftest import run_stages
from tests.stages.georeference.test_simulate_georef import _match
from tests.stages.strip_adjust.test_mounting import BORESIGHT, _flight, _run, _unknowns


def _truth_rms(sim: Path, points: str) -> float:
    """3-D RMS of the points of *points* against the simulator's true echoes."""
    *_, d = _match(sim / "truth" / "points.laz", Path(points))
    return float(np.sqrt(np.mean(np.sum(d**2, axis=1))))


def _no_farther_from_the_truth(sim: Path, out: Path, stage: dict) -> None:
    """The adjusted points are no farther from the true echoes than the georeferenced ones (1 mm slack)."""
    georef = run_stages(out)["georeference"]
    before = _truth_rms(sim, georef["outputs"]["points_georef"]["file"])
    after = _truth_rms(sim, stage["outputs"]["points_adjusted"]["file"])
    assert after <= before + 0.001, (before, after)


def _flat_flight(root: Path, *, sigma: float, pulse_rate: int, length: float = 150.0) -> Path:
    """Two lines there and back and a cross line, 100 m above the flat scene, roll and pitch 0 on the lines."""
    plan = {"altitude_m": 100, "speed_ms": 30, "line_length_m": length, "lead_in_m": 30, "second_altitude_m": None}
    return _flight(
        root, boresight=BORESIGHT, pulse_rate=pulse_rate, terrain="flat", sigma=sigma, level_attitude=True, **plan
    )


def _check(root: Path, sim: Path, cell: float) -> None:
    """Calibrate with patches of *cell* metres (parse and georeference from the shared cache) and check."""
    out = f"cell{cell:g}"
    stage, corr = _run(root, sim, f"model: mounting, cell: {cell:g}", out=out)
    u = _unknowns(corr)
    assert corr["note"] is None, corr["note"]
    for name in ("boresight_pitch", "boresight_yaw"):
        assert u[name]["held_because"] and not u[name]["estimated"], (cell, u[name])
        assert u[name]["correction"] == 0.0
        assert "opposite directions" in u[name]["determined_by"]
    assert sorted(stage["metrics"]["not_determined"]) == ["boresight_pitch", "boresight_yaw"]
    roll = u["boresight_roll"]
    if roll["applied"]:  # what is applied is right: roll tilts the swath, which the overlaps see
        assert abs(roll["correction"] - BORESIGHT[0]) <= max(3 * roll["sigma"], 0.005), roll
    _no_farther_from_the_truth(sim, root / out, stage)


@pytest.mark.slow  # 7 s; its claim at every cell size is the next test's, which the old code fails
def test_flat_ground_holds_pitch_and_yaw(tmp_path):
    _check(tmp_path, _flat_flight(tmp_path, sigma=0.02, pulse_rate=4_000), 4.0)


@pytest.mark.slow  # a flight dense enough for 2-m patches (0.45 M pulses), calibrated three times
@pytest.mark.parametrize("sigma", [0.02, 0.0])
def test_flat_ground_holds_pitch_and_yaw_at_every_cell(tmp_path, sigma):
    """Before issue 37, with 2 cm of noise and 2-m cells (4,965 links), pitch came out +0.0157 +- 0.0038 deg
    (truth -0.08) and was applied: the patches' random slopes taken for information."""
    sim = _flat_flight(tmp_path, sigma=sigma, pulse_rate=12_000, length=300.0)
    for cell in (2.0, 4.0, 8.0):
        _check(tmp_path, sim, cell)


@pytest.mark.slow  # a calibration flight at 500 m, 8,000 pulses/s (about 12 s)
def test_a_held_lever_arm_does_not_bias_the_boresight_silently(tmp_path):
    """The calibration flight without its second height, with a lever-arm error (0.03, -0.04, 0) m and
    lever_arm: true.  One height cannot determine lever-arm x (an along-track shift, like pitch), so it is
    held at the configured value, and pitch absorbs its error (0.03 m over 500-650 m of range: 0.0027 deg).
    Pitch is then either held, naming lever_arm_x, or applied with a sigma that carries the held lever
    arm's possible error, and lies within 3 of those sigmas of the truth (before issue 37: 8 sigma off)."""
    lever = (0.03, -0.04, 0.0)
    plan = {"altitude_m": 500, "second_altitude_m": None, "lines": 3, "line_length_m": 400, "lead_in_m": 0}
    sim = _flight(tmp_path, boresight=BORESIGHT, lever=lever, pulse_rate=8_000, **plan)
    stage, corr = _run(tmp_path, sim, "model: mounting, cell: 8, mounting: {lever_arm: true}")
    u = _unknowns(corr)
    assert u["lever_arm_x"]["held_because"], u["lever_arm_x"]
    pitch = u["boresight_pitch"]
    if pitch["held_because"]:
        assert "lever_arm_x" in pitch["held_because"], pitch
    else:
        assert pitch["applied"] and pitch["sigma_from_held"]["unknown"] == "lever_arm_x", pitch
    for name, truth in zip(("boresight_roll", "boresight_pitch", "boresight_yaw"), BORESIGHT, strict=True):
        if u[name]["applied"]:
            assert abs(u[name]["correction"] - truth) <= 3 * u[name]["sigma"], (name, u[name])

    row = mounting_table(corr).split("<td>boresight_pitch</td>")[1].split("</tr>")[0]
    assert "lever_arm_x" in row
    _no_farther_from_the_truth(sim, tmp_path / "out", stage)
