"""Rotations for georeferencing: Euler conventions, quaternions, SLERP.

Quaternions are ``(w, x, y, z)`` arrays of shape ``(..., 4)``, Hamilton
convention, active rotations: ``quat_matrix(q) @ v`` turns v by q.

Per-epoch conversions are few (one per trajectory epoch) and could use
:class:`scipy.spatial.transform.Rotation`; the per-pulse work (SLERP and
rotating a vector, millions of times) is written out in NumPy because the
``Rotation``/``Slerp`` path measured about 1 M pulses/s here, and the
pipeline needs several times that (issue 4).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation


def rot_x(angle: float) -> np.ndarray:
    """Rotation matrix about x by *angle* (radians), counter-clockwise seen from +x."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    """Rotation matrix about y by *angle* (radians).

    >>> np.round(rot_y(np.pi / 2) @ [1.0, 0.0, 0.0], 12)
    array([ 0.,  0., -1.])
    """
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    """Rotation matrix about z by *angle* (radians)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def euler_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) . Ry(pitch) . Rx(roll), angles in radians (body -> local level)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b (the rotation b, then a)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, dtype=np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, dtype=np.float64), -1, 0)
    return np.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        axis=-1,
    )


def _axis_quat(axis: int, angle: np.ndarray) -> np.ndarray:
    angle = np.asarray(angle, dtype=np.float64)
    q = np.zeros(angle.shape + (4,))
    q[..., 0] = np.cos(angle / 2)
    q[..., 1 + axis] = np.sin(angle / 2)
    return q


def euler_quat(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Quaternion of Rz(yaw) . Ry(pitch) . Rx(roll) (radians), vectorised.

    >>> q = euler_quat(0.1, -0.2, 0.3)
    >>> bool(np.allclose(quat_matrix(q), euler_matrix(0.1, -0.2, 0.3)))
    True
    """
    return quat_mul(quat_mul(_axis_quat(2, yaw), _axis_quat(1, pitch)), _axis_quat(0, roll))


def matrix_quat(m: np.ndarray) -> np.ndarray:
    """Quaternion(s) of rotation matrices ``(..., 3, 3)`` (scipy, w first, w >= 0)."""
    m = np.asarray(m, dtype=np.float64)
    xyzw = Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat()
    q = np.concatenate((xyzw[:, 3:], xyzw[:, :3]), axis=1)
    q[q[:, 0] < 0] *= -1
    return q.reshape(m.shape[:-2] + (4,))


def quat_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices ``(..., 3, 3)`` of unit quaternions."""
    w, x, y, z = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack(
        (
            np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), -1),
            np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), -1),
            np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1),
        ),
        -2,
    )


def unwrap_signs(q: np.ndarray) -> np.ndarray:
    """Flip quaternions so consecutive ones are in the same hemisphere (q and -q are one rotation)."""
    q = np.array(q, dtype=np.float64, copy=True)
    if len(q) > 1:
        dots = np.einsum("ij,ij->i", q[1:], q[:-1])
        flips = np.concatenate(([False], np.logical_xor.accumulate(dots < 0)))
        q[flips] *= -1
    return q


def slerp_weights(q0: np.ndarray, q1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per interval: the angle between two unit quaternions and 1/sin of it (0 when tiny).

    Intervals are few (one per trajectory epoch): computing them once makes
    the per-pulse SLERP two sines and a weighted sum.
    """
    dot = np.clip(np.einsum("ij,ij->i", q0, q1), -1.0, 1.0)
    theta = np.arccos(np.abs(dot))
    inv_sin = np.zeros_like(theta)
    big = theta > 1e-9
    inv_sin[big] = 1.0 / np.sin(theta[big])
    return theta, inv_sin


def slerp(q0: np.ndarray, q1: np.ndarray, f: np.ndarray, theta: np.ndarray, inv_sin: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation (Shoemake 1985, doi:10.1145/325165.325242).

    ``q0``, ``q1`` rows in the same hemisphere (see :func:`unwrap_signs`),
    ``f`` in [0, 1], ``theta`` and ``inv_sin`` from :func:`slerp_weights`.
    Where the angle is below 1e-9 rad the weights fall back to linear ones
    (the difference is below 1e-18 rad).
    """
    small = inv_sin == 0.0
    w0 = np.where(small, 1.0 - f, np.sin((1.0 - f) * theta) * inv_sin)
    w1 = np.where(small, f, np.sin(f * theta) * inv_sin)
    return w0[:, None] * q0 + w1[:, None] * q1
