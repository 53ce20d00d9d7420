"""IDW and nearest on a window of a grid: the k-d tree of the points near the window gives every point's answer.

``idw(margin=...)`` asks a tree of the points within the margin of the
window first and a tree of every point only for the cells whose k-th
neighbour is not nearer than the edge of that region.  The rasters must be
the same bytes as with one tree of every point (``margin=None``), where the
margin cuts through gaps (cells far from any point near them) and where
neighbours tie (points on a lattice).
"""

from __future__ import annotations

import numpy as np
import pytest

from lidar.grid import Grid
from stages.rasterize import interpolate
from stages.rasterize.interpolate import idw, nearest

X0, Y0 = 500_000.0, 4_400_000.0


def _random_with_gap() -> np.ndarray:
    """Random points on a millimetre grid, with an empty rectangle astride the window's west edge."""
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 200, (60_000, 2))
    gap = (xy[:, 0] > 45) & (xy[:, 0] < 80) & (xy[:, 1] > 50) & (xy[:, 1] < 120)
    xy = np.round(xy[~gap], 3)
    return np.column_stack((X0 + xy[:, 0], Y0 + xy[:, 1], 600 + 0.01 * xy[:, 0] + rng.normal(0, 0.1, len(xy))))


def _lattice_with_band() -> np.ndarray:
    """Points on a 0.5 m lattice (cell centres tie between four), no point in x 130..165 (astride the window's east edge)."""
    g = np.arange(0.25, 200, 0.5)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    keep = ~((x > 130) & (x < 165))
    x, y = x[keep], y[keep]
    return np.column_stack((X0 + x, Y0 + y, 600 + np.sin(x / 7) + np.cos(y / 5)))


@pytest.mark.parametrize(
    ("make", "reach"), [(_random_with_gap, 12.0), (_lattice_with_band, 30.0)], ids=["gap", "lattice"]
)
@pytest.mark.parametrize("method", ["idw", "nearest"])
def test_the_tree_of_the_near_points_gives_the_bytes_of_the_tree_of_all(make, reach, method, monkeypatch):
    points = make()
    grid = Grid.covering(X0, Y0, X0 + 200, Y0 + 200, 1.0)
    window = grid.window(40, 160, 50, 150)  # x 50..150, y 40..160 of the survey
    f = idw if method == "idw" else nearest
    every = f(points, window, nodata_distance=reach, margin=None)
    asked = []
    real = interpolate.canonical_neighbours
    monkeypatch.setattr(
        interpolate, "canonical_neighbours", lambda tree, q, *a: asked.append((tree.n, len(q))) or real(tree, q, *a)
    )
    near = f(points, window, nodata_distance=reach, margin=10.0)
    assert near.tobytes() == every.tobytes()
    if make is _random_with_gap:
        assert np.isnan(every).sum() > 100  # cells farther than nodata_distance from any point, in the gap
    else:  # cells whose near points in the window's region lie across the band, the nearest beyond the region
        assert not np.isnan(every).any()
    trees = sorted({n for n, _ in asked})
    assert len(trees) == 2 and trees[1] == len(points)  # the near tree first, every point's for a few cells
    again = sum(m for n, m in asked if n == len(points))
    assert 0 < again < 0.2 * window.rows * window.cols
