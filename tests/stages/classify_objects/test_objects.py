"""Buildings and vegetation on hand-made clouds whose answer is known from their geometry."""

from __future__ import annotations

import numpy as np
import pytest

from lidar.grid import Grid
from stages.classify_objects.objects import ObjectCells, banded_residual, object_classes, plane_residual, point_classes
from stages.classify_objects.params import ClassifyObjectsParams

PARAMS = ClassifyObjectsParams()


def _cloud(z_of, size: float = 80.0, density: float = 6.0, seed: int = 3):
    """Points on a surface ``z_of(x, y)`` (uniform in plan), 3 cm of noise; classes 2, single returns."""
    rng = np.random.default_rng(seed)
    n = int(size * size * density)
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    z = z_of(x, y) + rng.normal(0, 0.03, n)
    return np.column_stack((x, y, z)), np.full(n, 2, np.uint8), np.ones(n, np.uint8)


def _classes(xyz, cls, nret, multi_echo=False, params=PARAMS):
    new, _ = object_classes(xyz, cls, nret, np.ones(len(cls), bool), params, 1.0, multi_echo)
    return new


def _block(x, y):
    return (np.abs(x - 40) < 12) & (np.abs(y - 40) < 9)


def test_plane_residual_sees_a_step_and_not_a_slope():
    z = np.add.outer(np.arange(6.0), 0.7 * np.arange(6.0))  # a 35-degree plane: residual 0
    assert np.nanmax(plane_residual(z)) < 1e-6  # float cancellation
    z[:, 3:] += 3.0  # a 3 m wall between columns 2 and 3
    r = plane_residual(z)
    assert np.all(r[1:-1, 2:4] > 0.5)
    hole = z.copy()
    hole[0:2, 0:2] = np.nan  # a corner cell with 5 of 9 neighbours: no plane
    assert np.isnan(plane_residual(hole)[0, 0]) and np.isfinite(plane_residual(hole)[2, 2])


def test_a_roof_taken_for_ground_leaves_class_2():
    # a 24 m x 18 m flat roof 6 m above a gentle slope, every point called ground by the filter
    xyz, cls, nret = _cloud(lambda x, y: 100 + 0.05 * x + 6.0 * _block(x, y))
    new = _classes(xyz, cls, nret)
    roof = _block(xyz[:, 0], xyz[:, 1])
    inner = (np.abs(xyz[:, 0] - 40) < 11) & (np.abs(xyz[:, 1] - 40) < 8)
    assert np.all(new[inner] == 6)
    assert np.mean(new[roof] == 6) > 0.97
    assert np.all(new[~roof] == 2)  # the ground around keeps its class


@pytest.mark.parametrize("called_ground", [0.25, 0.75])
def test_on_cells_too_wide_to_see_walls_the_filters_terrain_is_no_roof(called_ground):
    """The roof of test_a_roof_taken_for_ground_leaves_class_2 with a share of its points called ground by the
    filter, the rest left (1).  On the grid of a sparse survey (4 m cells, wider than FACE_CELL = 1 m) a region
    the filter called mostly ground is terrain (TERRAIN_SHARE = 0.5): a plateau keeps its classes; a minority
    is a roof the filter partly took, and all of it becomes 6.  On 1 m cells its walls tell: 6 either way."""
    xyz, cls, nret = _cloud(lambda x, y: 100.0 + 6.0 * _block(x, y))
    roof = _block(xyz[:, 0], xyz[:, 1])
    left = roof & (np.random.default_rng(11).uniform(size=len(cls)) >= called_ground)  # not _cloud's seed
    cls[left] = 1
    for cell, terrain in ((4.0, called_ground > 0.5), (1.0, False)):
        new, _ = object_classes(xyz, cls, nret, np.ones(len(cls), bool), PARAMS, cell, False)
        built = np.mean(new[roof] == 6)
        assert built < 0.03 if terrain else built > 0.9, cell
        assert (np.mean(new[roof & ~left] == 2) > 0.97) == terrain, cell
        assert np.mean(new[~roof & (cls == 2)] == 2) > 0.95


def test_a_gabled_roof_left_by_the_filter_is_a_building():
    def z(x, y):
        ridge = 6.0 + 3.0 - 0.5 * np.abs(y - 40)  # 27-degree pitches from a 9 m ridge to 4.5 m eaves
        return 100 + np.where(_block(x, y), ridge, 0.0)

    xyz, cls, nret = _cloud(z)
    roof = _block(xyz[:, 0], xyz[:, 1])
    cls[roof] = 1
    new = _classes(xyz, cls, nret)
    assert np.mean(new[roof] == 6) > 0.95
    assert np.all(new[~roof] == 2)


