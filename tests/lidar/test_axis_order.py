"""Output CRS whose authority axis order is northing first: points still come out easting, northing.

EPSG:3006 (SWEREF99 TM) is registered with axes (N, E), as are EPSG:2193
(NZTM) and EPSG:31467 (Gauss-Kruger zone 3, X north).  The pipeline writes
LAS and GeoTIFF x = easting, y = northing, so the ECEF -> map transform must
be built in the traditional GIS order (pyproj ``always_xy=True``), whatever
order the registry gives.

Known answers: SWEREF99 TM is transverse Mercator on GRS 80 with central
meridian 15 E, false easting 500 000 m and scale 0.9996; a point on the
central meridian has easting 500 000 m exactly, and its northing is the
scaled meridian arc (6 651 411.19 m at 60 N, from pyproj in x/y order:
a peer computation from geodetic coordinates, not through our code).
"""

from __future__ import annotations

import laspy
import numpy as np
import pyproj
import pytest

from lidar.geodesy import LocalFrame, MapTransform
from stages.parse.read_las import convert_las_files


@pytest.mark.parametrize(
    ("epsg", "lat0", "lon0"),
    [(3006, 60.0, 15.0), (2193, -41.3, 174.8), (31467, 50.0, 9.0)],
)
def test_northing_first_crs_maps_easting_first(epsg, lat0, lon0):
    crs = pyproj.CRS.from_epsg(epsg)
    assert crs.axis_info[0].direction == "north"  # the case under test: the registry puts northing first
    frame = LocalFrame(lat0, lon0, 100.0)
    lo, hi = np.array([-500.0, -500.0, -50.0]), np.array([500.0, 500.0, 50.0])
    to_map = MapTransform(frame, crs, lo, hi)
    local = np.array([[0.0, 0.0, 0.0], [400.0, 0.0, 0.0], [0.0, 400.0, 0.0], [-300.0, 250.0, 20.0]])
    got = to_map(local)
    # the peer: the same points from geodetic coordinates, pyproj in x = easting, y = northing order
    lon, lat, h = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True).transform(
        *frame.to_ecef(local).T
    )
    e, n = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(got[:, 0], e, atol=1e-3)
    np.testing.assert_allclose(got[:, 1], n, atol=1e-3)
    np.testing.assert_allclose(got[:, 2], h, atol=1e-3)
    # by geometry: 400 m east moves the easting by about 400 m and the northing by 400 sin(gamma) at most,
    # gamma the grid convergence (under 2 degrees within 2 degrees of longitude of these central meridians:
    # 14 m); likewise 400 m north
    assert 395.0 < got[1, 0] - got[0, 0] < 405.0 and abs(got[1, 1] - got[0, 1]) < 15.0
    assert 395.0 < got[2, 1] - got[0, 1] < 405.0 and abs(got[2, 0] - got[0, 0]) < 15.0


def test_sweref99_tm_central_meridian_known_point():
    """60 N, 15 E, 100 m: SWEREF99 TM easting 500 000 m (central meridian), northing 6 651 411.19 m."""
    to_map = MapTransform(LocalFrame(60.0, 15.0, 100.0), pyproj.CRS.from_epsg(3006), -np.ones(3), np.ones(3))
    e, n, h = to_map(np.zeros((1, 3)))[0]
    assert abs(e - 500_000.0) < 1e-3
    assert abs(n - 6_651_411.19) < 0.01
    assert abs(h - 100.0) < 1e-3


@pytest.mark.parametrize("src", ["EPSG:32633", "EPSG:4326"])
def test_las_reprojected_to_northing_first_crs_stays_easting_first(tmp_path, src):
    """LAS in UTM 33N (easting first) or WGS 84 (registered latitude first) -> SWEREF99 TM (northing first).

    UTM 33N and SWEREF99 TM share the central meridian (15 E), false easting and
    scale: a point on the meridian keeps easting 500 000 m, and its northing
    moves by the WGS 84 -> SWEREF99 datum difference only (well under a metre).
    """
    lon, lat = np.array([15.0, 15.01, 14.99]), np.array([60.0, 60.005, 59.995])
    if src == "EPSG:4326":
        x, y, scale = lon, lat, 1e-8
    else:
        x, y = pyproj.Transformer.from_crs("EPSG:4326", src, always_xy=True).transform(lon, lat)
        scale = 1e-3
    header = laspy.LasHeader(point_format=3, version="1.2")
    header.scales = np.array([scale, scale, 1e-3])
    header.offsets = np.array([float(np.min(x)), float(np.min(y)), 0.0])
    header.add_crs(pyproj.CRS.from_user_input(src))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, np.array([100.0, 101.0, 102.0])
    las.write(str(tmp_path / "a.las"))
    convert_las_files(
        [tmp_path / "a.las"], tmp_path / "out.las", crs_setting="EPSG:3006", assign_crs=None, chunk_size=1000
    )
    out = laspy.read(str(tmp_path / "out.las"))
    assert out.header.parse_crs().to_epsg() == 3006
    # the peer: pyproj in x = easting, y = northing order
    e, n = pyproj.Transformer.from_crs(src, "EPSG:3006", always_xy=True).transform(x, y)
    np.testing.assert_allclose(out.x, e, atol=1e-3)
    np.testing.assert_allclose(out.y, n, atol=1e-3)
    # the writer's grid from the reprojected header bounds (lidar.clouds.point_header): offsets the
    # easting and northing rounded down to whole kilometres, scale 0.1 mm (swapped bounds: 1 cm, far offsets)
    np.testing.assert_array_equal(
        out.header.offsets[:2], [np.floor(e.min() / 1e3) * 1e3, np.floor(n.min() / 1e3) * 1e3]
    )
    np.testing.assert_array_equal(out.header.scales[:2], [1e-4, 1e-4])
    # by geometry: the first point is on the central meridian, 60 N
    assert abs(out.x[0] - 500_000.0) < 1.0 and abs(out.y[0] - 6_651_411.19) < 1.0
