"""SMRF at the survey's edge beside a building (issue 16: a band of missed ground along one edge).

The openings see the survey's edges through the padding, which continues the
slope of the last ``w_max`` cells before each edge (:func:`stages.classify_ground.surface.pad_linear`).
A least-squares line through those cells was tilted by a building among them:
its roof, 8 m up, made the ground seem to fall towards the edge, so the
padding dropped away from ground that in fact rises to it, and the opening
took the last metre for an object.  The line under the cells (their lower
hull at the band's middle) is not tilted by what stands on the ground.
"""

from __future__ import annotations

import numpy as np

from stages.classify_ground.smrf import smrf
from stages.classify_ground.surface import pad_linear


def test_ground_rising_to_the_edge_beyond_a_building_stays_ground():
    """A 16 % slope rising to the north edge; a 17 m x 12 m building 10 m from it: every ground point is ground."""
    rng = np.random.default_rng(7)
    x, y = rng.uniform(0, 120, 60_000), rng.uniform(0, 100, 60_000)
    pts = np.column_stack((x, y, 0.16 * y + rng.normal(0, 0.03, len(x))))
    roof = (np.abs(x - 60) < 8.5) & (y > 78) & (y < 90)
    pts[roof, 2] += 8.0
    ground = smrf(pts)
    assert not ground[roof & (np.abs(x - 60) < 7) & (y > 79.5) & (y < 88.5)].any()
    missed = ~ground & ~roof
    assert missed.sum() == 0, (
        f"{missed.sum()} ground points missed, {(missed & (y > 99)).sum()} of them in the last metre"
    )


def test_edge_padding_ignores_an_object_in_the_band():
    """The padding continues the ground's slope, not a line tilted by a roof within the band (of 18 or 17 cells)."""
    for rows in (30, 29):
        r, c = np.mgrid[0:rows, 0:40].astype(float)
        ground = 0.2 * r
        grid = ground.copy()
        grid[rows - 18 : rows - 12, 10:30] += 8.0  # a roof on the far side of the top edge's band
        padded = pad_linear(grid, 18)
        expected = pad_linear(ground, 18)
        np.testing.assert_allclose(padded[-18:, 18 + 12 : 18 + 28], expected[-18:, 18 + 12 : 18 + 28], atol=1e-9)
        # a plane continues exactly
        rr = np.arange(-18, rows + 18, dtype=float)[:, None]
        np.testing.assert_allclose(expected[:, 18:-18], np.broadcast_to(0.2 * rr, (rows + 36, 40)), atol=1e-9)
