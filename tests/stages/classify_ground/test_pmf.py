"""Known answers for the progressive morphological filter."""

from __future__ import annotations

import numpy as np
import pytest

from stages.classify_ground.pmf import height_thresholds, pmf, window_sizes


def _plane(n=20_000, size=100.0, seed=1, z=lambda x, y: np.zeros_like(x), noise=0.0):
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    return np.column_stack([x, y, z(x, y) + rng.normal(0, noise, n) if noise else z(x, y)])


def test_window_sizes_and_thresholds_follow_the_paper():
    assert window_sizes(1.0, 33.0) == [3, 5, 9, 17, 33]
    assert window_sizes(2.0, 33.0) == [3, 5, 9]  # 17 cells = 34 m > 33 m
    # eq. 7: dh0, then s (w_k - w_{k-1}) c + dh0, capped.
    th = height_thresholds([3, 5, 9, 17], cell_size=1.0, slope=0.5, initial_distance=0.2, max_distance=3.0)
    assert th == pytest.approx([0.2, 1.2, 2.2, 3.0])


def test_flat_plane_is_all_ground():
    pts = _plane(noise=0.02)
    assert pmf(pts).all()


def test_box_on_a_plane_is_not_ground_and_the_plane_is():
    pts = _plane(noise=0.02)
    inside = (np.abs(pts[:, 0] - 50) < 10) & (np.abs(pts[:, 1] - 50) < 7.5)
    pts[inside, 2] += 8.0  # a 20 m x 15 m building, 8 m high
    ground = pmf(pts, max_window_size=33.0)
    assert not ground[inside].any()
    assert ground[~inside].mean() > 0.99


def test_tree_on_a_plane_is_not_ground():
    pts = _plane(noise=0.02)
    d = np.hypot(pts[:, 0] - 30, pts[:, 1] - 60)
    crown = d < 4
    pts[crown, 2] += 12.0 - d[crown]
    ground = pmf(pts)
    assert not ground[crown].any()
    assert ground[~crown].mean() > 0.99


def test_inclined_plane_within_slope_stays_ground():
    # 10 % slope, below the configured slope of 0.15
    pts = _plane(z=lambda x, y: 0.10 * x, noise=0.02)
    assert pmf(pts, slope=0.15).mean() > 0.99


def test_empty_and_bad_shapes():
    assert pmf(np.zeros((0, 3))).shape == (0,)
    with pytest.raises(ValueError):
        pmf(np.zeros((5, 2)))
