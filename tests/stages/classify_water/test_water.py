"""Water found in the points and given by polygons: known answers from geometry (issue 34)."""

from __future__ import annotations

import numpy as np
import pytest

from stages.classify_water.params import DetectParams
from stages.classify_water.water import (
    cell_moments,
    cells_of,
    could_be_level,
    inside_polygons,
    level_and_mean,
    level_cells,
    lowest,
    reach,
    water_bodies,
    water_from_points,
    water_from_polygons,
    window_planes,
)

#: The lake of :func:`_valley`: centre, radius (m) and water level.
CENTRE, RADIUS, LEVEL = (60.0, 60.0), 25.0, 100.6


def _detect(**changes) -> dict:
    return DetectParams(**changes).model_dump(exclude={"enabled", "min_bank"})  # min_bank: the bodies step


def _valley(seed: int = 0, tilt: float = 0.0, density: float = 2.0, noise: float = 0.02):
    """A 120 m square valley whose sides rise at 4 % and more, a round lake in it (level, or tilted by *tilt*).

    Returns the points (all ground, class 2) and which of them are on the lake.
    """
    rng = np.random.default_rng(seed)
    n = int(120 * 120 * density)
    x, y = rng.uniform(0, 120, n), rng.uniform(0, 120, n)
    dx, dy = x - CENTRE[0], y - CENTRE[1]
    lake = np.hypot(dx, dy) < RADIUS
    z = 100.0 + 0.04 * (np.abs(dx) + np.abs(dy))  # at least 101.0 on the shore: 0.4 m above the water
    z = np.where(lake, LEVEL + tilt * dx, z) + rng.normal(0, noise, n)
    return np.column_stack((x, y, z)), lake


def test_window_planes_of_a_plane_give_its_slope_and_no_residual():
    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 20, (4000, 2)) + 440_000.0  # far from the origin, as projected coordinates are
    z = 700.0 + 0.03 * (xy[:, 0] - 440_000.0) - 0.04 * (xy[:, 1] - 440_000.0)
    i, j, shape = cells_of(xy, 1.0)
    planes = window_planes(i, j, shape, xy, z, 1.0, 3)
    inner = planes["window"] > 440  # whole windows: 49 cells of 10 points
    assert inner.sum() > 50
    np.testing.assert_allclose(planes["slope"][inner], 0.05, atol=1e-9)  # hypot(0.03, 0.04)
    assert np.nanmax(planes["rms"][inner]) < 1e-7
    assert np.all(planes["spread"][inner] > 1.5)  # a 7 m window filled: about 7 / sqrt(12) = 2 m


def test_window_planes_rms_is_the_noise_about_the_plane():
    rng = np.random.default_rng(2)
    xy = rng.uniform(0, 30, (30_000, 2))
    z = 50.0 + 0.01 * xy[:, 0] + rng.normal(0, 0.05, len(xy))
    i, j, shape = cells_of(xy, 1.0)
    planes = window_planes(i, j, shape, xy, z, 1.0, 3)
    inner = planes["window"] > 1000
    assert abs(np.median(planes["rms"][inner]) - 0.05) < 0.003
    assert abs(np.median(planes["slope"][inner]) - 0.01) < 0.002


def test_a_level_lake_in_a_valley_is_water_and_nothing_else():
    xyz, lake = _valley()
    cls = np.full(len(xyz), 2, np.uint8)
    found = water_from_points(xyz, cls, np.ones(len(xyz), bool), **_detect())
    assert found[lake].all()  # every echo of the lake, its shore included (grown)
    assert not found[~lake].any()  # the shore rises 0.4 m at once: none of it


def test_a_tilted_surface_is_not_water():
    xyz, _ = _valley(tilt=0.02)  # a 2 % slope: a road's cross-fall, not water
    found = water_from_points(xyz, np.full(len(xyz), 2, np.uint8), np.ones(len(xyz), bool), **_detect())
    assert not found.any()


