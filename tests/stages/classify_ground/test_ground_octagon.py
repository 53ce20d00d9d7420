"""SMRF's octagon dilation in a few passes equals the sum of its 3x3 elements (issue 16)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from stages.classify_ground.smrf import _dilate_octagon, _element


@pytest.mark.parametrize("radius", range(1, 19))
def test_octagon_dilation_is_the_sum_of_the_crosses_and_squares(radius):
    """A spike dilated by radius r is the octagon: ceil(r/2) crosses and floor(r/2) 3x3 squares, one after another;
    and any surface dilated both ways agrees on every cell at least r from the edge."""
    spike = np.zeros((41, 41))
    spike[20, 20] = 1.0
    surface = np.random.default_rng(radius).normal(size=(50, 60))
    expected = [spike, surface]
    for step in range(1, radius + 1):
        expected = [ndimage.grey_dilation(g, footprint=_element(step), mode="nearest") for g in expected]
    np.testing.assert_array_equal(_dilate_octagon(spike, radius), expected[0])
    inner = np.s_[radius:-radius, radius:-radius]
    np.testing.assert_array_equal(_dilate_octagon(surface, radius)[inner], expected[1][inner])
    if radius == 3:  # the octagon of radius 3: 7 cells wide at its middle rows, 3 at its top
        assert expected[0][17, 19:22].all() and not expected[0][17, 18] and expected[0][20, 17:24].all()
