"""Cell-aligned grids and TIN interpolation."""

from __future__ import annotations

import numpy as np
import pytest

import stages.rasterize.interpolate as gi
from lidar.grid import Grid, cell_max_count
from stages.rasterize.interpolate import thin_points, tin


def test_grid_is_cell_aligned_and_covers_every_point():
    g = Grid.covering(440_000.3, 4_474_000.7, 440_511.2, 4_474_383.9, 2.0)
    assert g.xmin % 2.0 == 0 and g.ymax % 2.0 == 0
    assert g.xmin <= 440_000.3 and g.xmin + g.cols * 2.0 > 440_511.2
    assert g.ymax >= 4_474_383.9 and g.ymax - g.rows * 2.0 < 4_474_000.7
    # A point exactly on a multiple gets its own column.
    assert Grid.covering(0.0, 0.0, 10.0, 10.0, 1.0).cols == 11


def test_tin_reproduces_a_plane_exactly():
    rng = np.random.default_rng(3)
    xy = rng.uniform(0, 50, (3000, 2)) + [500_000.0, 4_000_000.0]
    z = 100.0 + 0.3 * (xy[:, 0] - 500_000) - 0.2 * (xy[:, 1] - 4_000_000)
    g = Grid.covering(500_010.0, 4_000_010.0, 500_040.0, 4_000_040.0, 1.0)
    out = tin(np.column_stack([xy, z]), g, nodata_distance=10.0)
    gx, gy = g.centres()
    expected = 100.0 + 0.3 * (gx - 500_000) - 0.2 * (gy - 4_000_000)
    assert np.abs(out - expected).max() < 1e-6


def test_cells_far_from_points_or_outside_the_hull_are_nodata():
    pts = np.array([[0, 0, 1], [10, 0, 1], [0, 10, 1], [10, 10, 1], [5, 5, 1]], dtype=float)
    g = Grid(xmin=-5.0, ymax=15.0, resolution=1.0, cols=20, rows=20)
    out = tin(pts, g, nodata_distance=4.0, nodata=-9999.0)
    gx, gy = g.centres()
    inside = (gx > 0) & (gx < 10) & (gy > 0) & (gy < 10)
    near = np.min(np.hypot(gx[..., None] - pts[:, 0], gy[..., None] - pts[:, 1]), axis=-1) <= 4.0
    assert np.all(out[inside & near] == 1.0)
    assert np.all(out[~inside] == -9999.0)
    assert np.all(out[~near] == -9999.0)


def test_tin_needs_three_points():
    with pytest.raises(ValueError):
        tin(np.zeros((2, 3)), Grid(0, 1, 1, 1, 1), nodata_distance=1.0)


def test_thinning_keeps_the_point_nearest_each_half_cell_centre():
    # squares of 0.5 m anchored at the grid corner; centres at 0.25 + 0.5 i, -(0.25 + 0.5 j)
    xy = np.array(
        [
            [0.10, -0.10],  # square (0, 0): 0.212 from its centre
            [0.26, -0.24],  # square (0, 0): 0.014 -> kept
            [0.60, -0.30],  # square (1, 0), centre (0.75, -0.25): 0.158
            [0.70, -0.20],  # square (1, 0): 0.071 -> kept
            [1.20, -1.20],  # square (2, 2), centre (1.25, -1.25): 0.071, a tie: the first is kept
            [1.30, -1.30],  # 0.071
            [1.20, -1.20],  # coincident with the first of the tie: not kept
        ]
    )
    keep = thin_points(xy, 0.5)
    assert keep.tolist() == [1, 3, 4]


def test_thinned_tin_keeps_a_surface_it_can_resolve():
    # 16 points per 1 m cell on a quadric: thinned to at most 4 per cell, the
    # TIN stays within the curvature error of the unthinned one
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 40, (25_600, 2))
    z = 0.01 * (xy[:, 0] - 20) ** 2 + 0.02 * xy[:, 1]
    g = Grid(0.0, 40.0, 1.0, 40, 40).window(5, 35, 5, 35)
    full = tin(np.column_stack([xy, z]), g, nodata_distance=5.0, thin=False)
    thin = tin(np.column_stack([xy, z]), g, nodata_distance=5.0)
    gx, gy = g.centres()
    truth = 0.01 * (gx - 20) ** 2 + 0.02 * gy
    # linear interpolation on edges under 1 m: error below h^2 max|f''| / 8 (f'' = 0.02)
    assert np.abs(thin - truth).max() < 0.02 / 8 * 2
    assert np.abs(full - truth).max() < 0.02 / 8 * 2


def test_thinning_keeps_every_point_of_a_sparse_cell():
    # cell (0, 0) of 1 m (four 0.5 m squares) holds 3 points: all kept, the
    # duplicate once; cell (1, 0) holds 5: one per square
    sparse = [[0.10, -0.10], [0.20, -0.20], [0.10, -0.10], [0.80, -0.80]]
    dense = [
        [1.10, -0.10],
        [1.20, -0.20],
        [1.32, -0.32],
        [1.70, -0.20],
        [1.20, -0.70],
    ]  # 1.20, -0.20 nearest (1.25, -0.25)
    keep = thin_points(np.array(sparse + dense), 0.5, sparse=4)
    assert keep.tolist() == [0, 1, 3, 5, 7, 8]


