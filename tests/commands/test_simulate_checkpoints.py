"""The simulator's check points: where the lines recorded ground, clear of structures, spread over the survey."""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull

from commands.simulate import scene as sc
from commands.simulate.truth import _checkpoint_places


def _scene(cell: float = 1.0, size: int = 200) -> sc.Scene:
    """Flat open ground 200 m x 200 m; a building at 40-60 m x 40-60 m; trees over the east quarter."""
    ground = np.zeros((size, size))
    solid = ground.copy()
    canopy = ground.copy()
    cls = np.full((size, size), sc.GROUND, dtype=np.uint8)
    cls[40:60, 40:60] = sc.BUILDING
    solid[40:60, 40:60] = 8.0
    canopy[:, 150:] = 12.0
    return sc.Scene(0.0, 0.0, cell, ground, solid, canopy, cls)


def test_check_points_lie_where_ground_was_recorded_and_spread_over_it():
    world = _scene()
    rng = np.random.default_rng(7)
    # ground echoes on a lattice of 0.5 m over x 20-180 m, y 20-180 m (a scanned block)
    g = np.arange(20.0, 180.0, 0.5)
    ground_xy = np.column_stack([a.ravel() for a in np.meshgrid(g, g)])
    rows = _checkpoint_places(world, ground_xy, 30, rng)
    xy = np.array([(e, n) for e, n, _ in rows])
    covers = [c for *_, c in rows]
    assert len(rows) == 30 and covers.count("vegetated") == 10
    assert (xy >= 23.0 - 1.0).all() and (xy <= 177.0 + 1.0).all()  # 3 m inside the recorded block (a cell's jitter)
    building = (xy[:, 0] > 35.0 - 1) & (xy[:, 0] < 65.0 + 1) & (xy[:, 1] > 35.0 - 1) & (xy[:, 1] < 65.0 + 1)
    assert not building.any()  # 5 m clear of the building
    veg = np.array(covers) == "vegetated"
    assert (xy[veg, 0] >= 150.0 - 1).all() and (xy[~veg, 0] < 150.0 + 1).all()
    # spread: the hull reaches over 80 % of the block, the nearest two are over 10 m apart
    assert ConvexHull(xy).volume > 0.8 * 154.0**2
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    assert d[np.triu_indices(30, 1)].min() > 10.0


def test_no_ground_recorded_no_check_point():
    assert _checkpoint_places(_scene(), np.zeros((0, 2)), 10, np.random.default_rng(0)) == []
