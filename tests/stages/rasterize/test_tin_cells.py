"""The TIN draws exactly the cells whose centre is inside a triangle, whatever the triangle's shape."""

from __future__ import annotations

import numpy as np
import pytest

from dtm.common.grid import Grid
from dtm.stages.rasterize.interpolate import _draw_triangles


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