def test_rough_ground_at_one_level_is_not_water():
    xyz, _ = _valley(noise=0.25)  # a level field of boulders: 0.25 m about its plane
    found = water_from_points(xyz, np.full(len(xyz), 2, np.uint8), np.ones(len(xyz), bool), **_detect())
    assert not found.any()


@pytest.mark.parametrize(("side", "kept"), [(12.0, False), (24.0, True)])
def test_a_level_patch_is_water_only_above_the_minimum_area(side, kept):
    """Level cells are those whose whole window is level: a square patch of side s has about (s - 6)**2 m2 of them,
    36 m2 for 12 m (under the 70 m2 minimum), 324 m2 for 24 m."""
    rng = np.random.default_rng(3)
    x, y = rng.uniform(0, 60, 8000), rng.uniform(0, 60, 8000)
    patch = (np.abs(x - 30) < side / 2) & (np.abs(y - 30) < side / 2)
    z = np.where(patch, 99.0, 100.0 + 0.05 * np.hypot(x - 30, y - 30)) + rng.normal(0, 0.02, len(x))
    found = water_from_points(
        np.column_stack((x, y, z)), np.full(len(x), 2, np.uint8), np.ones(len(x), bool), **_detect()
    )
    assert found[patch].mean() > 0.99 if kept else not found.any()


def test_only_unclassified_and_ground_points_become_water():
    xyz, lake = _valley()
    cls = np.full(len(xyz), 2, np.uint8)
    boat = lake & (np.hypot(xyz[:, 0] - 60, xyz[:, 1] - 60) < 2)
    cls[boat] = 6  # a class another stage gave: kept
    withheld = np.zeros(len(xyz), bool)
    withheld[np.flatnonzero(lake)[:10]] = True
    found = water_from_points(xyz, cls, ~withheld, **_detect())
    assert not found[boat].any() and not found[withheld].any()
    assert found[lake & ~boat & ~withheld].all()


def test_reach_covers_the_window_the_growth_and_the_minimum_area():
    assert reach(1.0, 3.0, 70.0, 4.0) == 4.0 + 3.0 + 2.0 + 70.0 + 1.0
    assert reach(2.0, 4.0, 100.0, 0.0) == 4.0 + 4.0 + 50.0 + 1.0


def test_inside_polygons_leaves_out_the_holes():
    outer = np.array([[0, 0], [10, 0], [10, 10], [0, 10], [0, 0]], float)
    hole = np.array([[4, 4], [6, 4], [6, 6], [4, 6], [4, 4]], float)
    far = outer + 20.0
    pts = np.array([[2, 2], [5, 5], [11, 5], [25, 25], [15, 15]], float)
    np.testing.assert_array_equal(inside_polygons(pts, [[outer, hole], [far]]), [True, False, False, True, False])


def test_polygons_make_water_the_points_near_the_level_inside_them():
    xyz, lake = _valley()
    cls = np.full(len(xyz), 2, np.uint8)
    d = np.hypot(xyz[:, 0] - 60, xyz[:, 1] - 60)
    inside = d < RADIUS + 5.0  # the polygon takes 5 m of shore too: 0.4 m above the water and more
    found = water_from_polygons(xyz, cls, np.ones(len(xyz), bool), inside, cell_size=1.0, window=10.0, height=0.3)
    np.testing.assert_array_equal(found, lake)


