"""Known answers for gridding methods, hillshade, contours and accuracy figures."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from lidar.checkpoints import read_checkpoints
from lidar.grid import Grid, cell_count, cell_max
from lidar.shading import hillshade
from pipeline.errors import InputDataError
from stages.accuracy.vertical import vertical_accuracy
from stages.contours.lines import contour_lines
from stages.rasterize.interpolate import idw, nearest


def _points(n=4000, seed=2, f=lambda x, y: 10.0 + 0.0 * x):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 40, (n, 2))
    return np.column_stack([xy, f(xy[:, 0], xy[:, 1])])


def test_idw_and_nearest_reproduce_a_constant_field():
    pts = _points()
    g = Grid.covering(5.0, 5.0, 35.0, 35.0, 1.0)
    assert np.allclose(idw(pts, g, nodata_distance=5.0), 10.0)
    assert np.allclose(nearest(pts, g, nodata_distance=5.0), 10.0)


def test_nearest_takes_the_closest_point_and_idw_is_a_weighted_mean():
    pts = np.array([[0.5, 0.5, 1.0], [3.5, 0.5, 4.0]])
    g = Grid(xmin=0.0, ymax=1.0, resolution=1.0, cols=4, rows=1)
    np.testing.assert_allclose(nearest(pts, g, nodata_distance=10.0)[0], [1.0, 1.0, 4.0, 4.0])
    # cell 1 centre (1.5, 0.5): distances 1 and 2 -> weights 1 and 1/4
    assert idw(pts, g, nodata_distance=10.0, neighbors=2)[0, 1] == pytest.approx((1.0 + 4.0 / 4) / 1.25)
    far = nearest(pts, Grid(xmin=20.0, ymax=1.0, resolution=1.0, cols=1, rows=1), nodata_distance=5.0, nodata=-1)
    assert far[0, 0] == -1


def test_cell_count_and_max():
    pts = np.array([[0.2, 0.8, 1.0], [0.7, 0.1, 5.0], [1.5, 0.5, 2.0]])
    g = Grid(xmin=0.0, ymax=1.0, resolution=1.0, cols=3, rows=1)
    assert cell_count(pts, g).tolist() == [[2, 1, 0]]
    out = cell_max(pts, g)
    assert out[0, 0] == 5.0 and out[0, 1] == 2.0 and np.isnan(out[0, 2])


def test_hillshade_known_values():
    flat = np.zeros((6, 6))
    assert hillshade(flat, 1.0) == pytest.approx(255 * np.sin(np.radians(45)))
    # z rising to the east and south (rows go south): the slope faces north-west,
    # the light's direction.  Slope angle atan(|(0.5, 0.5)|) = 35.26 deg, so the
    # light meets it at 45 - 35.26 deg from its normal; the opposite slope at 45 + 35.26.
    yy, xx = np.mgrid[0:6, 0:6].astype(float)
    facing = 0.5 * xx + 0.5 * yy
    angle = np.degrees(np.arctan(np.hypot(0.5, 0.5)))
    assert hillshade(facing, 1.0)[3, 3] == pytest.approx(255 * np.cos(np.radians(45 - angle)))
    assert hillshade(-facing, 1.0)[3, 3] == pytest.approx(255 * np.cos(np.radians(45 + angle)))


def test_contours_of_a_plane_are_straight_at_the_right_place():
    # z = x on a 1 m grid whose cell centres are at x = 0.5 .. 19.5
    yy, xx = np.mgrid[0:10, 0:20].astype(float)
    dem = xx + 0.5
    lines = contour_lines(dem, Affine(1.0, 0, 0.0, 0, -1.0, 10.0), interval=5.0)
    assert sorted({lvl for lvl, _ in lines}) == [5.0, 10.0, 15.0]
    for level, xy in lines:
        np.testing.assert_allclose(xy[:, 0], level, atol=1e-9)
    nodata = np.full((4, 4), np.nan)
    assert contour_lines(nodata, Affine.identity(), interval=1.0) == []


def test_vertical_accuracy_asprs_figures():
    e = np.array([0.1, -0.1, 0.1, -0.1, 0.5, np.nan])
    cover = np.array(["open", "open", "open", "open", "vegetated", "open"], dtype=object)
    r = vertical_accuracy(e, cover)
    assert r["n"] == 5 and r["outside"] == 1
    assert r["nva_95"] == pytest.approx(1.96 * 0.1)  # open points only
    assert r["vva_95"] == pytest.approx(0.5)
    assert r["rmse_z"] == pytest.approx(np.sqrt((4 * 0.01 + 0.25) / 5))


def test_vva_as_rmse_z_of_the_vegetated_points_alone():
    """ASPRS Edition 2's VVA, by hand: vegetated errors +0.3 and -0.4 m give sqrt((0.09 + 0.16) / 2) = 0.35355 m,
    where Edition 1's 95th percentile of |error| is 0.3 + 0.95 x 0.1 = 0.395 m; the open point is left out."""
    e = np.array([0.3, -0.4, 2.0])
    r = vertical_accuracy(e, np.array(["vegetated", "vegetated", "open"], dtype=object))
    assert r["vva_rmse_z"] == pytest.approx(0.3535534, abs=1e-7)
    assert r["vva_95"] == pytest.approx(0.395)
    assert vertical_accuracy(e)["vva_rmse_z"] is None  # no land cover: no vegetated point


def test_checkpoint_errors_name_line_and_column(tmp_path):
    bad = tmp_path / "cp.csv"
    bad.write_text("id,x,y,height\nA,1,2,3\nB,1,two,3\n")
    with pytest.raises(InputDataError, match=r"cp.csv, line 3: x, y and z must be numbers"):
        read_checkpoints(bad)
    bad.write_text("id,x,elev\n")
    with pytest.raises(InputDataError, match=r"line 1: no column 'y'"):
        read_checkpoints(bad)
    good = tmp_path / "ok.csv"
    good.write_text("# comment\nEasting,Northing,Elevation,land_cover\n1,2,3,open\n")
    pts, cover = read_checkpoints(good)
    assert pts.tolist() == [[1.0, 2.0, 3.0]] and cover.tolist() == ["open"]
