"""Water bodies: outlines and levels from water points (lidar.water_bodies), known answers from geometry."""

from __future__ import annotations

import numpy as np
from affine import Affine

from lidar.water_bodies import DROPOUT_SHARE, burn_levels, poisson_rate, water_bodies, wave_allowance

LEVEL = 100.0


def _lake(seed=0, radius=20.0, tilt=0.0, bank=0.4, density=2.0):
    """Water points of a round lake at (50, 50) (level, or tilted along x by *tilt*) and ground points around it,
    *bank* m above the water at the shore and rising 5 % outwards."""
    rng = np.random.default_rng(seed)
    n = int(100 * 100 * density)
    x, y = rng.uniform(0, 100, n), rng.uniform(0, 100, n)
    d = np.hypot(x - 50, y - 50)
    lake = d < radius
    z = np.where(lake, LEVEL + tilt * (x - 50), LEVEL + bank + 0.05 * (d - radius)) + rng.normal(0, 0.02, n)
    xyz = np.column_stack((x, y, z))
    return xyz[lake], xyz[~lake]


def _params(**changes):
    return {"cell": 1.0, "min_area": 200.0, "close": 2, "max_spread": 0.3, "min_bank": 0.15, **changes}


def _bodies(water, ground, **changes):
    bodies, refused, _ = water_bodies(water, ground, **_params(**changes))
    return bodies, refused


def test_a_round_lake_is_one_flat_polygon_at_its_water_level():
    water, ground = _lake()
    (body,), refused = _bodies(water, ground)
    assert not refused.mask.any()
    assert body.flat and body.points == len(water)
    assert abs(body.level - LEVEL) < 0.01  # the median of the water; the banks are higher
    # drawn in by half a cell at its shore: the area within half a cell of the shore, and not more
    assert -2 * np.pi * 20 * 0.5 < body.area - np.pi * 20**2 < 0
    assert len(body.rings) == 1
    outer = body.rings[0]
    assert np.all(np.hypot(outer[:, 0] - 50, outer[:, 1] - 50) < 21.0)
    assert np.all(2 * outer == np.round(2 * outer))  # half-cell corners: half metres
    # its shore is one closed breakline, on the outline
    (shore,) = body.shores
    assert np.array_equal(shore[0], shore[-1]) and set(map(tuple, shore)) == set(map(tuple, outer))


def test_a_level_surface_whose_banks_do_not_rise_is_no_water():
    """Paved ground, level and wide, drains away at its edges: its 'banks' lie level with it or lower."""
    water, ground = _lake(bank=-0.05)
    bodies, refused = _bodies(water, ground)
    assert bodies == [] and refused.holds(water[:, :2]).all()
    assert not refused.holds(ground[np.hypot(ground[:, 0] - 50, ground[:, 1] - 50) > 24, :2]).any()


def test_the_level_is_not_above_the_banks():
    """Banks 0.4 m above the water but for an outflow (a tenth of the shore) 0.3 m below it: the median of the
    banks rises, and the level is their 5th percentile."""
    water, ground = _lake()
    d = np.hypot(ground[:, 0] - 50, ground[:, 1] - 50)
    outflow = (ground[:, 0] > 50) & (np.abs(ground[:, 1] - 50) < 6) & (d < 26)
    ground[outflow, 2] = LEVEL - 0.3
    (body,), _ = _bodies(water, ground)
    assert LEVEL - 0.35 < body.level < LEVEL - 0.2


def test_a_falling_river_is_outlined_but_not_flat():
    water, ground = _lake(tilt=0.03, bank=1.0)  # 1.2 m over the lake's 40 m, banks 1 m above its middle
    (body,), _ = _bodies(water, ground)
    assert not body.flat and body.spread > 0.9


def test_dropouts_are_closed_and_small_patches_left_out():
    water, ground = _lake()
    keep = (np.floor(water[:, 0] / 3) % 2 == 0) | (np.floor(water[:, 1] / 3) % 2 == 0)  # 3 m holes between echoes
    (body,), _ = _bodies(water[keep], ground)
    assert len(body.rings) == 1  # no hole left
    patch = water[np.hypot(water[:, 0] - 50, water[:, 1] - 50) < 7]  # 154 m2
    assert _bodies(patch, ground)[0] == []


def test_burn_levels_takes_the_cells_whose_centre_is_inside():
    square = np.array([[2.0, 2.0], [6.0, 2.0], [6.0, 6.0], [2.0, 6.0], [2.0, 2.0]])
    hole = np.array([[3.0, 3.0], [4.0, 3.0], [4.0, 4.0], [3.0, 4.0], [3.0, 3.0]])
    grid = burn_levels([([square, hole], 7.5)], (8, 8), Affine(1.0, 0.0, 0.0, 0.0, -1.0, 8.0))
    inside = np.isfinite(grid)
    assert inside.sum() == 16 - 1 and np.all(grid[inside] == 7.5)
    assert np.isnan(grid[8 - 4, 3])  # the hole's cell: centre (3.5, 3.5)


