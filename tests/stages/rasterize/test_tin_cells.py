"""The TIN draws exactly the cells whose centre is inside a triangle, whatever the triangle's shape."""

from __future__ import annotations

import numpy as np
import pytest

from lidar.grid import Grid
from stages.rasterize.interpolate import _draw_triangles, tin


def _inside(px, py, tri):
    """Cell centres strictly inside the triangle *tri* (3 x 2), by the signs of the three edge functions."""
    (x0, y0), (x1, y1), (x2, y2) = tri
    e = [
        (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0),
        (x2 - x1) * (py - y1) - (y2 - y1) * (px - x1),
        (x0 - x2) * (py - y2) - (y0 - y2) * (px - x2),
    ]
    return ((e[0] > 0) & (e[1] > 0) & (e[2] > 0)) | ((e[0] < 0) & (e[1] < 0) & (e[2] < 0))


@pytest.mark.parametrize(
    "tri",
    [
        [(0.13, -0.21), (97.31, -3.17), (2.71, -99.43)],  # a large right-ish triangle: long rows and columns
        [(1.07, -1.33), (98.77, -7.91), (49.13, -10.29)],  # a sliver across the grid: rows cut short
        [(50.37, -0.41), (0.29, -98.83), (99.61, -61.17)],  # leaning, no edge along the axes
    ],
)
def test_cells_drawn_are_the_centres_inside(tri):
    grid = Grid(xmin=0.0, ymax=0.0, resolution=1.0, cols=100, rows=100)
    xy = np.array(tri)
    z = np.array([10.0, 20.0, 40.0])  # the plane z = a + b x + c y through the three vertices
    out = np.full(grid.rows * grid.cols, np.nan)
    drawn = _draw_triangles(xy, z, np.array([[0, 1, 2]]), grid, out, batch_cells=1_000, progress=None)
    col, row = np.meshgrid(np.arange(grid.cols), np.arange(grid.rows))
    px, py = col + 0.5, -(row + 0.5)
    expected = _inside(px, py, xy).ravel()  # no centre lies on an edge of these triangles
    assert np.array_equal(np.isfinite(out), expected) and expected.sum() > 200
    a, b, c = np.linalg.solve(np.column_stack((np.ones(3), xy)), z)
    assert np.allclose(out[expected], (a + b * px + c * py).ravel()[expected], atol=1e-9)
    assert drawn.tolist() == [[0, 1, 2]]


def test_a_long_edge_on_the_tins_hull_is_not_drawn():
    """A square of points 1 m apart and one point 40 m north of it: a fan of triangles from it to the square's
    north edge, the outer two with an edge of 47 m on the hull.  Trimmed at 20 m, those two draw nothing: thin
    slivers along the hull; the rest is untouched."""
    g = np.arange(0.5, 50.0, 1.0)
    x, y = np.meshgrid(g, g)
    pts = np.vstack((np.column_stack((x.ravel(), y.ravel(), np.zeros(x.size))), [[25.0, 90.0, 40.0]]))
    grid = Grid(0.0, 100.0, 1.0, 50, 100)  # rows 0-49: y 100 to 50, north of the square
    full = tin(pts.copy(), grid, nodata_distance=100.0, thin=False)
    trimmed = tin(pts.copy(), grid, nodata_distance=100.0, thin=False, max_hull_edge=20.0)
    gone = np.isfinite(full) & np.isnan(trimmed)
    assert gone.sum() > 10
    both = np.isfinite(trimmed)
    np.testing.assert_array_equal(trimmed[both], full[both])  # nothing else changes
    cx, cy = grid.centres()
    tip = np.array([25.0, 90.0])
    for corner in (np.array([0.5, 49.5]), np.array([49.5, 49.5])):  # each cell gone lies along a hull edge
        edge = tip - corner
        t = np.clip(((cx - corner[0]) * edge[0] + (cy - corner[1]) * edge[1]) / (edge @ edge), 0, 1)
        near = np.hypot(cx - corner[0] - t * edge[0], cy - corner[1] - t * edge[1]) < 1.0
        gone &= ~near
    assert not gone.any()
