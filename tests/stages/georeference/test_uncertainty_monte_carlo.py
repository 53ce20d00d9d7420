"""Propagated uncertainty against Monte-Carlo, with a lever arm and unequal sigmas per axis (issue 19).

The hand-worked cases of test_uncertainty.py use a zero lever arm and equal
sigmas per axis, where a Jacobian that forgets the lever arm or a sigma read
on the wrong axis gives the right answer.  Here the mounting has a 1.7 m lever
arm, the pulses are short (a low pass over a roof, 12-25 m), every source has
its own sigma per axis, and the reference is a Monte-Carlo run of the
georeferencing equation written independently (scipy rotations): perturb
range, scan angle, position (east, north, up) and attitude (small rotations
about the body axes, as the model states), georeference, and measure the
spread.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from commands.simulate.forward import Earth
from lidar.georeferencing import Mounting, locate, prepare_trajectory
from stages.georeference.uncertainty import Sigmas, propagate

LAT, LON, H = 40.4, -3.7, 700.0
ROLL, PITCH, HEADING = 4.0, -2.5, 35.0  # degrees
LEVER = np.array([0.9, -0.6, 1.3])  # body x forward, y right, z down (m)
BORESIGHT = Rotation.from_euler("ZYX", [1.0, -0.5, 0.3], degrees=True).as_matrix()
SIGMA = {
    "range": 0.02,
    "scan": np.radians(0.005),
    "enu": np.array([0.015, 0.04, 0.09]),
    "att": np.radians([0.15, 0.05, 0.3]),  # roll, pitch, heading
}
#: scanner vectors (x along track, y across, z down), a line scanner turning about x
PULSES = np.array([[0.0, 0.0, 12.0], [0.0, 8.0, 14.0], [0.0, -15.0, 20.0], [0.0, 5.0, 24.5]])


def _propagated() -> tuple[np.ndarray, np.ndarray]:
    traj = prepare_trajectory(
        np.array([0.0, 1.0]),
        np.full(2, LAT),
        np.full(2, LON),
        np.full(2, H),
        np.full(2, ROLL),
        np.full(2, PITCH),
        np.full(2, HEADING),
        "NED",
    )
    t = np.full(len(PULSES), 0.5)
    i, f, _ = locate(traj, t, 2.0)
    sig = Sigmas(SIGMA["range"], SIGMA["scan"], tuple(SIGMA["enu"]), tuple(SIGMA["att"]))
    cols = tuple(PULSES[:, k].copy() for k in range(3))
    return propagate(traj, i, f, cols, Mounting(BORESIGHT, LEVER), sig, (1.0, 0.0, 0.0))


def _monte_carlo(n: int = 40_000, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal and vertical spread of each pulse's point over *n* perturbed georeferencings."""
    rng = np.random.default_rng(seed)
    # R_enu<-body at the trajectory's origin (the local frame of prepare_trajectory is centred there)
    body_to_enu = Earth(LAT, LON, H).local_from_body([LAT], [LON], *np.radians([ROLL, PITCH, HEADING]))[0]
    sh, sv = [], []
    for v in PULSES:
        rho = np.linalg.norm(v)
        scan = Rotation.from_rotvec(np.outer(rng.normal(0, SIGMA["scan"], n), [1.0, 0.0, 0.0]))
        v_s = scan.apply(v) * (1.0 + rng.normal(0, SIGMA["range"], n) / rho)[:, None]
        v_b = v_s @ BORESIGHT.T + LEVER
        tilt = Rotation.from_rotvec(rng.normal(0, 1, (n, 3)) * SIGMA["att"])  # small rotations, body axes
        p = (body_to_enu * tilt).apply(v_b) + rng.normal(0, 1, (n, 3)) * SIGMA["enu"]
        d = p - p.mean(axis=0)
        sh.append(np.sqrt(np.mean(d[:, 0] ** 2 + d[:, 1] ** 2)))
        sv.append(np.sqrt(np.mean(d[:, 2] ** 2)))
    return np.array(sh), np.array(sv)


def test_propagated_sigmas_match_monte_carlo_with_a_lever_arm_and_unequal_sigmas():
    h, v = _propagated()
    mc_h, mc_v = _monte_carlo()
    # 40,000 draws: the spread is known to about 0.4 % (1 sigma); 2 % leaves room for the
    # second-order terms the first-order propagation leaves out
    np.testing.assert_allclose(h, mc_h, rtol=0.02)
    np.testing.assert_allclose(v, mc_v, rtol=0.02)


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_each_position_sigma_lands_on_its_own_axis(axis):
    """One position sigma at a time: east and north are horizontal, up is vertical."""
    traj = prepare_trajectory(
        np.array([0.0, 1.0]),
        np.full(2, LAT),
        np.full(2, LON),
        np.full(2, H),
        np.zeros(2),
        np.zeros(2),
        np.zeros(2),
        "NED",
    )
    i, f, _ = locate(traj, np.array([0.5]), 2.0)
    enu = [0.0, 0.0, 0.0]
    enu[axis] = 0.05
    h, v = propagate(
        traj,
        i,
        f,
        (np.zeros(1), np.zeros(1), np.full(1, 50.0)),
        Mounting(np.eye(3), LEVER),
        Sigmas(0.0, 0.0, tuple(enu), (0.0, 0.0, 0.0)),
        (1.0, 0.0, 0.0),
    )
    assert (float(h[0]), float(v[0])) == pytest.approx((0.05, 0.0) if axis < 2 else (0.0, 0.05), abs=1e-12)
