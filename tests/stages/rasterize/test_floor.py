"""The forest floor: under trees, ground points above the floor's lower envelope are left out of the DTM.

The scenes are built here: a sloping floor (z = 100 + 0.2 x - 0.1 y) with 3 cm
of scanner noise, understory echoes a known height above it, trees' crowns
(the highest return of a cell) 12 m up where the scene says so.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator

from lidar.grid import Grid
from stages.rasterize.floor import COVER, tin_at, understory
from stages.rasterize.params import RasterizeParams
from stages.rasterize.products import TileCloud, tile_rasters

GRID = Grid(0.0, 60.0, 1.0, 60, 60)


def floor_z(xy: np.ndarray) -> np.ndarray:
    return 100.0 + 0.2 * xy[:, 0] - 0.1 * xy[:, 1]


def _scene(*, shrubs: float = 0.3, covered: bool = True, seed: int = 1):
    """4 floor echoes and 4 understory echoes a m² over 60 m x 60 m; crowns over everything when *covered*."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0, 60, (4 * 3600, 2))
    floor = np.column_stack((xy, floor_z(xy) + rng.normal(0, 0.03, len(xy))))
    xy = rng.uniform(0, 60, (4 * 3600, 2))
    shrub = np.column_stack((xy, floor_z(xy) + shrubs + rng.uniform(-0.05, 0.05, len(xy))))
    ground = np.vstack((floor, shrub))
    x, y = GRID.centres()
    top = floor_z(np.column_stack((x.ravel(), y.ravel()))).reshape(x.shape) + (12.0 if covered else 0.4)
    return ground, top, len(floor)


def test_under_trees_the_understory_is_left_out_and_the_floor_kept():
    ground, top, n = _scene()
    out = understory(ground, top, GRID, cell=2.0, tolerance=0.15)
    assert out[n:].mean() > 0.95  # the shrubs' echoes, 0.3 m up
    assert out[:n].mean() < 0.01  # the floor, with its noise


def test_in_the_open_nothing_is_left_out():
    """The same echoes with no return more than COVER above them: errors there are the scanner's, both ways."""
    ground, top, _ = _scene(covered=False)
    assert COVER > 0.4
    assert not understory(ground, top, GRID, cell=2.0, tolerance=0.15).any()


def test_the_tolerance_decides_how_high_the_understory_begins():
    ground, top, n = _scene(shrubs=0.3)
    assert understory(ground, top, GRID, cell=2.0, tolerance=0.5)[n:].mean() < 0.01  # 0.3 m is within 0.5
    assert understory(ground, top, GRID, cell=2.0, tolerance=0.15)[n:].mean() > 0.95


def test_the_cell_must_reach_past_a_thicket_to_the_floor():
    """A thicket 5 m wide with no floor echo inside: with 2 m cells its own lowest echoes make the envelope
    there (kept); with 12 m cells every cell holds floor echoes and the thicket is left out."""
    ground, top, n = _scene(shrubs=0.4)
    inside = (np.abs(ground[:, 0] - 30.0) < 2.5) & (np.abs(ground[:, 1] - 30.0) < 2.5)
    keep = ~(inside & (np.arange(len(ground)) < n))  # no floor echo in the thicket
    ground = ground[keep]
    thicket = inside[keep] & (np.arange(len(ground)) >= n - int((~keep).sum()))
    core = thicket & (np.abs(ground[:, 0] - 30.0) < 1.0) & (np.abs(ground[:, 1] - 30.0) < 1.0)
    assert core.sum() > 10
    assert understory(ground, top, GRID, cell=2.0, tolerance=0.15)[core].mean() < 0.5
    assert understory(ground, top, GRID, cell=12.0, tolerance=0.15)[core].mean() > 0.95


