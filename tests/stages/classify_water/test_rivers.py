"""A river's hydro-flattening: flat bank to bank, falling downstream, on a straight river whose slope is known."""

from __future__ import annotations

import numpy as np
import pyproj
from affine import Affine

from lidar.units import METRE
from lidar.water_bodies import burn_levels, read_water_bodies, river_axis, water_bodies, write_water_bodies
from stages.report.acceptance import rising_rivers, unflat_water_bodies

ANGLE = np.radians(30.0)  # the river's axis, from east
ALONG = np.array([np.cos(ANGLE), np.sin(ANGLE)])
ACROSS = np.array([-ALONG[1], ALONG[0]])
SLOPE = -0.005  # 0.5 m per 100 m, falling along ALONG
CENTRE = np.array([150.0, 150.0])


def _true_level(xy: np.ndarray) -> np.ndarray:
    return 100.0 + SLOPE * ((xy - CENTRE) @ ALONG)


def _river(seed: int = 1, noise: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Water points (2 per m2) of a river 200 m long and 20 m wide, and its banks 1.5 m above it, 20 m wide."""
    rng = np.random.default_rng(seed)
    s, t = rng.uniform(-100, 100, 16_000), rng.uniform(-30, 30, 16_000)
    xy = CENTRE + np.outer(s, ALONG) + np.outer(t, ACROSS)
    z = _true_level(xy) + np.where(np.abs(t) < 10, 0.0, 1.5) + rng.normal(0, noise, len(s))
    points = np.column_stack((xy, z))
    water = np.abs(t) < 10
    return points[water], points[~water]


def _bodies(water, ground, max_spread=0.3):
    kw = {"cell": 1.0, "min_area": 200.0, "close": 2, "max_spread": max_spread, "min_bank": -np.inf}
    return water_bodies(water, ground, **kw)[0]


def _grid_levels(bodies):
    transform = Affine(1.0, 0.0, 0.0, 0.0, -1.0, 300.0)
    levels = burn_levels(
        [(b.rings if b.heights is None else _with_z(b), b.level) for b in bodies], (300, 300), transform
    )
    r, c = np.nonzero(np.isfinite(levels))
    xy = np.column_stack(transform @ (c + 0.5, r + 0.5))
    return levels, levels[r, c], xy, transform


def _with_z(body):
    return [np.column_stack((ring, z)) for ring, z in zip(body.rings, body.heights, strict=True)]


def test_a_falling_river_is_flattened_bank_to_bank_and_falls_downstream():
    bodies = _bodies(*_river())
    assert len(bodies) == 1 and bodies[0].flat and bodies[0].heights is not None
    body = bodies[0]
    assert body.spread > 0.3  # one level could not flatten it
    vertices, heights = np.concatenate(body.rings), np.concatenate(body.heights)
    seen = np.abs((vertices - CENTRE) @ ALONG) <= 100.0  # the ends reach 2 cells on past the survey, held level
    assert np.max(np.abs(heights[seen] - _true_level(vertices[seen]))) < 0.03
    _, values, xy, _ = _grid_levels(bodies)
    assert len(values) > 3000
    assert np.max(np.abs(values - _true_level(xy))) < 0.03  # the true water surface, within 3 cm
    across = (xy - CENTRE) @ ACROSS
    along = (xy - CENTRE) @ ALONG
    centre, axis = river_axis(body.rings[0])  # the river's own axis: 0.6 degrees off the true one
    order = np.argsort((xy - centre) @ axis)
    assert np.all(np.diff(values[order]) <= 0)  # never rising downstream
    assert np.max(np.diff(values[np.argsort(along)])) < 0.001  # along the true axis: under a millimetre
    same = np.abs(along - 20.0) < 0.5  # a cross-section 20 m downstream of the centre: flat bank to bank
    assert np.ptp(across[same]) > 15 and np.ptp(values[same]) < 0.006  # at most the slope over a metre


def test_water_that_neither_lies_level_nor_falls_is_not_flattened():
    water, ground = _river(noise=0.25)  # waves of 25 cm (1 sigma): 0.8 m between the 5th and 95th percentile
    (body,) = _bodies(water, ground)
    assert not body.flat and body.heights is None


def test_the_river_survives_water_gpkg_and_is_judged_by_the_acceptance(tmp_path):
    bodies = _bodies(*_river())
    path = tmp_path / "water.gpkg"
    write_water_bodies(path, bodies, crs=pyproj.CRS.from_epsg(25830), units=METRE)
    read = read_water_bodies(path, METRE)
    assert len(read) == 1 and np.ptp(read[0][0][0][:, 2]) > 0.9  # vertex heights falling 1 m over 200 m
    transform = Affine(1.0, 0.0, 0.0, 0.0, -1.0, 300.0)
    levels = burn_levels(read, (300, 300), transform)
    np.testing.assert_allclose(levels, _grid_levels(bodies)[0], atol=1e-9)  # written and read: the same surface
    dtm = np.where(np.isfinite(levels), levels, 105.0)
    assert rising_rivers(dtm, read, transform) == 0 and unflat_water_bodies(dtm, read, transform) == 0
    r, c = np.nonzero(np.isfinite(levels))
    low = np.argmin(levels[r, c])  # the river's downstream end
    bump = (np.abs(r - r[low]) < 12) & (np.abs(c - c[low]) < 12)
    dtm[r[bump], c[bump]] += 0.3  # its last metres rise 30 cm: a river that climbs
    assert rising_rivers(dtm, read, transform) == 1 and unflat_water_bodies(dtm, read, transform) == 1
    lake = [([np.column_stack((read[0][0][0][:, :2], np.full(len(read[0][0][0]), 100.0)))], 100.0)]
    assert rising_rivers(dtm, lake, transform) is None  # a lake: no river to judge


def test_a_river_cut_by_the_survey_edge_runs_on_to_it_and_its_breaklines_are_its_banks():
    (body,) = _bodies(*_river())
    along = (np.concatenate(body.rings)[:, :2] - CENTRE) @ ALONG
    assert along.min() < -100.5 and along.max() > 100.5  # 2 cells on past its last points, at both ends
    assert len(body.shores) == 2  # one line a bank, none across the cut ends
    for shore in body.shores:
        assert np.ptp((shore - CENTRE) @ ALONG) > 190
        # at the water's edge (10 m out): the outline's steps across a 30-degree bank, notches where a cell at
        # the edge caught no echo (2 per m2)
        out = np.abs((shore - CENTRE) @ ACROSS)
        assert abs(np.median(out) - 10.0) < 0.75 and np.all((out > 7.0) & (out < 13.0))


def test_a_level_bank_above_the_river_is_no_water_of_it():
    """The river's banks level, 1.5 m above its water and 10 m wide, their points taken for water too (a level
    bank looks like a pond): split from the river at the step, and refused (the river beside them is lower:
    water would drain into it)."""
    water, ground = _river()
    t = (ground[:, :2] - CENTRE) @ ACROSS
    floor = np.abs(t) < 20  # the bank floors, beside the river (its points 1.5 m above the water)
    water = np.vstack((water, ground[floor]))
    bodies, refused, _ = water_bodies(
        water, ground[~floor], cell=1.0, min_area=200.0, close=2, max_spread=0.3, min_bank=-np.inf
    )
    (body,) = bodies
    assert body.flat and body.heights is not None  # the river alone: falling, flattened
    vertices = np.concatenate(body.rings)[:, :2] - CENTRE
    inside = np.abs(vertices @ ALONG) < 99.0  # (its ends run on 2 cells past the survey's edge)
    assert np.all(np.abs(vertices[inside] @ ACROSS) < 12.0)  # at its shores (10 m, in 1 m steps), not the banks' (20)
    assert refused.holds(ground[floor][:, :2]).mean() > 0.95