@pytest.mark.parametrize("density", [2.0, 0.5, 0.2, 0.05])
def test_planes_are_skipped_only_where_no_body_could_be_found(density):
    """could_be_level is False only when fewer cells than a body's smallest area could be level; then the full
    fit finds no water either.  The lake of _valley at 2, 0.5, 0.2 and 0.05 points per m²."""
    xyz, _ = _valley(density=density)
    p = DetectParams()
    i, j, shape = cells_of(xyz[:, :2], p.cell_size)
    half = int(np.ceil(p.window / p.cell_size))
    min_cells = p.min_area / p.cell_size**2
    planes = window_planes(i, j, shape, xyz[:, :2], xyz[:, 2], p.cell_size, half)
    level = level_cells(planes, cell=p.cell_size, min_points=p.min_points, max_slope=p.max_slope, max_rms=p.max_rms)
    found = water_bodies(level, planes["mean"], step=p.step, min_cells=min_cells).any()
    possible = could_be_level(i, j, shape, half, p.min_points, min_cells)
    assert possible or not found  # never skips a body
    assert possible == (int((planes["window"] >= p.min_points).sum()) >= min_cells)
    if density <= 0.05:
        assert not possible  # 0.05 points per m²: 2.5 in a 7 m window, fewer than 10


def test_window_planes_equal_a_least_squares_fit_of_each_window():
    """Terraces a few metres high at a survey's heights and coordinates: per cell, the slope, RMS and spread of
    numpy's least-squares plane through the points of its 7 x 7 cells (fitted here point by point)."""
    rng = np.random.default_rng(5)
    xy = rng.uniform(0, 25, (6000, 2))
    z = 1480.0 + np.floor(xy[:, 0] / 4.0) * 1.7 + 0.02 * xy[:, 1] + rng.normal(0, 0.03, len(xy))
    xy = xy + 440_000.0
    i, j, shape = cells_of(xy, 1.0)
    planes = window_planes(i, j, shape, xy, z, 1.0, 3)
    checked = 0
    for a, b in rng.integers(0, shape, (40, 2)):
        near = (np.abs(i - a) <= 3) & (np.abs(j - b) <= 3)
        p = np.column_stack((xy[near] - xy[near].mean(axis=0), z[near] - z[near].mean()))
        design = np.column_stack((p[:, :2], np.ones(len(p))))
        coef, *_ = np.linalg.lstsq(design, p[:, 2], rcond=None)
        rms = np.sqrt(np.mean((p[:, 2] - design @ coef) ** 2))
        narrow = np.sqrt(np.linalg.eigvalsh(np.cov(p[:, :2].T, bias=True))[0])
        assert planes["window"][a, b] == near.sum()
        np.testing.assert_allclose(planes["slope"][a, b], np.hypot(*coef[:2]), rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(planes["rms"][a, b], rms, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(planes["spread"][a, b], narrow, rtol=1e-9)
        checked += 1
    assert checked == 40


@pytest.mark.parametrize("rows", [1, 7, 40])
def test_level_cells_in_bands_equal_the_whole_grid(rows):
    """The lake of _valley: level cells and mean heights fitted a band of *rows* rows at a time are, bit for bit,
    those of the grid fitted whole (each band reads the window's reach of rows either side)."""
    xyz, lake = _valley(seed=3)
    p = DetectParams()
    i, j, shape = cells_of(xyz[:, :2], p.cell_size)
    k = i * shape[1] + j
    low = lowest(k, xyz[:, 2], shape[0] * shape[1])
    m = cell_moments(k, xyz[:, :2], xyz[:, 2], low, shape, p.cell_size)
    args = {"cell": p.cell_size, "half": 3, "min_points": p.min_points, "max_slope": p.max_slope, "max_rms": p.max_rms}
    whole = level_and_mean(m, low.reshape(shape), rows=shape[0], **args)
    banded = level_and_mean(m, low.reshape(shape), rows=rows, **args)
    assert whole[0].sum() > 0.5 * np.pi * RADIUS**2  # the lake is level (its windows off the shore)
    np.testing.assert_array_equal(banded[0], whole[0])
    np.testing.assert_array_equal(banded[1], whole[1])
    planes = window_planes(i, j, shape, xyz[:, :2], xyz[:, 2], p.cell_size, 3)  # the planes of the points
    np.testing.assert_array_equal(whole[1], planes["mean"])
    level = level_cells(planes, cell=p.cell_size, min_points=p.min_points, max_slope=p.max_slope, max_rms=p.max_rms)
    np.testing.assert_array_equal(whole[0], level)