@pytest.mark.parametrize(
    "surface",
    [
        # a 3 m terrace: the upper level joins the slope above it; the riser is 45 degrees
        lambda x, y: 100 + 0.1 * x + np.clip(x - 40, 0, 3),
        # a flat-topped hill: a 30 m plateau 5 m up, 30-degree flanks
        lambda x, y: 100 + np.clip(5.0 - 0.58 * (np.maximum(np.abs(x - 40), np.abs(y - 40)) - 15), 0, 5),
        # an embankment: a road 4 m up, 1:1.5 sides
        lambda x, y: 100 + np.clip(4.0 - (np.abs(x - 40) - 5) / 1.5, 0, 4),
    ],
    ids=["terrace", "flat-topped hill", "embankment"],
)
@pytest.mark.parametrize("multi", [False, True], ids=["single-echo survey", "multi-echo survey"])
def test_terrain_is_no_building(surface, multi):
    xyz, cls, nret = _cloud(surface)
    assert np.all(_classes(xyz, cls, nret, multi_echo=multi) == 2)


def _wall_at_the_edge(upper: float | None):
    """A field (z 100, y < 40, class 2) ending at a 6 m wall along y = 40 seen from the field (class 1, single
    returns); beyond it nothing (*upper* None: a roof out of the survey) or a level *upper* m up, seen, wider
    than the widest building (terrain)."""
    rng = np.random.default_rng(5)
    xyz, cls, nret = _cloud(lambda x, y: 100 + 0 * x, size=130.0)
    field = xyz[:, 1] < 40
    n = 4000
    wall = np.column_stack((rng.uniform(10, 120, n), 40 + rng.normal(0, 0.03, n), 100 + rng.uniform(0, 6, n)))
    parts = [(xyz[field], cls[field]), (wall, np.ones(n, np.uint8))]
    if upper is not None:
        top, tcls, _ = _cloud(lambda x, y: 100 + upper + 0 * x, size=130.0, seed=6)
        beyond = top[:, 1] > 40
        parts.append((top[beyond], tcls[beyond]))
    xyz = np.vstack([p[0] for p in parts])
    cls = np.concatenate([p[1] for p in parts])
    return xyz, cls, np.ones(len(cls), np.uint8), len(parts[0][1]) + np.arange(n)


def test_a_wall_whose_roof_lies_beyond_the_survey_is_a_building():
    xyz, cls, nret, on = _wall_at_the_edge(None)
    new = _classes(xyz, cls, nret, multi_echo=True)
    assert np.mean(new[on][xyz[on, 2] >= 100.6] == 6) > 0.97
    assert not np.any(new[on][xyz[on, 2] < 100.4] == 6)  # the wall's foot stays (WALL_FOOT, 0.5 m)
    field = np.ones(len(cls), bool)
    field[on] = False
    assert np.all(new[field] == 2)  # the field keeps its class


@pytest.mark.parametrize("upper", [6.0, 3.0], ids=["level with its top", "a 3 m terrace"])
def test_a_wall_with_its_top_seen_is_no_lone_wall(upper):
    xyz, cls, nret, on = _wall_at_the_edge(upper)
    if upper < 6.0:  # a terrace's riser is as high as the terrace
        keep = np.ones(len(cls), bool)
        keep[on[xyz[on, 2] > 100 + upper]] = False
        xyz, cls, nret = xyz[keep], cls[keep], nret[keep]
    assert not np.any(_classes(xyz, cls, nret, multi_echo=True) == 6)


def test_a_small_object_stays_1():
    # a car: planar, single returns, in a survey with several returns per pulse (in a single-return survey its
    # rough edges make it low vegetation: docs/stages/classify_objects.md)
    car = lambda x, y: (np.abs(x - 40) < 2.2) & (np.abs(y - 40) < 0.9)  # noqa: E731
    xyz, cls, nret = _cloud(lambda x, y: 100 + 1.5 * car(x, y))
    on = car(xyz[:, 0], xyz[:, 1])
    cls[on] = 1
    new = _classes(xyz, cls, nret, multi_echo=True)
    assert np.all(new[on] == 1) and np.all(new[~on] == 2)