def _sea(water_density, seed=1, bank_density=2.0, missed=0.1):
    """A round lake whose water returns *water_density* echoes per m² (the banks *bank_density*), a share
    *missed* of its echoes in 3 m patches left as ground (the windows that found none), and the lake's outer
    ring of 2 m left as ground too: undetected water at its level in the ring of banks."""
    rng = np.random.default_rng(seed)
    water, _ = _lake(seed=seed, density=water_density)
    _, ground = _lake(seed=seed + 1, density=bank_density)
    d = np.hypot(water[:, 0] - 50, water[:, 1] - 50)
    centres = rng.uniform(35, 65, (int(missed * 400 / 9) + 1, 2))
    patch = np.min(np.hypot(*(water[:, None, :2] - centres[None]).transpose(2, 0, 1)), axis=1) < 1.5
    unseen = patch | (d > 18.0)
    return water[~unseen], np.vstack((ground, water[unseen])), water[unseen]


def test_water_seen_through_dropouts_grows_through_its_unseen_level_ground():
    """A lake returning 0.3 echoes per m² beside banks of 2: its undetected echoes (its outer 2 m and patches
    inside) lie level with it in its ring, which alone would refuse it (its banks would not rise).  Grown through
    them (tolerance 0.15 m), it is one body, bank to bank, and its unseen ground is water."""
    water, ground, unseen = _sea(0.3)  # 0.15 of the banks' density
    assert _bodies(water, ground)[0] == []  # without growth: refused by its own unseen water
    bodies, refused, grown = water_bodies(water, ground, **_params(), tolerance=0.15)
    (body,) = bodies
    assert not refused.mask.any()
    level = grown.at(unseen[:, :2])
    taken = np.isfinite(level)
    assert np.all(np.abs(unseen[taken, 2] - level[taken]) <= 0.15)
    # all but a few at the shore, reached only across voids beside the banks (which the growth does not cross)
    assert taken.mean() > 0.85 and np.all(np.hypot(*(unseen[~taken, :2] - 50).T) > 17.5)
    banks = ground[np.hypot(ground[:, 0] - 50, ground[:, 1] - 50) > 21.5]
    assert not np.isfinite(grown.at(banks[:, :2])).any()  # the banks stay land
    assert np.pi * 18**2 < body.area < np.pi * 20**2  # more than its detected core, not more than the lake


def test_water_as_dense_as_its_banks_does_not_grow():
    """DROPOUT_SHARE: a lake at 0.7 of its banks' density is level land for all the rule knows (a field next to
    more field); at 0.15 it is water seen through dropouts.  Its rate is compared with the banks' Poisson rate."""
    assert DROPOUT_SHARE == 0.5
    for share, grows in ((0.15, True), (0.7, False)):
        water, ground, unseen = _sea(share * 2.0)
        _, _, grown = water_bodies(water, ground, **_params(), tolerance=0.15)
        assert np.isfinite(grown.at(unseen[:, :2])).mean() > 0.85 if grows else not np.isfinite(grown.level).any()


def test_a_tree_shadow_is_not_a_dropout():
    """The lake's middle band undetected (its echoes left as ground), with a belt 4 m wide in it where neither
    water nor ground returned: voids, which the growth crosses; under a canopy (echoes of another class there),
    a shadow, which it does not cross."""
    water, ground, _ = _sea(0.3, missed=0.0)
    x = water[:, 0]
    band, belt = np.abs(x - 50.0) < 6.0, np.abs(x - 50.0) < 2.0
    ground = np.vstack((ground, water[band & ~belt]))
    water = water[~band]
    probes = np.column_stack((np.full(21, 50.5), np.arange(40.5, 61, 1.0)))  # cells of the belt, in the lake
    canopy = np.column_stack((np.arange(48.25, 52, 0.5).repeat(80), np.tile(np.arange(30.25, 70, 0.5), 8)))
    for others, crosses in ((None, True), (canopy, False)):
        _, _, grown = water_bodies(water, ground, **_params(), tolerance=0.15, others=others)
        taken = np.isfinite(grown.at(probes)).mean()
        assert taken > 0.9 if crosses else taken == 0.0, (crosses, taken)


def test_poisson_rate_inverts_the_zero_truncated_mean():
    for rate in (0.05, 0.3, 1.2, 8.0):
        assert abs(poisson_rate(rate / (1.0 - np.exp(-rate))) - rate) < 1e-9


