"""Bridge decks (17) on hand-made clouds: a deck over a channel, an embankment across a valley, a roof."""

from __future__ import annotations

import numpy as np

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
