"""Known answers of the mounting model's numerical Jacobian (issue 23), from the geometry of flat ground.

One flat patch at the origin's height, D metres north of the first platform position.  The surface
strip looks at it straight down from above it; the observed strip sees it from the first position, at
the scan angle theta = atan(D / H).  Attitude is the identity (body axes = east, north, up), so:

- a range offset dr moves the nadir surface down by dr and the slant points down by dr cos(theta):
  d(residual)/d(dr) = 1 - cos(theta) (with the surface's own beams a few metres off nadir: slightly less);
- a roll (about body x = east) by phi lifts a point by phi * v_y: the slant points by phi * D, the
  surface (symmetric about its centre) not at its centre: d(residual)/d(roll) = D;
- pitch and yaw move the points along the flat ground, and a lever arm moves every point alike: no
  change of any distance.
"""

from __future__ import annotations

import numpy as np
import pytest

from lidar.geodesy import LocalFrame
from lidar.georeferencing import Mounting, trajectory_from
from stages.strip_adjust.mounting import Links, Sample, georeference_sample, jacobian, make_unknowns, residuals

H, D = 1000.0, 400.0  # flying height and ground distance of the patch, metres


@pytest.fixture
def flat_patch():
    traj = trajectory_from(
        np.array([0.0, 1.0]),
        np.array([[0.0, 0.0, H], [0.0, D, H]]),
        np.array([[1.0, 0.0, 0.0, 0.0]] * 2),
        LocalFrame(40.0, -3.0, 0.0),
    )
    g = np.linspace(-2.0, 2.0, 5)
    gx, gy = (a.ravel() for a in np.meshgrid(g, g))
    surface = np.column_stack((gx, gy, np.full(gx.size, -H)))  # from (0, D, H): nadir
    h = np.linspace(-1.5, 1.5, 4)
    ox, oy = (a.ravel() for a in np.meshgrid(h, h))
    observed = np.column_stack((ox, D + oy, np.full(ox.size, -H)))  # from (0, 0, H): slant
    v = np.vstack((surface, observed))
    n_s, n_o = len(surface), len(observed)
    sample = Sample(
        np.zeros(n_s + n_o, np.int64),
        np.r_[np.ones(n_s), np.zeros(n_o)],
        v,
        np.r_[np.ones(n_s, np.int64), np.full(n_o, 2, np.int64)],
    )
    links = Links(
        np.arange(n_s),
        np.zeros(n_s, np.int64),
        np.arange(n_s, n_s + n_o),
        np.zeros(n_o, np.int64),
        np.array([[0.0, D, 0.0]]),
        np.array([[1, 2]]),
        np.array([float(n_o)]),
    )
    return traj, Mounting(np.eye(3), np.zeros(3)), sample, links


def test_flat_ground_jacobian_has_the_geometric_values(flat_patch):
    traj, mounting, sample, links = flat_patch
    unknowns = make_unknowns(
        lever_arm=True, range_offset=True, offset_strips=[], reference=None, limits=(1.0, 1.0, 1.0, 1.0)
    )
    theta = np.zeros(unknowns.size)

    xyz = georeference_sample(traj, mounting, sample, theta, unknowns)
    assert np.allclose(xyz[:, 2], 0.0, atol=1e-9)  # every pulse ends on the ground
    assert residuals(links, xyz) == pytest.approx([0.0], abs=1e-9)
    jac = jacobian(traj, mounting, sample, links, theta, unknowns, list(range(7)))[0]
    cos_theta = np.mean(H / np.linalg.norm(sample.v[25:], axis=1))
    # the nadir surface's beams are not quite vertical either: where the observed points lie (x, y from the
    # patch centre) it moves down by dr H / sqrt(H^2 + x^2 + y^2), a quadratic the surface fit holds exactly
    local = sample.v[25:, :2] - [0.0, D]
    cos_surface = np.mean(H / np.sqrt(H**2 + np.sum(local**2, axis=1)))
    assert jac[6] == pytest.approx(cos_surface - cos_theta, rel=1e-6)  # range offset
    assert jac[0] == pytest.approx(D, rel=1e-6)  # roll, metres per radian
    assert np.allclose(jac[1:3], 0.0, atol=1e-6)  # pitch and yaw move the points along the flat ground
    assert np.allclose(jac[3:6], 0.0, atol=1e-6)  # lever arm
