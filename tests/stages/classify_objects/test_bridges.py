"""Bridge decks (17) on hand-made clouds: a deck over a channel, an embankment across a valley, a roof."""

from __future__ import annotations

import numpy as np

from stages.classify_objects.bridges import approach_ends
from stages.classify_objects.objects import object_classes
from stages.classify_objects.params import ClassifyObjectsParams

PARAMS = ClassifyObjectsParams()
C = 65.0  # the scene's centre


def _cloud(z_of, cls_of, size: float = 130.0, density: float = 5.0, seed: int = 5):
    """Points uniform in plan on ``z_of(x, y)`` (3 cm of noise), classes ``cls_of(x, y)``, single returns.

    The banks are wider than ``max_size``: a level plane cut by the survey's edge with a drop on its one
    seen side would be a roof.
    """
    rng = np.random.default_rng(seed)
    n = int(size * size * density)
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    xyz = np.column_stack((x, y, z_of(x, y) + rng.normal(0, 0.03, n)))
    return xyz, cls_of(x, y).astype(np.uint8), np.ones(n, np.uint8)


def _classes(xyz, cls, nret):
    return object_classes(xyz, cls, nret, np.ones(len(cls), bool), PARAMS, 1.0, True)[0]


def _channel(y):
    return np.abs(y - C) < 10  # a 20 m channel along x, 8 m below the banks, with vertical banks


def _deck(x, y):
    return (np.abs(x - C) < 3) & _channel(y)  # a 6 m deck across it, level with the road either side


def test_a_deck_over_a_channel_is_17_and_its_approaches_stay_ground():
    def z(x, y):
        ground = 100 + 0.02 * x
        return np.where(_channel(y) & ~_deck(x, y), 92.0, ground)

    def cls(x, y):  # the filter took the deck for ground, as SMRF does where it joins the road
        return np.where(_channel(y) & ~_deck(x, y), 9, 2)

    xyz, c, nret = _cloud(z, cls)
    new = _classes(xyz, c, nret)
    x, y = xyz[:, 0], xyz[:, 1]
    inner = (np.abs(x - C) < 2) & (np.abs(y - C) < 9)
    assert np.all(new[inner] == 17)
    deck = _deck(x, y)
    assert np.mean(new[deck] == 17) > 0.9
    assert np.all(new[~deck & (np.abs(y - C) > 11.5)] == 2)  # the banks and the road beyond the deck's ends
    assert np.all(new[_channel(y) & ~deck] == 9)  # the water keeps its class


def test_an_embankment_across_a_valley_is_not_a_bridge():
    def z(x, y):
        valley = 100 - 8.0 * np.clip(1 - np.abs(y - C) / 10, 0, None)  # V-shaped, 8 m deep
        road = 100 - np.clip(np.abs(x - C) - 3, 0, None)  # 6 m wide, 1:1 side slopes down to the valley
        return np.maximum(valley, road)

    xyz, c, nret = _cloud(z, lambda x, y: np.full(x.shape, 2))
    new = _classes(xyz, c, nret)
    assert not np.any(new == 17)


def test_a_roof_is_not_a_bridge():
    def z(x, y):
        return 100 + 6.0 * ((np.abs(x - C) < 12) & (np.abs(y - C) < 5))  # long and narrow, walls all round

    xyz, c, nret = _cloud(z, lambda x, y: np.full(x.shape, 2))
    new = _classes(xyz, c, nret)
    roof = (np.abs(xyz[:, 0] - C) < 11) & (np.abs(xyz[:, 1] - C) < 4)
    assert not np.any(new == 17)
    assert np.all(new[roof] == 6)


def test_on_cells_too_wide_to_see_walls_a_decks_ground_stays():
    """The deck of the first test, half its points left by the filter (1), on 2 m cells (wider than FACE_CELL):
    those become 17 and the ground stays 2 (an embankment over an underpass has the same drops there); on 1 m
    cells both become 17."""

    def z(x, y):
        return np.where(_channel(y) & ~_deck(x, y), 92.0, 100 + 0.02 * x)

    xyz, c, nret = _cloud(z, lambda x, y: np.where(_channel(y) & ~_deck(x, y), 9, 2))
    deck = _deck(xyz[:, 0], xyz[:, 1])
    left = deck & (np.random.default_rng(11).uniform(size=len(c)) < 0.5)  # not _cloud's seed
    c[left] = 1
    for cell, ground_kept in ((2.0, True), (1.0, False)):
        new = object_classes(xyz, c, nret, np.ones(len(c), bool), PARAMS, cell, True)[0]
        assert np.mean(new[left] == 17) > 0.9, cell
        assert np.all(new[deck & ~left] == 2) if ground_kept else np.mean(new[deck & ~left] == 17) > 0.9, cell


