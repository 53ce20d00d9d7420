"""The simulator's flat scene and level attitude (issue 37), read back from the files it writes."""

from __future__ import annotations

import laspy
import numpy as np
import rasterio

from tests.flights import PERFECT_NAVIGATION, lines, simulate_flight


def _fly(root, **more):
    scanner = {"preset": "q140", "pulse_rate_hz": 2_000, "range_noise_m": 0.0}
    flight = lines(100, 30, 2, 200, cross_line=False, lead_in_m=20, **more.pop("flight", {}))
    simulate_flight(
        root, seed=3, formats=["lmsq_sbet"], scanner=scanner, flight=flight, navigation=PERFECT_NAVIGATION, **more
    )
    sbet = np.fromfile(root / "lmsq" / "trajectory.sbet", "<f8").reshape(-1, 17)
    return sbet[:, 7], sbet[:, 8]  # roll, pitch (radians)


def test_flat_scene_is_level_ground_and_nothing_else(tmp_path):
    _fly(tmp_path, scene={"terrain": "flat"})
    with rasterio.open(tmp_path / "truth" / "terrain.tif") as ds:
        z = ds.read(1, masked=True)
    with rasterio.open(tmp_path / "truth" / "land_cover.tif") as ds:
        cover = ds.read(1, masked=True)
    # level in the local frame: in ellipsoidal heights the Earth's curvature lowers it by d^2 / 2R (mm here)
    assert z.count() > 0 and float(z.max() - z.min()) < 0.01
    assert set(np.unique(cover.compressed()).tolist()) == {2}
    truth = laspy.read(tmp_path / "truth" / "points.laz")
    assert np.ptp(np.asarray(truth.z)) < 0.01  # no noise: every echo on the plane
    assert set(np.unique(np.asarray(truth.classification)).tolist()) == {2}


def test_level_attitude_has_no_roll_or_pitch_out_of_the_turns(tmp_path):
    roll, pitch = _fly(tmp_path / "level", flight={"level_attitude": True})
    assert np.all(pitch == 0.0)
    # two lines of 200 m at 30 m/s: 13 s of epochs at 200 Hz, at least half of them exactly level (the rest
    # is where the smoothed turn rate dies away); banked in the turns
    assert np.sum(roll == 0.0) > 0.5 * 200 * 2 * 200 / 30 and np.degrees(np.abs(roll).max()) > 10
    roll, pitch = _fly(tmp_path / "default")
    assert 1.0 < np.degrees(np.mean(pitch)) < 2.0 and np.mean(roll == 0.0) < 0.01  # nose-up, oscillating