def test_densification_keeps_a_ridge_under_trees():
    """A ridge 1 m high, z = exp(-(x/4)^2) (a bank under a hedge): the TIN of each 2 m cell's lowest point (built
    here with SciPy) cuts its crest off (it spans the crest between the lowest points of its flanks: 0.25 m below
    for a curvature of 0.125 /m over 4 m); the densified envelope keeps the crest."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 60, (10 * 3600, 2))
    z = 100.0 + 1.0 * np.exp(-(((xy[:, 0] - 30.0) / 4.0) ** 2))
    ground = np.column_stack((xy, z))
    top = np.full((60, 60), 130.0)
    crest = np.abs(xy[:, 0] - 30.0) < 0.5
    assert understory(ground, top, GRID, cell=2.0, tolerance=0.15)[crest].mean() < 0.05
    key = np.floor(xy[:, 0] / 2.0) * 1000 + np.floor(xy[:, 1] / 2.0)
    order = np.lexsort((z, key))
    lowest = order[np.r_[True, key[order][1:] != key[order][:-1]]]
    first = LinearNDInterpolator(xy[lowest], z[lowest])(xy[crest])
    assert np.mean(z[crest] > first + 0.15) > 0.9


@pytest.mark.parametrize("tolerance", [0.15, None])
def test_the_dtm_follows_the_floor_unless_switched_off(tolerance):
    ground, top, _ = _scene()
    cloud = TileCloud(ground, top, np.ones((60, 60), np.int64))
    crop = (slice(0, 60), slice(0, 60))
    params = RasterizeParams(resolution=1.0, floor_tolerance=tolerance)
    dtm = tile_rasters(cloud, GRID, GRID, crop, params)["dtm"]
    x, y = GRID.centres()
    error = dtm - floor_z(np.column_stack((x.ravel(), y.ravel()))).reshape(x.shape)
    inner = error[5:-5, 5:-5]
    if tolerance is None:  # every ground point: the TIN zigzags through the shrubs' echoes
        assert np.median(inner) > 0.1
    else:
        assert abs(np.median(inner)) < 0.03


def test_floor_cell_reaches_the_dtm():
    """The thicket of test_the_cell_must_reach_past_a_thicket_to_the_floor, through the DTM: on 2 m cells its
    echoes stay (the DTM 0.4 m up at its centre), on 12 m cells they are left out (the floor's height)."""
    ground, top, n = _scene(shrubs=0.4)
    inside = (np.abs(ground[:, 0] - 30.0) < 2.5) & (np.abs(ground[:, 1] - 30.0) < 2.5)
    ground = ground[~(inside & (np.arange(len(ground)) < n))]
    crop = (slice(0, 60), slice(0, 60))
    centre = {}
    for cell in (2.0, 12.0):
        cloud = TileCloud(ground, top, np.ones((60, 60), np.int64))
        dtm = tile_rasters(cloud, GRID, GRID, crop, RasterizeParams(resolution=1.0, floor_cell=cell))["dtm"]
        centre[cell] = dtm[29, 29] - floor_z(np.array([[29.5, 30.5]]))[0]
    assert centre[2.0] > 0.3 and abs(centre[12.0]) < 0.1


def test_tin_at_is_scipys_linear_tin():
    """The envelope's TIN at scattered points of a projected CRS is SciPy's LinearNDInterpolator (Qhull, an
    independent triangulator) on coordinates from a local origin, to rounding; NaN outside the hull, whatever the
    points' order.  (On the raw coordinates SciPy is off by up to 2.7 m here: Qhull's rounding.)"""
    rng = np.random.default_rng(7)
    origin = np.array([512_000.0, 4_300_000.0])
    vertices = np.column_stack((rng.uniform(0, 100, (3000, 2)) + origin, rng.normal(0, 1, 3000)))
    xy = rng.uniform(-5, 105, (40_000, 2)) + origin
    ours = tin_at(vertices, xy)
    scipy_ = LinearNDInterpolator(vertices[:, :2] - origin, vertices[:, 2])(xy - origin)
    assert np.array_equal(np.isnan(ours), np.isnan(scipy_))
    assert np.isnan(ours).sum() > 1000  # the 5 m margin lies outside the hull
    assert np.nanmax(np.abs(ours - scipy_)) < 1e-9
    order = rng.permutation(len(xy))
    assert np.array_equal(tin_at(vertices, xy[order]), ours[order], equal_nan=True)


def test_tin_at_a_plane_and_degenerate_vertices():
    """A plane is itself at every point inside (duplicate vertices dropped); vertices on a line make no TIN."""
    rng = np.random.default_rng(8)
    xy = rng.uniform(0, 50, (500, 2))
    vertices = np.column_stack((xy, 3.0 + 0.5 * xy[:, 0] - 0.25 * xy[:, 1]))
    vertices = np.concatenate((vertices, vertices[:50]))  # the same xy twice
    q = rng.uniform(10, 40, (2000, 2))
    assert np.allclose(tin_at(vertices, q), 3.0 + 0.5 * q[:, 0] - 0.25 * q[:, 1], atol=1e-9)
    line = np.column_stack((np.arange(10.0), np.arange(10.0), np.zeros(10)))
    assert np.isnan(tin_at(line, q)).all()