def _diagonal_bridge(size: float = 130.0, density: float = 5.0, seed: int = 7, bank: bool = False):
    """A 5 m deck at 45° to the grid over a 20 m channel 8 m below the land, with 1 m railings along its sides;
    its road is level with the land at both ends.

    Returns the points, the filter's classes (deck and railings 1, the land 2, the channel 9) and masks of
    the deck's surface and of its railings.  With *bank*, a riverside path 4 m wide runs 3 m below the land
    along both banks, the road crossing it at the deck's level under crowns 8 m higher (class 1): the
    approaches stand over a gap, their cells topped by the crowns, their ground at the deck's level.
    """
    rng = np.random.default_rng(seed)
    c = size / 2
    n = int(size * size * density)
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    u, v = ((x - c) + (y - c)) / np.sqrt(2), ((x - c) - (y - c)) / np.sqrt(2)  # along and across the deck
    channel = np.abs(u) < 10
    deck = (np.abs(v) < 2.5) & channel
    z = np.where(channel & ~deck, 92.0, 100.0)
    path = bank & (np.abs(u) >= 10) & (np.abs(u) < 14)
    z = np.where(path & (np.abs(v) >= 2.5), 97.0, z)
    cls = np.where(deck, 1, np.where(channel, 9, 2))
    # the railings: a point every 0.2 m along each side of the deck, 1 m above it
    t = np.arange(-10.0, 10.0, 0.2)
    ru = np.concatenate([t, t])
    rv = np.concatenate([np.full(t.shape, 2.4), np.full(t.shape, -2.4)])
    rx, ry = c + (ru + rv) / np.sqrt(2), c + (ru - rv) / np.sqrt(2)
    xyz = np.column_stack((np.r_[x, rx], np.r_[y, ry], np.r_[z, np.full(rx.shape, 101.0)]))
    xyz[:, 2] += rng.normal(0, 0.03, len(xyz))
    cls = np.r_[cls, np.ones(rx.shape, int)].astype(np.uint8)
    rail = np.r_[np.zeros(n, bool), np.ones(rx.shape, bool)]
    deck = np.r_[deck, np.zeros(rx.shape, bool)]
    if bank:
        m = int(2 * 8 * 4 * 2 * density)  # over the road where it crosses the paths: 8 m wide, 4 m deep
        tu = rng.uniform(10, 14, m) * rng.choice([-1, 1], m)
        tv = rng.uniform(-4, 4, m)
        crowns = np.column_stack((c + (tu + tv) / np.sqrt(2), c + (tu - tv) / np.sqrt(2), rng.normal(108, 1, m)))
        xyz = np.vstack((xyz, crowns))
        cls = np.r_[cls, np.ones(m, np.uint8)]
        rail, deck = np.r_[rail, np.zeros(m, bool)], np.r_[deck, np.zeros(m, bool)]
    return xyz, cls, deck, rail


def test_a_narrow_diagonal_deck_with_railings_is_17():
    """Railings put a metre's drop into most 3 x 3 windows of a deck a few cells wide: at the decks' planarity
    it is found, its pieces joined, and its points are those from its surface up; at a roof's it is not."""
    xyz, cls, deck, rail = _diagonal_bridge()
    nret = np.ones(len(cls), np.uint8)
    new = object_classes(xyz, cls, nret, np.ones(len(cls), bool), PARAMS, 1.0, True)[0]
    along = np.abs((xyz[:, 0] - 65.0) + (xyz[:, 1] - 65.0)) / np.sqrt(2)
    # its last 2 m at each end, level with the land, go with the approach (docs: a side edge beside level land)
    assert np.mean(new[deck & (along < 8)] == 17) > 0.8
    assert np.mean(new[rail] == 17) > 0.85
    assert np.mean(new[~deck & ~rail] == 17) < 0.01  # the land and the channel
    roofs = PARAMS.model_copy(update={"bridges": PARAMS.bridges.model_copy(update={"planarity": 0.15})})
    strict = object_classes(xyz, cls, nret, np.ones(len(cls), bool), roofs, 1.0, True)[0]
    assert np.mean(strict[deck] == 17) < 0.5


def test_an_approach_over_a_gap_counts_at_its_grounds_height():
    """A region (1) whose sides drop away, with a cell at each end, both over a gap: by its top a lamp post's
    cell is not level with the region; by the height of its ground, the approach road's is."""
    labels = np.zeros((3, 9), int)
    labels[1, 2:7] = 1
    top = np.full(labels.shape, 90.0)  # the drop along the region's sides
    top[1, 2:7] = 100.0
    top[1, 1] = top[1, 7] = 104.0
    gap = np.ones(labels.shape, bool)
    assert not approach_ends(labels, top, gap, 1.0, 2)[1]
    ground = np.zeros(labels.shape, bool)
    ground[1, 1] = ground[1, 7] = True
    height = top.copy()
    height[1, 1], height[1, 7] = 100.2, 100.1  # the road's ground
    assert approach_ends(labels, top, gap & ~ground, 1.0, 2, height)[1]
    assert not approach_ends(labels, top, gap & ~ground, 1.0, 2, top)[1]  # by the tops
    height[1, 7] = 96.0  # a wall's cell: its ground lies at its foot
    assert not approach_ends(labels, top, gap & ~ground, 1.0, 2, height)[1]


def test_a_deck_whose_approaches_stand_over_a_gap_under_trees_is_17():
    """The approaches' cells, over a gap, hold ground at the deck's level under crowns 8 m higher."""
    xyz, cls, deck, rail = _diagonal_bridge(bank=True)
    nret = np.ones(len(cls), np.uint8)
    new = object_classes(xyz, cls, nret, np.ones(len(cls), bool), PARAMS, 1.0, True)[0]
    along = np.abs((xyz[:, 0] - 65.0) + (xyz[:, 1] - 65.0)) / np.sqrt(2)
    assert np.mean(new[deck & (along < 8)] == 17) > 0.8
    assert np.mean(new[~deck & ~rail] == 17) < 0.01
