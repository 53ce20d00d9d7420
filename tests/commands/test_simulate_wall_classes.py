"""The simulator's true class of an echo on a wall or under a deck (its scene stands walls as one-cell ramps)."""

from __future__ import annotations

import numpy as np

from commands.simulate.scene import Scene


def _scene(high_class: int) -> Scene:
    """Four 1 m columns: two of ground at 0 m, then two of *high_class* at 8 m (a wall between x = 1.5 and 2.5)."""
    solid = np.array([[0.0, 0.0, 8.0, 8.0]] * 4)
    cls = np.array([[2, 2, high_class, high_class]] * 4, np.uint8)
    return Scene(0.0, 0.0, 1.0, np.zeros((4, 4)), solid, solid.copy(), cls)


def test_an_echo_up_a_wall_is_the_buildings_and_at_its_foot_the_grounds():
    s = _scene(6)
    e, n = np.array([1.9, 1.9, 1.9, 0.5]), np.full(4, 2.0)
    z = np.array([3.2, 0.05, 7.9, 0.0])  # up the wall, at its foot (within 0.1 m), near its top, on open ground
    assert s.class_of_hit(e, n, z).tolist() == [6, 2, 6, 2]
    assert s.class_at(e, n).tolist() == [2, 2, 2, 2]  # the nearest cell alone: every one ground


def test_an_echo_below_a_decks_thickness_is_what_lies_under_it():
    s = _scene(17)
    e, n = np.full(3, 1.9), np.full(3, 2.0)
    z = np.array([7.5, 3.0, 0.05])  # the deck's edge, the open air under it (the ground below), the ground
    assert s.class_of_hit(e, n, z).tolist() == [17, 2, 2]