def _survey_with_a_gap(rng, gap):
    """Ground at 2 points/m2 on a 200 m square but where ``gap(x, y)`` (water), on a curved surface."""
    xy = rng.uniform(0, 200, (80_000, 2))
    xy = xy[~gap(xy[:, 0], xy[:, 1])]
    z = 50.0 + 0.01 * (xy[:, 0] - 100) ** 2 - 0.02 * xy[:, 0] * xy[:, 1] / 100
    return np.column_stack([xy + [500_000.0, 4_000_000.0], z])


@pytest.mark.parametrize(
    ("gap", "rows", "cols", "matters"),
    [
        (lambda x, y: x < 0, (80, 120), (80, 120), False),  # dense: the near points suffice
        (lambda x, y: np.hypot(x - 100, y - 75) < 45, (80, 120), (80, 120), True),  # a lake across the edge
        (lambda x, y: x < 0, (0, 40), (0, 200), False),  # the survey's edge: cells outside the hull
    ],
)
def test_tin_of_the_near_points_equals_the_tin_of_all_points(monkeypatch, gap, rows, cols, matters):
    """A window of a survey drawn from the points within the margin is the window drawn from every point.

    Whole grid 200 x 200 cells of 1 m; the window is a tile's core.  Where
    water reaches beyond the margin, the near points alone triangulate it
    differently (a lake's far shore is missing: cells are left undrawn):
    the check must notice and take every point.  The case marked
    ``matters`` fails if the check is skipped.
    """
    pts = _survey_with_a_gap(np.random.default_rng(7), gap)
    grid = Grid(500_000.0, 4_000_200.0, 1.0, 200, 200).window(rows[0], rows[1], cols[0], cols[1])
    every = tin(pts.copy(), grid, nodata_distance=50.0, margin=None)
    assert np.isfinite(every).mean() > 0.9
    for margin in (3.0, 25.0):
        assert np.array_equal(tin(pts.copy(), grid, nodata_distance=50.0, margin=margin), every, equal_nan=True)
    monkeypatch.setattr(gi, "_same_as_all", lambda *a: True)
    unchecked = tin(pts.copy(), grid, nodata_distance=50.0, margin=3.0)
    assert np.array_equal(unchecked, every, equal_nan=True) != matters


def test_a_point_beyond_the_margin_inside_a_near_triangles_circumcircle_is_seen(monkeypatch):
    """Every cell is drawn from the near points, yet one far point changes the triangulation.

    Window: 10 x 10 cells of 1 m; margin 3 m.  The near points (the corners
    of a 12 m square around the window and its centre) make four triangles;
    the top one's circumcircle (centre (5, 11), radius 6) holds the point
    (5, 16.5), 3.5 m beyond the margin: in the triangulation of all points
    the top edge flips and the cells near the top take other planes.
    """
    pts = np.array(
        [[-1, -1, 10.0], [11, -1, 12.0], [11, 11, 15.0], [-1, 11, 11.0], [5, 5, 20.0], [5, 16.5, 0.0]], dtype=float
    )
    grid = Grid(xmin=-50.0, ymax=60.0, resolution=1.0, cols=100, rows=100).window(50, 60, 50, 60)  # x, y 0..10
    every = tin(pts.copy(), grid, nodata_distance=50.0, margin=None)
    assert np.isfinite(every).all()
    assert np.array_equal(tin(pts.copy(), grid, nodata_distance=50.0, margin=3.0), every)
    monkeypatch.setattr(gi, "_same_as_all", lambda *a: True)
    near = tin(pts.copy(), grid, nodata_distance=50.0, margin=3.0)
    assert np.isfinite(near).all() and not np.array_equal(near, every)


def test_cells_the_near_points_leave_undrawn_inside_the_whole_hull_are_seen(monkeypatch):
    """The near points draw three cells; far points (beyond the 3 m margin) span the rest of the window.

    The near triangle's circumcircle holds no far point, so only the test
    of the undrawn cells against the hull of all points catches it.
    """
    pts = np.array(
        [[0.2, 0.2, 1.0], [2.2, 0.2, 2.0], [0.2, 2.2, 3.0], [20, 0, 4.0], [20, 20, 5.0], [0, 20, 6.0]], dtype=float
    )
    grid = Grid(xmin=-50.0, ymax=60.0, resolution=1.0, cols=100, rows=100).window(50, 60, 50, 60)  # x, y 0..10
    every = tin(pts.copy(), grid, nodata_distance=50.0, margin=None)
    assert np.isfinite(every).all()
    assert np.array_equal(tin(pts.copy(), grid, nodata_distance=50.0, margin=3.0), every)
    monkeypatch.setattr(gi, "_same_as_all", lambda *a: True)
    assert np.isfinite(tin(pts.copy(), grid, nodata_distance=50.0, margin=3.0)).sum() == 3


def test_highest_point_and_count_per_cell_from_columns_or_rows():
    """Cell (row 0, col 1) of a 2 x 3 grid of 1 m holds z 5 and 7; points off the grid count nowhere."""
    pts = np.array([[1.5, 9.5, 5.0], [1.2, 9.1, 7.0], [0.5, 8.5, 1.0], [-0.5, 9.5, 99.0], [3.5, 9.5, 99.0]])
    grid = Grid(xmin=0.0, ymax=10.0, resolution=1.0, cols=3, rows=2)
    expected_max = np.array([[np.nan, 7.0, np.nan], [1.0, np.nan, np.nan]])
    expected_count = np.array([[0, 2, 0], [1, 0, 0]])
    for given in (pts, [pts[:, 0].copy(), pts[:, 1].copy(), pts[:, 2].copy()]):
        highest, count = cell_max_count(given, grid)
        assert np.array_equal(highest, expected_max, equal_nan=True)
        assert np.array_equal(count, expected_count)
