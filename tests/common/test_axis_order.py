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

import numpy as np
import pyproj
import pytest

from dtm.common.geodesy import LocalFrame, MapTransform


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
