"""Single pulses worked by hand, in each attitude convention, through the georeferencing code.

At latitude 0, longitude 0, height 0 the local-level axes in ECEF are simple:
north = +Z, east = +Y, down = -X (so west = -Y, up = +X), and the platform
is at (a, 0, 0) with a = 6 378 137 m.  With 90-degree rotations every step
of R_b^n . (R_s^b . v_s + a_b) can be done by hand (written out below).
"""

from __future__ import annotations

import laspy
import numpy as np
import pyproj
import pytest

from commands.simulate.writers import write_sbet
from lidar.geodesy import LocalFrame, MapTransform
from lidar.georeferencing import Mounting, georeference_local, locate, prepare_trajectory
from lidar.rotation import rot_y, rot_z
from pipeline.cli import main
from stages.parse.read_lmsq import write_lmsq
from tests.conftest import constant_geoid, run_stages
from tests.flights import lines, simulate_flight

A = 6_378_137.0
S30, C30 = 0.5, np.sqrt(3) / 2


def _one_pulse(convention, roll, pitch, yaw, v_s, rotation, lever):
    traj = prepare_trajectory(
        np.array([0.0, 1.0]),
        np.zeros(2),
        np.zeros(2),
        np.zeros(2),
        np.full(2, roll),
        np.full(2, pitch),
        np.full(2, yaw),
        convention,
    )
    i, f, ok = locate(traj, np.array([0.5]), 2.0)
    assert ok.all()
    local = np.column_stack(georeference_local(traj, *(np.array([c]) for c in v_s), Mounting(rotation, lever), i, f))
    return traj.frame.to_ecef(local)[0]