def test_a_noisy_lake_grows_by_its_cells_mean_heights():
    """A lake of 6 echoes per m² with 8 cm of noise (the lowest of a cell's echoes lies 0.1-0.2 m below its
    level) beside banks of 20, its outer 3 m undetected: grown through the cells whose mean lies at its level,
    and judged on the banks at or above it, it is water.  Its own unseen ring alone would refuse it."""
    rng = np.random.default_rng(7)
    n = 100 * 100 * 20
    x, y = rng.uniform(0, 100, n), rng.uniform(0, 100, n)
    d = np.hypot(x - 50, y - 50)
    lake = (d < 20.0) & (rng.uniform(size=n) < 0.3)  # 6 of 20 echoes return from the water
    bank = d >= 20.0
    z = np.where(d < 20.0, LEVEL + rng.normal(0, 0.08, n), LEVEL + 0.4 + 0.05 * (d - 20.0) + rng.normal(0, 0.02, n))
    xyz = np.column_stack((x, y, z))
    unseen = lake & (d > 17.0)
    water, ground = xyz[lake & ~unseen], np.vstack((xyz[bank], xyz[unseen]))
    assert _bodies(water, ground)[0] == []
    bodies, refused, grown = water_bodies(water, ground, **_params(), tolerance=0.15)
    assert len(bodies) == 1 and not refused.mask.any()
    assert abs(bodies[0].level - LEVEL) < 0.02
    taken = np.isfinite(grown.at(xyz[unseen, :2]))
    assert taken.mean() > 0.85  # all but cells at the shore, whose mean holds the bank's echoes too


def _rough_sea(waves: float, seed: int = 3):
    """A lake seen through dropouts (1 echo per m², banks 4) whose echoes scatter by *waves* (m, 1 sigma):
    its echoes more than 0.15 m from its level (the detector's tolerance), and its outer 2 m, left as ground."""
    rng = np.random.default_rng(seed)
    water, _ = _lake(seed=seed, density=1.0)
    _, ground = _lake(seed=seed + 1, density=4.0)
    water[:, 2] = LEVEL + rng.normal(0, waves, len(water))
    d = np.hypot(water[:, 0] - 50, water[:, 1] - 50)
    unseen = (np.abs(water[:, 2] - LEVEL) > 0.15) | (d > 18.0)
    return water[~unseen], np.vstack((ground, water[unseen])), water[unseen]


def test_wave_allowance_is_the_largest_normal_departure_of_the_echoes():
    """sqrt(2 ln n) robust sigmas: 5 cm waves over 20,000 echoes reach 0.222 m; calm water keeps the tolerance."""
    heights = np.random.default_rng(4).normal(0, 0.05, 20_000)
    assert abs(wave_allowance(heights, 0.15) - 0.05 * np.sqrt(2 * np.log(20_000))) < 0.005
    assert wave_allowance(heights / 5, 0.15) == 0.15
    assert wave_allowance(heights, 0.30) == 0.30


def test_the_crests_of_rough_water_are_water():
    """Waves of 7 cm: echoes up to 0.22 m above the level, beyond the 0.15 m tolerance, lie in the water's cells
    and are water (a 2 cm sea has no echo there: what stands 0.17 m up on it is no wave)."""
    water, ground, unseen = _rough_sea(0.07)
    _, _, grown = water_bodies(water, ground, **_params(), tolerance=0.15)
    crests = unseen[(unseen[:, 2] > LEVEL + 0.15) & (unseen[:, 2] < LEVEL + 0.22)]
    crests = crests[np.hypot(crests[:, 0] - 50, crests[:, 1] - 50) < 17.0]
    assert len(crests) >= 5
    assert grown.water(crests).all()
    calm, ground2, _ = _rough_sea(0.02)
    _, _, still = water_bodies(calm, ground2, **_params(), tolerance=0.15)
    above = np.column_stack((crests[:, :2], np.full(len(crests), LEVEL + 0.17)))
    assert np.isfinite(still.at(above[:, :2])).all() and not still.water(above).any()


def test_a_patch_refused_alone_inside_grown_water_is_that_water():
    """A 3 x 3 m patch of detected water inside a lake seen through dropouts, cut off from its detected water by
    a ring of undetected level echoes (as the simulated sea had one): alone its banks do not rise and it is
    refused; enclosed by the lake's growth it is the lake's water, and so is the dense ground around it."""
    water, ground, unseen = _sea(0.3, missed=0.0)
    d_w = np.max(np.abs(water[:, :2] - [50.0, 50.0]), axis=1)
    d_g = np.max(np.abs(ground[:, :2] - [50.0, 50.0]), axis=1)
    rng = np.random.default_rng(9)
    patch = np.column_stack((rng.uniform(48.5, 51.5, 30), rng.uniform(48.5, 51.5, 30), np.full(30, LEVEL)))
    ring = np.column_stack((rng.uniform(42, 58, 1024), rng.uniform(42, 58, 1024), np.full(1024, LEVEL)))
    ring = ring[np.max(np.abs(ring[:, :2] - [50.0, 50.0]), axis=1) > 2.0]  # dense: 4 echoes a m², level
    water = np.vstack((water[d_w > 8.0], patch))  # 6.5 m apart: the closing (2 cells) does not join them
    ground = np.vstack((ground[d_g > 8.0], ring))
    bodies, refused, grown = water_bodies(water, ground, **_params(), tolerance=0.15)
    assert len(bodies) == 1 and not refused.mask.any()
    assert grown.water(patch).all() and grown.water(ring).all()
