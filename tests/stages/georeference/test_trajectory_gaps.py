"""Pulses inside a trajectory gap get no position (``max_gap_s``, issue 19).

A navigation outage is not interpolated across: a pulse inside an interval
longer than ``max_gap_s`` is rejected (counted), one in a normal interval is
georeferenced.  Checked on the function with known times, and on a simulated
flight whose SBET loses 1.5 s of epochs.
"""

from __future__ import annotations

import laspy
import numpy as np

from commands.simulate.settings import SimulateConfig
from commands.simulate.simulator import simulate
from lidar.georeferencing import Mounting, georeference, prepare_trajectory
from pipeline.cli import main
from tests.conftest import run_stages
from tests.flights import TRUTH_CELL
from tests.stages.georeference.test_simulate_georef import RIEGL, _input

LAS_GPS_OFFSET = 1e9


def test_a_pulse_inside_a_gap_has_no_position():
    # epochs every 0.1 s from 0 to 10 s, none between 4 and 6 s; flying north at 50 m/s
    t = np.concatenate((np.arange(0.0, 4.01, 0.1), np.arange(6.0, 10.01, 0.1)))
    lat = 40.0 + 50.0 * t / 111_000.0
    traj = prepare_trajectory(t, lat, np.full(len(t), -3.7), np.full(len(t), 800.0), *np.zeros((3, len(t))), "NED")
    pulses = np.array([1.05, 3.95, 4.5, 5.0, 5.95, 6.0, 9.0])
    v = tuple(np.array([0.0] * len(pulses)) if k < 2 else np.full(len(pulses), 100.0) for k in range(3))
    xyz, ok = georeference(traj, pulses, v, Mounting(np.eye(3), np.zeros(3)), lambda e, n, u: (e, n, u), max_gap_s=0.5)
    assert ok.tolist() == [True, True, False, False, False, True, True]
    assert np.isnan(xyz[~ok]).all() and np.isfinite(xyz[ok]).all()
    # a longer allowance bridges the gap (the point then lies on the straight line between the epochs)
    _, ok = georeference(traj, pulses, v, Mounting(np.eye(3), np.zeros(3)), lambda e, n, u: (e, n, u), max_gap_s=2.5)
    assert ok.all()


def test_a_navigation_outage_rejects_the_pulses_inside_it(tmp_path):
    sim = tmp_path / "sim"
    result = simulate(
        SimulateConfig(output=sim, seed=7, checkpoints=0, truth_resolution=TRUTH_CELL, faults={"noise": False}, **RIEGL)
    )
    # cut 1.5 s out of the SBET (and its accuracy file) in the middle of the first line
    sbet = np.fromfile(sim / "lmsq" / "trajectory.sbet", dtype="<f8").reshape(-1, 17)
    sow0 = float(sbet[0, 0])
    truth = laspy.read(sim / "truth" / "points.laz")
    gps = np.asarray(truth.gps_time) + LAS_GPS_OFFSET
    line1 = gps[np.asarray(truth.point_source_id) == 1]
    mid = float(np.median(line1)) - result.gps_start + sow0  # seconds of week
    gap = (sbet[:, 0] > mid - 0.75) & (sbet[:, 0] < mid + 0.75)
    sbet[~gap].tofile(sim / "lmsq" / "trajectory.sbet")
    smr = np.fromfile(sim / "lmsq" / "trajectory.smrmsg", dtype="<f8").reshape(-1, 10)
    smr[~gap].tofile(sim / "lmsq" / "trajectory.smrmsg")
    lo, hi = sbet[~gap][:, 0][sbet[~gap][:, 0] < mid].max(), sbet[~gap][:, 0][sbet[~gap][:, 0] > mid].min()
    inside = (gps - result.gps_start + sow0 > lo) & (gps - result.gps_start + sow0 < hi)
    assert inside.sum() > 1000

    config = tmp_path / "gap.yaml"
    config.write_text(
        f"name: gap\ninput:\n{_input('lmsq_sbet', sim)}\ncrs: auto-utm\noutput: out\ncache: cache\n"
        "stages:\n  georeference: {max_gap_s: 0.5, strips: {turn_rate_deg_s: 2.0, min_line_s: 2.0}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "georeference"]) == 0
    stages = run_stages(tmp_path / "out")
    geo = stages["georeference"]
    assert geo["metrics"]["rejected_no_trajectory"] == int(inside.sum())
    points = laspy.read(geo["outputs"]["points_georef"]["file"])
    t_out = np.asarray(points.gps_time) + LAS_GPS_OFFSET - result.gps_start + sow0
    assert not ((t_out > lo) & (t_out < hi)).any()