def test_ned_pulse_by_hand():
    # scanner: mirror angle 30 deg, range 100 m -> v_s = (0, 100 sin 30, 100 cos 30) = (0, 50, 86.6025)
    # boresight Rz(90): (x, y, z) -> (-y, x, z)           -> (-50, 0, 86.6025)
    # lever arm (1, 2, 3)                                -> v_b = (-49, 2, 89.6025)
    # roll 90, Rx: (x, y, z) -> (x, -z, y)               -> (-49, -89.6025, 2)
    # pitch 90, Ry: (x, y, z) -> (z, y, -x)              -> (2, -89.6025, 49)
    # heading 90, Rz: (x, y, z) -> (-y, x, z)            -> NED (89.6025, 2, 49)
    # ECEF = (a, 0, 0) + 89.6025 north + 2 east + 49 down = (a - 49, 2, 89.6025)
    v_s = (0.0, 100 * S30, 100 * C30)
    got = _one_pulse("NED", 90.0, 90.0, 90.0, v_s, rot_z(np.pi / 2), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(got, [A - 49.0, 2.0, 3.0 + 100 * C30], atol=1e-6)


def test_nwu_pulse_by_hand():
    # the same body vector and angles, read in the MTi-G's NWU frame: (89.6025 N, 2 W, 49 U)
    # ECEF = (a, 0, 0) + 89.6025 (0, 0, 1) + 2 (0, -1, 0) + 49 (1, 0, 0) = (a + 49, -2, 89.6025)
    v_s = (0.0, 100 * S30, 100 * C30)
    got = _one_pulse("NWU", 90.0, 90.0, 90.0, v_s, rot_z(np.pi / 2), np.array([1.0, 2.0, 3.0]))
    np.testing.assert_allclose(got, [A + 49.0, -2.0, 3.0 + 100 * C30], atol=1e-6)


def test_ldmrs_mounting_by_hand():
    # LD-MRS point 10 m along its optical axis: Ry(+90) (10, 0, 0) = (0, 0, -10), + MPOS of cb5000
    # (0.013, 0.0299, -0.0565) -> (0.013, 0.0299, -10.0565) in NWU at level attitude:
    # ECEF = (a, 0, 0) + 0.013 north + 0.0299 west - 10.0565 up = (a - 10.0565, -0.0299, 0.013)
    got = _one_pulse("NWU", 0.0, 0.0, 0.0, (10.0, 0.0, 0.0), rot_y(np.pi / 2), np.array([0.013, 0.0299, -0.0565]))
    np.testing.assert_allclose(got, [A - 10.0565, -0.0299, 0.013], atol=1e-6)


def test_heading_is_clockwise_in_ned_and_counter_clockwise_in_nwu():
    # a pulse straight ahead (body x), heading/yaw 90 deg: NED -> east (+Y); NWU -> west (-Y)
    ned = _one_pulse("NED", 0.0, 0.0, 90.0, (10.0, 0.0, 0.0), np.eye(3), np.zeros(3))
    nwu = _one_pulse("NWU", 0.0, 0.0, 90.0, (10.0, 0.0, 0.0), np.eye(3), np.zeros(3))
    np.testing.assert_allclose(ned, [A, 10.0, 0.0], atol=1e-6)
    np.testing.assert_allclose(nwu, [A, -10.0, 0.0], atol=1e-6)


def test_sbet_pulse_end_to_end_by_hand(tmp_path):
    """One .lmsq measurement + a two-record SBET -> parse -> georeference -> the hand-computed point in UTM.

    SBET: platform heading 120 deg, wander 30 deg -> true heading 90 deg; roll = pitch = 0.  Scanner:
    mirror angle 0, range 100 m -> v_s = (0, 0, 100); boresight 0; lever arm (1, 0, 0) m.
    NED = Rz(90) (1, 0, 100) = (0, 1, 100): 1 m east, 100 m down of the INS at (0 N, 0 E, 500 m):
    ECEF (a + 500 - 100, 1, 0) = (a + 400, 1, 0).
    """
    week, sow = 2400, 100_000.0
    write_lmsq(tmp_path / "scan.lmsq", 140, [("pps", sow, week), ("m", 100.0, 200, 0.0, 40, 0, 500_000, (0, 0, 0))])
    rec = np.zeros((2, 17))
    rec[:, 0] = [sow, sow + 1.0]
    rec[:, 3] = 500.0
    rec[:, 9] = np.radians(120.0)
    rec[:, 10] = np.radians(30.0)
    write_sbet(tmp_path / "t.sbet", rec)
    config = tmp_path / "one.yaml"
    config.write_text(
        "input: {format: lmsq_sbet, paths: [scan.lmsq], sbet: t.sbet, boresight_deg: [0, 0, 0], lever_arm_m: [1, 0, 0]}\n"
        "crs: EPSG:32631\noutput: out\nstages: {georeference: {max_gap_s: 2.0, strips: {keep_turns: true}}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "georeference"]) == 0
    stages = run_stages(tmp_path / "out")

    las = laspy.read(stages["georeference"]["outputs"]["points_georef"]["file"])
    assert len(las) == 1
    x, y, z = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:32631", always_xy=True).transform(A + 400.0, 1.0, 0.0)
    assert las.x[0] == pytest.approx(x, abs=1e-3) and las.y[0] == pytest.approx(y, abs=1e-3)
    assert las.z[0] == pytest.approx(z, abs=1e-3) and z == pytest.approx(400.0, abs=1e-6)
    # GPS time: week x 604800 + sow + 0.5 s, stored as adjusted standard GPS time
    assert las.gps_time[0] + 1e9 == pytest.approx(week * 604_800 + sow + 0.5, abs=1e-6)


def test_ltp_difference_is_what_geometry_predicts(tmp_path):
    """Seed 0's local tangent plane over a 1 km flight, against the exact tangent plane.

    Geometry: N = R dlat differs from the meridian arc M dlat by (R/M - 1) n; E = R dlon cos(lat0)
    from the parallel arc by about (R/N - 1) e; and U = h stands above the tangent plane by
    d^2 / 2R.  The reported figures must be those, within 1 cm (they are decimetres, not the
    "negligible" the seed assumes).
    """
    scanner = {"preset": "q140", "pulse_rate_hz": 2000}
    flight = lines(150, 60, 1, 1000)
    simulate_flight(
        tmp_path / "sim", seed=3, formats=["lmsq_sbet"], scanner=scanner, flight=flight, faults={"noise": False}
    )
    sim = tmp_path / "sim" / "lmsq"
    config = tmp_path / "ltp.yaml"
    config.write_text(
        f"input: {{format: lmsq_sbet, paths: [{sim}/scan.lmsq], sbet: {sim}/trajectory.sbet, "
        "boresight_deg: [0, 0, 0], lever_arm_m: [0.1, 0, 0.25]}\n"
        "output: out\nstages: {georeference: {frame: ltp, strips: {keep_turns: true}}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "georeference"]) == 0
    m = run_stages(tmp_path / "out")["georeference"]
    m = m["metrics"]
    d = m["ltp_vs_exact_extent_m"]  # farthest point from the first fix
    assert 800 < d < 1300  # the 1 km line, from a first fix 3 s before its start
    # the prediction, for the flight's north-south line over ground about 650 m above the
    # ellipsoid: (R/(M + h) - 1) d horizontally, d^2/2R vertically
    lat0 = np.radians(40.4168)
    e2 = 6.69437999014e-3
    radius_m = A * (1 - e2) / (1 - e2 * np.sin(lat0) ** 2) ** 1.5
    assert m["ltp_predicted_max_horizontal_m"] == pytest.approx(abs(6_371_000 / (radius_m + 650) - 1) * d, rel=0.1)
    assert m["ltp_predicted_max_vertical_m"] == pytest.approx(d**2 / (2 * 6_371_000), rel=0.02)
    # and the measured difference is the predicted one, up to the flat-earth term the first-order
    # prediction leaves out: offsets added in one plane are tilted by d/R, 150 m x 1.4e-4 = 2 cm here
    assert m["ltp_vs_exact_max_horizontal_m"] == pytest.approx(m["ltp_predicted_max_horizontal_m"], abs=0.04)
    assert m["ltp_vs_exact_max_vertical_m"] == pytest.approx(m["ltp_predicted_max_vertical_m"], abs=0.02)
    assert m["ltp_vs_exact_max_horizontal_m"] > 0.5  # not negligible: decimetres per 100 m of extent
    assert m["crs"].startswith("unknown") or "Equidistant" in m["crs"] or m["crs_epsg"] is None


def test_geoid_grid_gives_orthometric_heights(tmp_path):
    """A geoid grid of N = 50 m: heights drop by 50 m (H = h - N), positions do not move."""
    grid = constant_geoid(tmp_path / "geoid.tif", 50.0)
    frame = LocalFrame(40.4168, -3.7038, 650.0)
    lo, hi = np.array([-500.0, -500.0, -100.0]), np.array([500.0, 500.0, 300.0])
    crs = pyproj.CRS.from_epsg(32630)
    with_geoid, without = MapTransform(frame, crs, lo, hi, geoid=grid), MapTransform(frame, crs, lo, hi)
    pts = np.array([[10.0, 20.0, 5.0], [-400.0, 300.0, 250.0]])
    np.testing.assert_allclose(with_geoid(pts) - without(pts), [[0, 0, -50.0]] * 2, atol=1e-6)
