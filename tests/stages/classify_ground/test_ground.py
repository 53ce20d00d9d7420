"""Known answers for the ground filters, the noise tests and the metrics."""

from __future__ import annotations

import numpy as np
import pytest

from commands.evaluate.scores import score
from stages.classify_ground.csf import CsfParams, csf
from stages.classify_ground.ground_classes import classify
from stages.classify_ground.params import ClassifyGroundParams
from stages.classify_ground.pmf import PmfParams, pmf
from stages.classify_ground.smrf import SmrfParams, smrf
from stages.classify_ground.surface import inpaint
from stages.denoise.outliers import isolated_points, low_outliers

FILTERS = {"smrf": smrf, "pmf": pmf, "csf": csf}


def scene(size=100.0, density=2.0, noise=0.03, seed=1, z=lambda x, y: np.zeros_like(x)):
    rng = np.random.default_rng(seed)
    n = int(size * size * density)
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    return np.column_stack([x, y, z(x, y) + rng.normal(0, noise, n)])


@pytest.mark.parametrize("name", ["smrf", "pmf", "csf"])
def test_flat_plane_is_all_ground(name):
    pts = scene()
    assert FILTERS[name](pts).mean() > 0.999


@pytest.mark.parametrize("name", ["smrf", "pmf", "csf"])
def test_box_on_a_plane_is_not_ground(name):
    pts = scene()
    box = (np.abs(pts[:, 0] - 50) < 12) & (np.abs(pts[:, 1] - 40) < 8)  # 24 m x 16 m
    pts[box, 2] += 7.0
    ground = FILTERS[name](pts)
    assert ground[box].mean() < 0.01
    assert ground[~box].mean() > 0.99


@pytest.mark.parametrize("name", ["smrf", "pmf", "csf"])
def test_tree_on_a_plane_is_not_ground(name):
    pts = scene()
    d = np.hypot(pts[:, 0] - 30, pts[:, 1] - 60)
    crown = d < 5
    pts[crown, 2] += 14.0 - 1.5 * d[crown]
    ground = FILTERS[name](pts)
    assert ground[crown].mean() < 0.01
    assert ground[~crown].mean() > 0.99


def test_thirty_degree_slope_stays_ground():
    pts = scene(z=lambda x, y: np.tan(np.radians(30.0)) * x)
    assert smrf(pts).mean() > 0.995


def test_wall_bounded_terrace_keeps_both_levels():
    # a 4 m retaining wall across the area: two wide, flat levels
    pts = scene(z=lambda x, y: np.where(x > 50.0, 4.0, 0.0))
    ground = smrf(pts)
    assert ground[pts[:, 0] < 50].mean() > 0.99
    assert ground[pts[:, 0] > 50].mean() > 0.99


def test_low_outliers_do_not_drag_the_surface_down():
    pts = scene()
    pts[:20, 2] -= 15.0  # multipath echoes
    ground = smrf(pts)
    assert not ground[:20].any()
    assert ground[20:].mean() > 0.99


def test_inpaint_is_harmonic():
    # a linear function is harmonic: inpainting must reproduce it exactly
    yy, xx = np.mgrid[0:30, 0:40].astype(float)
    truth = 2.0 + 0.3 * xx - 0.1 * yy
    holes = truth.copy()
    holes[5:20, 8:30] = np.nan
    np.testing.assert_allclose(
        inpaint(holes), truth, atol=1e-6
    )  # 1 µm: the iterative solve stops at a relative residual (INPAINT_TOL)


def test_metrics_known_values():
    ref = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 0], bool)
    pred = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], bool)
    s = score(ref, pred)
    assert s.type_1 == pytest.approx(0.25)
    assert s.type_2 == pytest.approx(1 / 6)
    assert s.total == pytest.approx(0.2)
    # po = 0.8, pe = (4*4 + 6*6) / 100 = 0.52 -> kappa = 0.28 / 0.48
    assert s.kappa == pytest.approx(0.28 / 0.48)
    assert score(ref, ref).kappa == 1.0


def test_isolated_points_and_low_outliers():
    pts = scene(size=40.0)
    pts = np.vstack([pts, [[20.0, 20.0, 60.0], [5.0, 35.0, -30.0]]])  # a bird, a deep echo
    iso = isolated_points(pts, multiplier=5.0)
    assert iso[-2:].all() and iso[:-2].mean() < 0.001
    low = low_outliers(pts, cell_size=10.0, elevation_threshold=2.0)
    assert low[-1] and not low[-2] and low[:-2].sum() == 0


def test_driver_keeps_noise_and_uses_last_returns_only():
    pts = scene(size=40.0)
    n = len(pts)
    cls = np.zeros(n, np.uint8)
    cls[:5] = 7
    rn = np.ones(n, np.uint8)
    nr = np.ones(n, np.uint8)
    nr[5:10] = 2  # first returns of two-return pulses: never ground
    out = classify(pts, cls, rn, nr, np.zeros(n, bool), ClassifyGroundParams())
    assert (out[:5] == 7).all()
    assert (out[5:10] == 1).all()
    assert (out[10:] == 2).mean() > 0.99


def test_algorithm_defaults_are_the_documented_ones():
    assert SmrfParams(name="smrf").model_dump() == {
        "name": "smrf",
        "cell_size": 1.0,
        "slope": 0.15,
        "max_window_size": 18.0,
        "elevation_threshold": 0.5,
        "elevation_scalar": 1.25,
        "floor_window": 3.0,
        "wall_height": 2.0,
    }
    assert ClassifyGroundParams().algorithm.name == "smrf"
    assert PmfParams(name="pmf").max_window_size == 33.0
    assert CsfParams(name="csf").rigidness == 1
