"""Per-point total propagated uncertainty (TPU) of direct georeferencing.

First-order propagation of p = pos + R_b^n (R_s^b v_s + a_b) (see
:mod:`lidar.georeferencing`) with independent errors in range, scan
angle, position, attitude, boresight and lever arm, as in Glennie (2007),
"Rigorous 3D error analysis of kinematic scanning LIDAR systems",
J. Applied Geodesy 1, doi:10.1515/jag.2007.017: each source adds
s_k^2 J_k J_k^T to the point's covariance.  Where we depart: attitude errors
are small rotations about the body axes, and no errors are correlated
(docs/stages/georeference.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lidar.georeferencing import Mounting, Trajectory, locate
from lidar.rotation import quat_matrix, slerp
from pipeline.errors import ConfigError
from stages.georeference.params import UncertaintyParams


@dataclass
class Sigmas:
    """One-sigma errors.  Arrays (one value per pulse) or scalars."""

    range_m: float
    scan_angle_rad: float
    position_enu_m: tuple  # (east, north, up), each scalar or (n,)
    attitude_rad: tuple  # (roll, pitch, heading), each scalar or (n,)
    boresight_rad: float = 0.0
    lever_arm_m: float = 0.0


def _cross(a: tuple, b: tuple) -> tuple:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _rot(cols: tuple, v: tuple) -> tuple:
    """Apply per-pulse rotation matrices given as 3x3 nested tuples of columns to vectors."""
    return tuple(cols[0][j] * v[0] + cols[1][j] * v[1] + cols[2][j] * v[2] for j in range(3))


def _mount(rs: np.ndarray, v: tuple) -> tuple:
    """Apply the boresight rotation R_s^b to scanner-frame vectors given as columns."""
    return tuple(rs[j, 0] * v[0] + rs[j, 1] * v[1] + rs[j, 2] * v[2] for j in range(3))


def propagate(
    traj: Trajectory,
    i: np.ndarray,
    f: np.ndarray,
    v_s: tuple[np.ndarray, np.ndarray, np.ndarray],
    mounting: Mounting,
    sig: Sigmas,
    scan_axis: tuple[float, float, float],
) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal and vertical one-sigma of each pulse's point (metres).

    ``i``, ``f`` locate the pulses in the trajectory (:func:`~lidar.georeferencing.locate`);
    ``scan_axis`` is the scanner-frame axis the beam turns about when the
    scan angle changes (x for the RIEGL line scanners, z for the LD-MRS).
    """
    q = slerp(traj.attitude[i], traj.attitude[i + 1], f, traj.theta[i], traj.inv_sin[i])
    m = quat_matrix(q)  # (n, 3, 3) local ENU <- body
    body = tuple(tuple(m[:, j, k] for j in range(3)) for k in range(3))  # columns of R
    rs = mounting.rotation
    sx, sy, sz = (np.asarray(c, dtype=np.float64) for c in v_s)
    vb_s = _mount(rs, (sx, sy, sz))
    a = mounting.lever_arm
    v_b = (vb_s[0] + a[0], vb_s[1] + a[1], vb_s[2] + a[2])
    rho = np.sqrt(sx**2 + sy**2 + sz**2)
    inv = 1.0 / np.maximum(rho, 1e-9)
    var = [np.zeros(len(sx)) for _ in range(3)]

    def add(sigma, col):
        s2 = np.square(sigma)
        for j in range(3):
            var[j] += s2 * col[j] ** 2

    # range: along the beam
    add(sig.range_m, _rot(body, tuple(c * inv for c in vb_s)))
    # scan angle: the beam turns about the scan axis
    ax = np.asarray(scan_axis, dtype=np.float64)
    turn = _cross(tuple(np.full(len(sx), v) for v in ax), (sx, sy, sz))
    add(sig.scan_angle_rad, _rot(body, _mount(rs, turn)))
    # position: straight through, per axis
    for j in range(3):
        var[j] += np.square(sig.position_enu_m[j])
    # attitude: small rotations about the body axes, applied to the lever-armed vector
    unit = [tuple(np.full(len(sx), 1.0 if k == j else 0.0) for k in range(3)) for j in range(3)]
    for j in range(3):
        add(sig.attitude_rad[j], _rot(body, _cross(unit[j], v_b)))
    # boresight: small rotations about the scanner axes, applied to the beam
    if sig.boresight_rad:
        for j in range(3):
            add(sig.boresight_rad, _rot(body, _mount(rs, _cross(unit[j], (sx, sy, sz)))))
    # lever arm: through the attitude
    if sig.lever_arm_m:
        for j in range(3):
            add(sig.lever_arm_m, tuple(body[j][k] for k in range(3)))
    return np.sqrt(var[0] + var[1]), np.sqrt(var[2])


