"""The simulator's own geometry (commands/simulate/forward.py) against PROJ and textbook cases (issue 19).

The simulator's truth checks georeferencing only if the two do not share
code: these tests pin the forward model to independent references (PROJ's
geodetic and topocentric conversions, rotations worked by hand), and check
that nothing under commands/simulate imports lidar.georeferencing or stages.parse.
"""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pyproj

from commands.simulate.forward import Earth, RecordedPose, attitude, enu_axes, mounting_matrix

SIM = Path(__file__).resolve().parents[2] / "commands" / "simulate"


def test_the_simulator_imports_nothing_from_georef():
    """Nor from the readers it checks: their constants (mountings, GPS epoch, NMEA checksum) are its own."""
    assert len(list(SIM.glob("*.py"))) > 5  # the simulator's modules are read
    for path in SIM.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""]
            checked = (
                "lidar.georeferencing",
                "lidar.geodesy",
                "lidar.rotation",
                "stages.georeference",
            )
            assert not any(n.startswith((*checked, "stages.parse")) for n in names), (
                path.name,
                names,
            )


def test_local_level_axes_are_the_derivatives_of_the_geodetic_position():
    """North and up at (lat, lon) from PROJ by finite differences: the columns of R_ecef<-enu."""
    to_ecef = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
    lat, lon, d = 40.4, -3.7, 1e-6
    p0 = np.array(to_ecef.transform(lon, lat, 700.0))
    north = np.array(to_ecef.transform(lon, lat + d, 700.0)) - p0
    east = np.array(to_ecef.transform(lon + d, lat, 700.0)) - p0
    up = np.array(to_ecef.transform(lon, lat, 701.0)) - p0
    axes = enu_axes(lat, lon)[0].as_matrix()
    for k, v in enumerate((east, north, up)):
        np.testing.assert_allclose(axes[:, k], v / np.linalg.norm(v), atol=1e-7)


def test_local_frame_is_the_topocentric_frame():
    """A point 1 km east and 100 m up of the origin; the origin itself; a round trip through geodetic."""
    earth = Earth(40.4, -3.7, 700.0)
    origin = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True).transform(-3.7, 40.4, 700.0)
    np.testing.assert_allclose(earth.to_ecef([[0.0, 0.0, 0.0]])[0], origin, atol=1e-6)
    p = np.array([[1000.0, 0.0, 100.0], [-250.0, 3000.0, -40.0]])
    back = earth.from_ecef(earth.to_ecef(p))
    np.testing.assert_allclose(back, p, atol=1e-6)
    lat, lon, h = earth.geodetic(p)
    np.testing.assert_allclose(earth.from_geodetic(lat, lon, h), p, atol=1e-6)
    # 1 km east at 40.4 N: the longitude grows by 1000 / (N cos(lat)); the height by the Earth's curvature
    n = 6378137.0 / np.sqrt(1 - 0.00669437999014 * np.sin(np.radians(40.4)) ** 2)
    assert abs((lon[0] + 3.7) - np.degrees(1000.0 / ((n + 800.0) * np.cos(np.radians(40.4))))) < 1e-7
    assert abs(h[0] - (800.0 + 1000.0**2 / (2 * n))) < 0.01


def test_attitude_and_mounting_rotations_by_hand():
    # heading 90 deg: forward points east (NED y); roll 90 deg: right wing points down
    np.testing.assert_allclose(attitude(0.0, 0.0, np.pi / 2).apply([1.0, 0.0, 0.0])[0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(attitude(np.pi / 2, 0.0, 0.0).apply([0.0, 1.0, 0.0])[0], [0.0, 0.0, 1.0], atol=1e-12)
    # nose up (pitch +90 deg): forward points up (NED -z)
    np.testing.assert_allclose(attitude(0.0, np.pi / 2, 0.0).apply([1.0, 0.0, 0.0])[0], [0.0, 0.0, -1.0], atol=1e-12)
    # the order: roll first, heading last: Rz(90) Rx(90) takes body x to east, y to down, z to north
    r = attitude(np.pi / 2, 0.0, np.pi / 2).as_matrix()[0]
    np.testing.assert_allclose(r, [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(mounting_matrix(np.pi / 2, 0.0, np.pi / 2), r, atol=1e-12)


def test_level_flight_north_looks_straight_down():
    """Level, heading north, at the origin: body down is local down, body forward is local north."""
    earth = Earth(40.4, -3.7, 700.0)
    r = earth.local_from_body([40.4], [-3.7], 0.0, 0.0, 0.0).as_matrix()[0]
    np.testing.assert_allclose(r @ [0.0, 0.0, 1.0], [0.0, 0.0, -1.0], atol=1e-12)
    np.testing.assert_allclose(r @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(r @ [0.0, 1.0, 0.0], [1.0, 0.0, 0.0], atol=1e-12)


def test_recorded_pose_interpolates_between_epochs():
    """Two epochs 1 s apart, 40 m east, heading turning 90 -> 100 deg: the pulse half way sees 95 deg."""
    earth = Earth(40.4, -3.7, 700.0)
    lat, lon, h = earth.geodetic(np.array([[0.0, 0.0, 100.0], [40.0, 0.0, 100.0]]))
    pose = RecordedPose(earth, [0.0, 1.0], lat, lon, h, [0.0, 0.0], [0.0, 0.0], [90.0, 100.0])
    lever = np.array([0.0, 0.0, 1.0])  # 1 m below the INS
    p = pose.points([0.5], np.array([[10.0, 0.0, 0.0]]), np.eye(3), lever)[0]
    heading = np.radians(95.0)  # the local level turns by 40 m / R between epochs: below 1e-5 rad
    expect = [20.0 + 10.0 * np.sin(heading), 10.0 * np.cos(heading), 99.0]
    np.testing.assert_allclose(p, expect, atol=2e-4)
