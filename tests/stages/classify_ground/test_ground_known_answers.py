"""Known answers for the ground filters' parameters, fast (issue 19).

Each case is built so that one parameter decides it, as the papers define
it: SMRF's window radius ``w_max`` (an object narrower than ``2 w_max`` is
removed, a wider one is not), its threshold ``s r c`` growing with the
radius (a smooth hill whose top curves less than ``s / c`` is ground), the harmonic
inpainting (it reproduces harmonic surfaces exactly), and PMF's
within-cell allowance ``s c`` (a plain slope gentler than ``s`` is all
ground).  References: Pingel et al. (2013), doi:10.1016/j.isprsjprs.2012.12.002;
Zhang et al. (2003), doi:10.1109/TGRS.2003.810682.
"""

from __future__ import annotations

import numpy as np
import pytest

from stages.classify_ground import surface as surface_module
from stages.classify_ground.pmf import pmf
from stages.classify_ground.smrf import smrf, walled_plateaus
from stages.classify_ground.surface import inpaint


def _ground_plane(size: float, spacing: float, seed: int, slope=(0.03, 0.01)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = np.arange(spacing / 2, size, spacing)
    x, y = (a.ravel() + rng.uniform(-0.2, 0.2, a.size) * spacing for a in np.meshgrid(g, g))
    return np.column_stack((x, y, 100.0 + slope[0] * x + slope[1] * y + rng.normal(0, 0.02, x.size)))


@pytest.mark.parametrize("half_width, removed", [(7.0, True), (12.0, False)])
def test_smrf_window_radius_is_w_max(half_width, removed):
    """w_max = 10 m: a 14 m wide building is removed, a 24 m wide one is beyond the window (its roof stays).

    The window alone, as the paper has it: the walled-plateau rule, which takes the wider one out, is off."""
    pts = _ground_plane(90.0, 0.7, 1)
    roof = (np.abs(pts[:, 0] - 45) < half_width) & (np.abs(pts[:, 1] - 45) < half_width)
    pts[roof, 2] += 7.0
    ground = smrf(pts, cell_size=1.0, slope=0.15, max_window_size=10.0, wall_height=0.0)
    inner = (np.abs(pts[:, 0] - 45) < half_width - 1.5) & (np.abs(pts[:, 1] - 45) < half_width - 1.5)
    if removed:
        assert not ground[inner].any()
        away = (np.abs(pts[:, 0] - 45) > half_width + 3) | (np.abs(pts[:, 1] - 45) > half_width + 3)
        assert ground[away].all()
    else:
        assert ground[inner].mean() > 0.9


def test_smrf_threshold_grows_with_the_window():
    """A smooth hill (4 m high, curvature 0.028 /m at the top) is ground with s = 0.15.

    The opening at radius r cuts a cap of about kappa r^2 / 2 off a top of curvature kappa, so the
    lowering from radius r - 1 to r is about kappa r c^2: the paper's threshold s r c passes any top
    with kappa < s / c, while a threshold that does not grow (s c) flags it from r > s / kappa (5 cells).
    """
    pts = _ground_plane(120.0, 0.8, 2, slope=(0.0, 0.0))
    r2 = (pts[:, 0] - 60) ** 2 + (pts[:, 1] - 60) ** 2
    pts[:, 2] += 4.0 * np.exp(-r2 / (2 * 12.0**2))
    ground = smrf(pts, cell_size=1.0, slope=0.15, max_window_size=18.0)
    assert ground.all(), f"{(~ground).sum()} hill points taken for objects"
    # and the threshold still catches a building on the same hill
    box = (np.abs(pts[:, 0] - 60) < 8) & (np.abs(pts[:, 1] - 60) < 8)
    pts[box, 2] += 5.0
    ground = smrf(pts, cell_size=1.0, slope=0.15, max_window_size=18.0)
    assert not ground[box & (r2 < 36)].any()


def test_smrf_floor_keeps_a_bridge_deck_out_of_the_dem():
    """A 6 m wide deck 2.5-4 m above a channel, its ends meeting the tops of 13.5 m banks.

    The deck is an object at every radius from 3 m, but its cells, inpainted harmonically, are
    filled with a ramp from the bank tops, and the deck's points within reach of the ramp pass the
    point test.  With the floor (the opening that flagged a cell bounds the DEM under it), no deck
    point more than 3 m from a bank is ground; within 3 m, the bank's own slope widens the point
    test's tolerance to metres (the paper's ``et + es * slope``).  Without the floor, some are.
    """
    rng = np.random.default_rng(3)
    x, y = rng.uniform([0, 0], [80, 40], (12_800, 2)).T
    z = np.where((y < 10) | (y > 30), 15.0, np.where((y < 14) | (y > 26), 1.5, 0.0))  # banks, bank band, water
    deck = (np.abs(x - 40) < 3) & (y > 10) & (y < 30)  # nothing is seen under it
    z = np.where(deck, 4.0, z) + rng.normal(0, 0.03, x.size)
    pts = np.column_stack((x, y, z))
    away = deck & (y > 13) & (y < 27)
    ground = smrf(pts)
    assert not ground[away].any(), f"{ground[away].sum()} deck points taken for ground"
    assert ground[~deck].all()
    assert smrf(pts, floor_window=0.0)[away].sum() > 20  # what the floor changes


def test_smrf_takes_a_walled_plateau_wider_than_the_window_for_a_building():
    """A 60 m x 44 m building 6 m high: no opening of radius 18 m fits inside it, so the openings keep its roof
    (95 % of its points ground without the walled-plateau rule); walled all round, it is an object.  The same
    block cut by the survey's edge could be a terrace continuing beyond it: left to the openings, as the
    surface is padded there."""
    pts = _ground_plane(150.0, 0.7, 5, slope=(0.05, 0.02))
    roof = (np.abs(pts[:, 0] - 75) < 30) & (np.abs(pts[:, 1] - 75) < 22)
    pts[roof, 2] += 6.0
    ground = smrf(pts)
    assert not ground[roof].any() and ground[~roof].all()
    assert smrf(pts, wall_height=0.0)[roof].mean() > 0.9  # what the rule changes
    pts = _ground_plane(150.0, 0.7, 6, slope=(0.05, 0.02))
    pts[pts[:, 0] > 90, 2] += 6.0  # a 6 m step across the survey: terrain on both sides
    assert smrf(pts).mean() > 0.995


def test_walled_plateaus_stand_above_their_whole_boundary_inside_the_survey():
    """A 30 x 30-cell block 6 m up, with empty cells scattered in it, is walled; cut by the survey's outer
    boundary (empty cells reaching the grid's edge), or below higher ground along one of its four sides (a
    terrace: 75 % of its boundary walled, under 80 %), it is not; nor is a 15 x 15 block when the square it
    must hold is 19 cells wide."""
    z = np.zeros((80, 80))
    z[20:50, 20:50] = 6.0
    z[22:48:6, 25:45:7] = np.nan
    block = (z == 6.0) & np.isfinite(z)
    assert (walled_plateaus(z, wall=2.0, min_width=9) == block).all()
    cut = z.copy()
    cut[:, 50:] = np.nan  # no points east of the block, up to the grid's edge
    assert not walled_plateaus(cut, wall=2.0, min_width=9).any()
    terrace = z.copy()
    terrace[20:50, 50:] = 10.0  # higher ground along the block's east side
    assert not walled_plateaus(terrace, wall=2.0, min_width=9).any()
    small = np.zeros((80, 80))
    small[30:45, 30:45] = 6.0
    assert not walled_plateaus(small, wall=2.0, min_width=9).any()
    assert walled_plateaus(small, wall=2.0, min_width=7).sum() == 225


def test_inpainting_reproduces_harmonic_surfaces():
    """The discrete Laplace equation is solved exactly by planes and by x^2 - y^2: a hole is filled with them."""
    r, c = np.mgrid[0:40, 0:50].astype(float)
    for surface in (3.0 + 0.2 * c - 0.1 * r, 0.01 * (c**2 - r**2)):
        grid = surface.copy()
        grid[8:30, 10:35] = np.nan  # a building-sized hole
        grid[20:23, 40:42] = np.nan  # and a small one
        np.testing.assert_allclose(
            inpaint(grid), surface, atol=1e-6
        )  # 1 µm: the iterative solve stops at a relative residual (INPAINT_TOL)


@pytest.mark.parametrize("cheap_steps", [0, 10_000])
def test_inpainting_is_the_same_surface_whichever_solver_ends_it(monkeypatch, cheap_steps):
    """A wide void (a lake: 140 x 150 cells to fill) in x^2 - y^2: multigrid from the start (0 cheap
    steps) and diagonally preconditioned CG alone (enough steps to converge) both fill it exactly."""
    monkeypatch.setattr(surface_module, "_CHEAP_STEPS", cheap_steps)
    r, c = np.mgrid[0:200, 0:190].astype(float)
    surface = 300.0 + 0.001 * ((c - 95) ** 2 - (r - 100) ** 2)
    grid = surface.copy()
    grid[30:170, 20:170] = np.nan
    np.testing.assert_allclose(inpaint(grid), surface, atol=1e-6)


def test_inpainting_at_the_grid_edge_has_no_flux_across_it():
    """A hole on the grid's edge: the edge cells have three neighbours (a zero normal derivative), so a
    surface that does not vary across the edge is filled exactly; counting a fourth, missing neighbour
    (zero outside the grid) pulls the fill towards zero."""
    r, c = np.mgrid[0:40, 0:50].astype(float)
    surface = 650.0 + 0.2 * c  # varies along the top and bottom edges only
    grid = surface.copy()
    grid[0:6, 10:30] = np.nan  # touching row 0
    grid[34:40, 35:45] = np.nan  # touching the last row
    np.testing.assert_allclose(
        inpaint(grid), surface, atol=1e-6
    )  # 1 µm: the iterative solve stops at a relative residual (INPAINT_TOL)


def test_inpainting_fills_every_cell_with_its_neighbours_mean():
    """Random heights with random holes, some joined into a large one at a corner (a survey's missing
    block): each filled cell is the mean of its neighbours inside the grid, the known cells unchanged."""
    rng = np.random.default_rng(3)
    grid = rng.normal(100.0, 5.0, (60, 70))
    grid[rng.random(grid.shape) < 0.1] = np.nan
    grid[35:, 45:] = np.nan  # a corner block: two edges and the known cells bound it
    filled = inpaint(grid)
    padded = np.pad(filled, 1, constant_values=np.nan)
    neighbours = np.stack((padded[:-2, 1:-1], padded[2:, 1:-1], padded[1:-1, :-2], padded[1:-1, 2:]))
    hole = np.isnan(grid)
    np.testing.assert_allclose(
        filled[hole], np.nanmean(neighbours, axis=0)[hole], rtol=0, atol=1e-6
    )  # 1 µm: the iterative solve stops at a relative residual (INPAINT_TOL)
    np.testing.assert_array_equal(filled[~hole], grid[~hole])


def test_pmf_keeps_a_plain_slope_gentler_than_s():
    """A plain 10 % slope, 2 points/m2 at random, 2 cm noise, PMF s = 0.15: every point is ground.

    A point lies up to s c above the lowest point of its cell; the paper's thresholds are for cell minima,
    so without that allowance about 0.9 % of this slope's points are rejected.
    """
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 100, 20_000), rng.uniform(0, 100, 20_000)
    pts = np.column_stack((x, y, 0.1 * x + rng.normal(0, 0.02, len(x))))
    ground = pmf(pts, cell_size=1.0, slope=0.15)
    assert ground.all(), f"{(~ground).sum()} of {len(pts)} points of the slope rejected"