@dataclass(frozen=True)
class EpochSigmas:
    """Per-epoch one-sigma errors of the navigation, and where each came from."""

    position: tuple[np.ndarray, np.ndarray, np.ndarray]  # east, north, up; metres
    attitude: tuple[np.ndarray, np.ndarray, np.ndarray]  # roll, pitch, heading; radians
    sources: dict[str, str]  # "position" / "attitude" -> "configuration" or "trajectory"


def epoch_sigmas(u: UncertaintyParams, traj: dict) -> EpochSigmas:
    """Per-epoch position and attitude sigmas: from the configuration, else from the trajectory's columns.

    Neither is a :class:`~pipeline.errors.ConfigError` naming the key to set.
    """
    n = len(traj["time"])
    out: dict = {"sources": {}}
    wanted = (
        (
            "position",
            u.position_m,
            1.0,
            ("sigma_east_m", "sigma_north_m", "sigma_up_m"),
            "position_m",
            "no position sigmas (no $GST, no smrmsg)",
        ),
        (
            "attitude",
            u.attitude_deg,
            np.pi / 180,
            ("sigma_roll_deg", "sigma_pitch_deg", "sigma_heading_deg"),
            "attitude_deg",
            "no attitude sigmas (only smrmsg files carry them)",
        ),
    )
    for name, stated, scale, columns, key, missing in wanted:
        if stated is not None:
            out[name] = tuple(np.full(n, stated * scale) for _ in range(3))
            out["sources"][name] = "configuration"
        elif all(c in traj for c in columns):
            out[name] = tuple(np.asarray(traj[c], dtype=np.float64) * scale for c in columns)
            out["sources"][name] = "trajectory"
        else:
            raise ConfigError(
                f"stages.georeference.uncertainty.{key}: the trajectory has {missing}, so state the {name} error."
            )
    return EpochSigmas(out["position"], out["attitude"], out["sources"])


def scan_axis(pulse_format: str | None) -> tuple[float, float, float]:
    """The scanner-frame axis the beam turns about: z for the LD-MRS (3.A), x for the RIEGL line scanners."""
    return (0.0, 0.0, 1.0) if pulse_format == "ldmrs_mtig" else (1.0, 0.0, 0.0)


@dataclass(frozen=True)
class PointUncertainty:
    """What the per-point propagation needs besides the pulses: the configured and per-epoch sigmas, the scan axis."""

    config: UncertaintyParams
    epochs: EpochSigmas
    scan_axis: tuple[float, float, float]

    def sigmas(
        self, traj: Trajectory, t: np.ndarray, v_s: list[np.ndarray], mounting: Mounting
    ) -> tuple[np.ndarray, np.ndarray]:
        """Horizontal and vertical one-sigma (metres) of pulses at times *t* with scanner vectors *v_s*."""
        u = self.config
        i, f, _ = locate(traj, t, float("inf"))
        sig = Sigmas(
            range_m=u.range_m,
            scan_angle_rad=np.radians(u.scan_angle_deg),
            position_enu_m=tuple(c[i] for c in self.epochs.position),
            attitude_rad=tuple(c[i] for c in self.epochs.attitude),
            boresight_rad=np.radians(u.boresight_deg),
            lever_arm_m=u.lever_arm_m,
        )
        return propagate(traj, i, f, tuple(v_s), mounting, sig, self.scan_axis)


def point_uncertainty(u: UncertaintyParams, traj: dict, pulse_format: str | None) -> PointUncertainty:
    """The :class:`PointUncertainty` of a flight: *u* configured, *traj* the trajectory's columns."""
    return PointUncertainty(u, epoch_sigmas(u, traj), scan_axis(pulse_format))
