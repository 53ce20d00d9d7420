"""The smrmsg's attitude sigmas are arc-minutes (SPEC 3.C): read back in degrees, 1' = 1/60 degree.

SPEC 3.C: an smrmsg record is 10 little-endian float64: time (GPS seconds of
week), north/east/down position sigma (m), north/east/down velocity sigma
(m/s), roll/pitch/heading sigma in arc-minutes.  The files are written here
with NumPy, record by record, and read through the 3.C trajectory reader.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from stages.parse.read_ins import TrajectoryCounters
from stages.parse.trajectory import sbet_trajectory

WEEK = 2300
SOW = np.array([100_000.0, 100_001.0, 100_002.0, 100_003.0])


def _write(tmp_path, roll_arcmin, pitch_arcmin, heading_arcmin):
    sbet = np.zeros((len(SOW), 17))
    sbet[:, 0] = SOW
    sbet[:, 1], sbet[:, 2], sbet[:, 3] = np.radians(59.0), np.radians(15.0), 500.0
    sbet[:, 9] = np.radians(45.0)  # platform heading; wander 0
    smr = np.zeros((len(SOW), 10))
    smr[:, 0] = SOW
    smr[:, 1], smr[:, 2], smr[:, 3] = 0.02, 0.03, 0.05  # north, east, down position sigma, m
    smr[:, 4:7] = 0.01  # velocity sigma, m/s
    smr[:, 7], smr[:, 8], smr[:, 9] = roll_arcmin, pitch_arcmin, heading_arcmin
    sbet.astype("<f8").tofile(tmp_path / "t.sbet")
    smr.astype("<f8").tofile(tmp_path / "t.smrmsg")
    return SimpleNamespace(sbet=tmp_path / "t.sbet", smrmsg=tmp_path / "t.smrmsg")


def test_attitude_sigmas_from_arc_minutes_to_degrees(tmp_path):
    # 1.5', 3', 6' -> 0.025, 0.05, 0.1 degree; rising over the file so each epoch reads its own record
    roll = np.array([1.5, 1.8, 2.1, 2.4])
    p = _write(tmp_path, roll, np.full(4, 3.0), np.full(4, 6.0))
    counters = TrajectoryCounters()
    out, extra = sbet_trajectory(p, WEEK, counters)
    assert extra["smrmsg_epochs"] == 4 and counters.malformed == 0
    np.testing.assert_allclose(out["time"], WEEK * 604_800.0 + SOW)
    np.testing.assert_allclose(out["sigma_roll_deg"], [0.025, 0.03, 0.035, 0.04], rtol=1e-12)
    np.testing.assert_allclose(out["sigma_pitch_deg"], 0.05, rtol=1e-12)
    np.testing.assert_allclose(out["sigma_heading_deg"], 0.1, rtol=1e-12)
    # positions in metres, as written; the down sigma is the up sigma
    np.testing.assert_allclose(out["sigma_north_m"], 0.02)
    np.testing.assert_allclose(out["sigma_east_m"], 0.03)
    np.testing.assert_allclose(out["sigma_up_m"], 0.05)


def test_one_degree_sigma_is_sixty_arc_minutes(tmp_path):
    """60' is one degree, and 600' (10 degrees, a poor but possible INS) is ten, not 600."""
    p = _write(tmp_path, np.full(4, 60.0), np.full(4, 600.0), np.full(4, 0.6))
    out, _ = sbet_trajectory(p, WEEK, TrajectoryCounters())
    np.testing.assert_allclose(out["sigma_roll_deg"], 1.0, rtol=1e-12)
    np.testing.assert_allclose(out["sigma_pitch_deg"], 10.0, rtol=1e-12)
    np.testing.assert_allclose(out["sigma_heading_deg"], 0.01, rtol=1e-12)
