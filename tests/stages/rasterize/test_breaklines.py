"""Breaklines enforced in the TIN: a pond's shore at its water level shapes the DTM where no point was seen."""

from __future__ import annotations

import numpy as np

from lidar.grid import Grid
from lidar.water_bodies import breakline_points
from stages.rasterize.params import RasterizeParams
from stages.rasterize.products import TileCloud, tile_rasters

CENTRE, SHORE, IGNORED = np.array([25.0, 25.0]), 10.0, 12.0


def _pond(breaklines: bool) -> tuple[np.ndarray, np.ndarray]:
    """Level ground at 10 m, no point within 12 m of (25, 25): the water (dropouts) and the ignored ground
    (class 20) around its shore, a circle of 10 m at the water level, 9 m.  The DTM and each cell's distance
    from the centre."""
    rng = np.random.default_rng(4)
    xy = rng.uniform(0, 50, (10_000, 2))
    xy = xy[np.hypot(*(xy - CENTRE).T) > IGNORED]
    ground = np.column_stack((xy, np.full(len(xy), 10.0)))
    angle = np.linspace(0, 2 * np.pi, 65)
    shore = np.column_stack((CENTRE + SHORE * np.column_stack((np.cos(angle), np.sin(angle))), np.full(65, 9.0)))
    grid = Grid(0.0, 50.0, 1.0, 50, 50)
    cloud = TileCloud(ground, np.full((50, 50), 10.0), np.ones((50, 50), np.int64))
    lines = breakline_points([shore], 1.0) if breaklines else None
    crop = (slice(0, 50), slice(0, 50))
    dtm = tile_rasters(cloud, grid, grid, crop, RasterizeParams(resolution=1.0), breaklines=lines)["dtm"]
    x, y = grid.centres()
    return dtm, np.hypot(x - CENTRE[0], y - CENTRE[1])


def test_the_shore_shapes_the_dtm_where_no_point_was_seen():
    dtm, r = _pond(breaklines=True)
    assert np.all(np.abs(dtm[r < SHORE - 0.5] - 9.0) < 1e-9)  # inside the shore: its level, from it alone
    bank = (r > SHORE + 0.5) & (r < IGNORED - 0.5)  # between the shore and the first ground: a slope up
    assert np.all((dtm[bank] > 9.0) & (dtm[bank] < 10.0))
    beyond = (r > IGNORED + 1.5) & np.isfinite(dtm)  # (the grid's corners lie outside the points' hull)
    assert np.all(np.abs(dtm[beyond] - 10.0) < 1e-9)  # the ground beyond, untouched
    without, _ = _pond(breaklines=False)
    assert np.all(np.abs(without[r < IGNORED] - 10.0) < 1e-9)  # the TIN bridges the gap at the ground's height