def _trees(multi: bool):
    """A flat field with a domed 14 m crown (radius 5 m) seen at every height; with *multi*, half are 2nd returns."""
    rng = np.random.default_rng(8)
    xyz, cls, nret = _cloud(lambda x, y: 100 + 0 * x)
    n = 3000
    r, a = 5 * np.sqrt(rng.uniform(0, 1, n)), rng.uniform(0, 2 * np.pi, n)
    top = 14.0 * np.sqrt(1.0 - (r / 5.0) ** 2)
    crown = np.column_stack((40 + r * np.cos(a), 40 + r * np.sin(a), 100 + rng.uniform(0.2, 1.0, n) * top))
    crown_ret = np.where(rng.uniform(0, 1, n) < 0.5, 2, 1).astype(np.uint8) if multi else np.ones(n, np.uint8)
    return (
        np.vstack((xyz, crown)),
        np.concatenate((cls, np.ones(n, np.uint8))),
        np.concatenate((nret, crown_ret)),
        crown[:, 2] - 100,
    )


@pytest.mark.parametrize("multi", [True, False], ids=["several returns", "single returns"])
def test_vegetation_by_height(multi):
    xyz, cls, nret, height = _trees(multi)
    new = _classes(xyz, cls, nret, multi_echo=multi)[-len(height) :]
    expected = np.select([height >= 5.0, height >= 2.0, height >= 0.5], [5, 4, 3], 1)
    assert np.mean(new == expected) > 0.95
    assert not np.any(new == 6)
    assert np.all(_classes(xyz, cls, nret, multi_echo=multi)[: -len(height)] == 2)


def test_disabled_parts_leave_classes():
    xyz, cls, nret = _cloud(lambda x, y: 100 + 6.0 * _block(x, y))
    off = ClassifyObjectsParams.model_validate({"buildings": {"enabled": False}})
    assert np.all(_classes(xyz, cls, nret, params=off) == 2)
    with pytest.raises(ValueError, match="ascending"):
        ClassifyObjectsParams.model_validate({"vegetation": {"breaks": [2.0, 0.5, 5.0]}})


@pytest.mark.parametrize("rows", [1, 2, 7, 256])
def test_the_residual_in_bands_of_rows_is_the_residual_of_the_whole_grid(rows):
    rng = np.random.default_rng(1)
    z = np.cumsum(rng.normal(size=(300, 40)), axis=1)  # rough, sloping rows
    z[rng.random(z.shape) < 0.2] = np.nan  # holes: cells with fewer than 6 of 9 neighbours at band edges too
    np.testing.assert_array_equal(banded_residual(z, rows), plane_residual(z))


def _without_and_with_return_numbers(xyz, cls, rn, nr):
    """The classes without the return numbers (every return a last one, none known as first) and with them."""
    usable = np.ones(len(cls), bool)
    without, _ = object_classes(xyz, cls, nr, usable, PARAMS, 1.0, True)
    return without, object_classes(xyz, cls, nr, usable, PARAMS, 1.0, True, return_number=rn)[0]


def _roof_under_a_crown(seed: int = 11):
    """A flat roof 5 m up (20 m x 20 m, walls to the ground at 100 m) with a tree's crown (radius 5 m, 10-13 m up)
    over its middle: 6 pulses per m²; under the crown each pulse returns twice, first from the crown and last
    from the roof.  Returns the points, classes (ground 2, the rest 1), return numbers, numbers of returns and
    masks of the roof's echoes under the crown and of the crown's."""
    rng = np.random.default_rng(seed)
    n = 80 * 80 * 6
    x, y = rng.uniform(0, 80, n), rng.uniform(0, 80, n)
    roof = (np.abs(x - 40) < 10) & (np.abs(y - 40) < 10)
    z = np.where(roof, 105.0, 100.0) + rng.normal(0, 0.03, n)
    crown = np.hypot(x - 40, y - 40) < 5.0
    nret = np.where(crown, 2, 1).astype(np.uint8)
    last = np.column_stack((x, y, z))
    first = np.column_stack((x[crown], y[crown], rng.uniform(110.0, 113.0, crown.sum())))
    xyz = np.vstack((last, first))
    cls = np.concatenate((np.where(roof, 1, 2), np.ones(crown.sum()))).astype(np.uint8)
    rn = np.concatenate((nret, np.ones(crown.sum(), np.uint8)))
    nr = np.concatenate((nret, np.full(crown.sum(), 2, np.uint8)))
    under = np.concatenate((roof & crown, np.zeros(crown.sum(), bool)))
    crowns = np.concatenate((np.zeros(n, bool), np.ones(crown.sum(), bool)))
    return xyz, cls, rn, nr, under, crowns


def test_a_roof_under_a_crown_is_seen_through_its_last_returns():
    """The crown's echoes make the roof's cells under it rough on the surface of every return: they are no roof,
    and the roof's echoes there become vegetation.  On the surface of the last returns they are the roof's: its
    echoes there are the building's, the crown's above them are not."""
    xyz, cls, rn, nr, under, crowns = _roof_under_a_crown()
    without, new = _without_and_with_return_numbers(xyz, cls, rn, nr)
    assert np.mean(without[under] == 6) < 0.5
    assert np.mean(new[under] == 6) > 0.95
    assert np.mean(new[crowns] == 6) < 0.01 and np.mean(np.isin(new[crowns], (3, 4, 5))) > 0.95


