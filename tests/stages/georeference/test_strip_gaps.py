"""Line segmentation does not smooth across trajectory gaps (issue 37).

Known answers built by hand: 200 Hz epochs, lines of steady heading, turns at
18 deg/s.  With the 2 s moving average a turn that starts at time T0 shows a
smoothed rate of 18 * (overlap of [t - 1, t + 1] with the turn) / 2 deg/s at
time t, below 1 deg/s only while that overlap is under 1/9 s: the epochs more
than 1 + 1/9 s from a recorded turn are on a line.  A gap (> 2 s without an
epoch) ends a piece of trajectory; nothing of the heading on one side reaches
the other.
"""

from __future__ import annotations

import laspy
import numpy as np

from pipeline.cli import main
from stages.georeference.strips import segment_strips
from tests.conftest import run_stages
from tests.flights import lines, simulate_flight
from tests.stages.georeference.test_simulate_georef import _input

LAS_GPS_OFFSET = 1e9

HZ = 200.0


def epochs(start: float, stop: float, hz: float = HZ) -> np.ndarray:
    """Epoch times from *start* to *stop* inclusive at *hz*."""
    return start + np.arange(round((stop - start) * hz) + 1) / hz


def test_a_turn_not_recorded_leaves_both_lines_whole():
    # line 1 heading 0 deg for 30 s, 40 s without epochs (the turn), line 2 heading 180 deg for 30 s
    t1, t2 = epochs(0.0, 30.0), epochs(70.0, 100.0)
    t = np.concatenate((t1, t2))
    hdg = np.concatenate((np.zeros(len(t1)), np.full(len(t2), 180.0)))
    s = segment_strips(t, hdg)
    assert s[: len(t1)].tolist() == [1] * len(t1)
    assert s[len(t1) :].tolist() == [2] * len(t2)  # no 0 at the start of line 2 (nor at the end of line 1)


def test_a_recorded_turn_is_still_a_turn():
    # the same lines, flown through a recorded 10 s turn at 18 deg/s from 30 to 40 s
    t = epochs(0.0, 70.0)
    hdg = np.clip((t - 30.0) * 18.0, 0.0, 180.0)
    s = segment_strips(t, hdg)
    on_line1, on_line2 = t <= 29.0, t >= 41.0  # more than 1 + 1/9 s from the turn
    turn = (t >= 29.25) & (t <= 40.75)  # the turn and the 1 s either side the average spreads it over (+ margin)
    assert (s[on_line1] == 1).all() and (s[on_line2] == 2).all()
    assert (s[turn] == 0).all()


def test_a_turn_half_recorded_is_a_turn_on_both_sides_of_its_gap():
    # the recording pauses 33-37 s inside the turn: the recorded parts of the turn stay turns
    t = epochs(0.0, 70.0)
    t = t[(t <= 33.0) | (t >= 37.0)]
    hdg = np.clip((t - 30.0) * 18.0, 0.0, 180.0)
    s = segment_strips(t, hdg)
    # at the edge of a piece the padding holds the heading: the last epoch before the gap still
    # sees 1 s of turn in its 2 s window (9 deg/s)
    assert (s[(t >= 30.5) & (t <= 39.5)] == 0).all()
    assert (s[t <= 29.0] == 1).all() and (s[t >= 41.0] == 2).all()


def test_each_piece_smooths_over_its_own_time_step():
    # line 1 at 200 Hz; after a gap, 10 Hz epochs: line 2, a 10 s turn at 18 deg/s, line 3.  The
    # window is 2 s in each piece (20 epochs at 10 Hz), not 400 epochs (40 s) from the 200 Hz median
    t1, t2 = epochs(0.0, 100.0), epochs(110.0, 170.0, hz=10.0)
    t = np.concatenate((t1, t2))
    hdg = np.concatenate((np.zeros(len(t1)), 90.0 + np.clip((t2 - 140.0) * 18.0, 0.0, 180.0)))
    s = segment_strips(t, hdg)
    assert (s[t <= 100.0] == 1).all()
    assert (s[(t >= 110.0) & (t <= 139.0)] == 2).all()
    assert (s[(t >= 140.0) & (t <= 150.0)] == 0).all()
    assert (s[t >= 151.0] == 3).all()


def test_a_simulated_flight_whose_turn_was_not_recorded_keeps_every_echo_of_its_lines(tmp_path):
    """Through the stage: the SBET loses the epochs of the turn between lines 1 and 2; no echo of either is dropped.

    Before the fix the second either side of the gap was a turn: only 1133 of line 1's 3663 echoes
    were kept (its echoes over the simulated terrain last 1.3 s and end at the gap).
    """
    sim = tmp_path / "sim"
    scanner = {"preset": "q140", "pulse_rate_hz": 3000}
    result = simulate_flight(
        sim, seed=7, formats=["lmsq_sbet"], scanner=scanner, flight=lines(120, 40, 2, 160), faults={"noise": False}
    )
    sbet = np.fromfile(sim / "lmsq" / "trajectory.sbet", dtype="<f8").reshape(-1, 17)
    truth = laspy.read(sim / "truth" / "points.laz")
    sow = np.asarray(truth.gps_time) + LAS_GPS_OFFSET - result.gps_start + float(sbet[0, 0])  # seconds of week
    line = np.asarray(truth.point_source_id)
    # every epoch strictly between line 1's last echo and line 2's first one is cut (tens of seconds)
    end1, start2 = sow[line == 1].max(), sow[line == 2].min()
    cut = (sbet[:, 0] > end1 + 0.01) & (sbet[:, 0] < start2 - 0.01)
    assert np.ptp(sbet[cut, 0]) > 10.0
    sbet[~cut].tofile(sim / "lmsq" / "trajectory.sbet")
    smr = np.fromfile(sim / "lmsq" / "trajectory.smrmsg", dtype="<f8").reshape(-1, 10)
    smr[~cut].tofile(sim / "lmsq" / "trajectory.smrmsg")

    config = tmp_path / "gap.yaml"
    config.write_text(
        f"name: gap\ninput:\n{_input('lmsq_sbet', sim)}\ncrs: auto-utm\noutput: out\ncache: cache\n"
        "stages:\n  georeference: {max_gap_s: 0.5, strips: {turn_rate_deg_s: 2.0, min_line_s: 1.0}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "georeference"]) == 0
    geo = run_stages(tmp_path / "out")["georeference"]
    points = laspy.read(geo["outputs"]["points_georef"]["file"])
    strip = np.asarray(points.point_source_id)
    assert np.count_nonzero(strip == 1) == np.count_nonzero(line == 1)
    assert np.count_nonzero(strip == 2) == np.count_nonzero(line == 2)
    assert len(strip) == len(line)
