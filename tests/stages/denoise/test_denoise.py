"""The noise step flags outliers, not vegetation.

The synthetic scene of the shipped LAS sample (trees with second and third
returns, buildings, no outlier): the noise step must leave it alone (the
survey-wide statistical test flagged 901 of its points, 0.29 %, nearly all
in tree crowns).  Outliers injected into it (birds over the open ground and
over the crowns, a pair of birds, multipath echoes 20-30 m deep) must all be found,
the birds as high noise and the echoes as low noise.
"""

from __future__ import annotations

import numpy as np
import pytest

from stages.denoise.noise_classes import noise_classes
from stages.denoise.params import DenoiseParams
from tests.synthetic import make_scene, terrain


@pytest.fixture(scope="module")
def scene():
    s = make_scene()
    return np.column_stack([s.x, s.y, s.z]), s


def test_a_clean_survey_with_canopy_is_left_alone(scene):
    xyz, s = scene
    cls = noise_classes(xyz, DenoiseParams())
    crowns = ~s.true_ground & (s.number_of_returns > 1)
    assert crowns.sum() > 10_000  # the scene has canopy to lose
    assert (cls > 0).sum() <= 1e-4 * len(xyz)  # at most 0.01 % flagged
    assert not (cls[s.true_ground] > 0).any()


def test_injected_outliers_are_found(scene):
    xyz, s = scene
    rng = np.random.default_rng(7)
    canopy = np.flatnonzero(~s.true_ground & (s.number_of_returns > 1))
    # birds: 20 over random places, 10 just over tree crowns (12-40 m above the top return)
    bx, by = rng.uniform(20, 490, 20), rng.uniform(20, 360, 20)
    birds = np.column_stack([bx, by, terrain(bx, by) + rng.uniform(20, 80, 20)])
    over = xyz[rng.choice(canopy, 10, replace=False)] + np.column_stack([np.zeros((10, 2)), rng.uniform(12, 40, 10)])
    pair = np.array([[250.0, 200.0, terrain(250.0, 200.0) + 50.0], [250.6, 200.5, terrain(250.0, 200.0) + 50.4]])
    dx, dy = rng.uniform(20, 490, 15), rng.uniform(20, 360, 15)
    deep = np.column_stack([dx, dy, terrain(dx, dy) - rng.uniform(20, 30, 15)])  # 10 spacings: 11-18 m here
    high = np.vstack([birds, over, pair])
    pts = np.vstack([xyz, high, deep])
    cls = noise_classes(pts, DenoiseParams())
    n = len(xyz)
    assert (cls[n : n + len(high)] == 18).all(), cls[n : n + len(high)]
    assert (cls[n + len(high) :] == 7).all(), cls[n + len(high) :]
    assert (cls[:n] > 0).sum() <= 1e-4 * n