def _eaves_and_a_tree(seed: int = 12):
    """A flat roof 5 m up (20 m x 20 m) whose eaves overhang its walls by 0.6 m: a pulse on an eave returns from
    it first and from the ground last; trees' crowns (1.9 m x 8 m, 7-9 m up) beside its west eave, their pulses
    returning from the crown first and the ground last.  6 pulses per m².  Returns the points, classes (ground 2,
    the rest 1), return numbers, numbers of returns, and masks of the eaves' first returns and the crown's."""
    rng = np.random.default_rng(seed)
    n = 80 * 80 * 6
    x, y = rng.uniform(0, 80, n), rng.uniform(0, 80, n)
    d = np.maximum(np.abs(x - 40), np.abs(y - 40))
    roof, eave = d < 10.0, (d >= 10.0) & (d < 10.6)
    crown = (x >= 27.5) & (x < 29.4) & (np.abs(y - 40.0) < 4.0)  # a row of crowns from the eaves' edge on
    split = eave | crown
    ground = np.column_stack((x, y, np.where(roof, 105.0, 100.0) + rng.normal(0, 0.03, n)))
    tops = np.where(eave, 105.0 + rng.normal(0, 0.03, n), rng.uniform(107.0, 109.0, n))[split]
    xyz = np.vstack((ground, np.column_stack((x[split], y[split], tops))))
    m = int(split.sum())
    cls = np.concatenate((np.where(roof, 1, 2), np.ones(m))).astype(np.uint8)
    rn = np.concatenate((np.where(split, 2, 1), np.ones(m))).astype(np.uint8)
    nr = np.concatenate((np.where(split, 2, 1), np.full(m, 2))).astype(np.uint8)
    first = np.concatenate((np.zeros(n, bool), np.ones(m, bool)))
    return (
        xyz,
        cls,
        rn,
        nr,
        first & np.concatenate((np.zeros(n, bool), eave[split])),
        first & np.concatenate((np.zeros(n, bool), crown[split])),
    )


def test_a_pulse_split_at_the_eave_is_the_roofs_and_a_crown_beside_it_is_not():
    """Beside a roof only single returns were taken (a tree by a wall returns several times), so the eaves' first
    returns, at the roof's height, became vegetation.  A first return within max(min_height / 2, cell) of the roof
    beside it is the roof's; the crowns' beside the eave, 2-4 m above the roof, stay vegetation."""
    xyz, cls, rn, nr, eaves, crown = _eaves_and_a_tree()
    without, new = _without_and_with_return_numbers(xyz, cls, rn, nr)
    assert np.mean(without[eaves] == 6) < 0.1
    assert np.mean(new[eaves] == 6) > 0.9
    assert np.mean(new[crown] == 6) < 0.01 and np.mean(np.isin(new[crown], (3, 4, 5))) > 0.95


@pytest.mark.parametrize(("min_height", "reach"), [(2.0, 1.0), (4.0, 2.0)])
def test_an_eaves_first_return_is_the_roofs_within_half_min_height(min_height, reach):
    """Hand-made cells: a roof cell (top 105 m) and the edge cell beside it.  There, of two-return pulses, the
    first returns within max(min_height / 2, cell) of the roof's 105 m are the building's; higher ones, and last
    returns at any height, are not.  Ground under the edge cell: 100 m."""
    grid = Grid(0.0, 1.0, 1.0, 2, 1)
    cells = ObjectCells(
        grid,
        roofs=np.array([[True, False]]),
        edges=np.array([[True, True]]),
        ground=np.full((1, 2), 100.0),
        rough=np.zeros((1, 2), bool),
        decks=np.zeros((1, 2), bool),
        deck_top=np.full((1, 2), np.inf),
        roof_top=np.full((1, 2), np.inf),
        eave=np.array([[np.nan, 105.0]]),
    )
    z = 105.0 + np.array([-1.4, -0.6, 0.0, 0.6, 1.4, 1.9, 2.6, 0.0])
    rn = np.array([1, 1, 1, 1, 1, 1, 1, 2])
    params = ClassifyObjectsParams(buildings={"min_height": min_height})
    k = np.ones(len(z), np.int64)  # all in the edge cell
    new, _ = point_classes(cells, k, np.ones(len(z), np.uint8), z, np.full(len(z), 2), params, rn)
    expected = (np.abs(z - 105.0) <= reach) & (rn == 1)
    np.testing.assert_array_equal(new == 6, expected)
