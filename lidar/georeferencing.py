"""Direct georeferencing of LiDAR pulses (SPEC 4), vectorised.

For each pulse at time t::

    p_map = T( pos(t) + R_n^e(t) . R_b^n(t) . (R_s^b . v_s + a_b) )

v_s the pulse in the scanner frame, R_s^b the boresight, a_b the lever arm,
R_b^n the attitude (NED or NWU local level), R_n^e local level -> ECEF, T the
exact ECEF -> output CRS transform: Baltsavias (1999), ISPRS J. 54(2-3),
doi:10.1016/S0924-2716(99)00011-8; Glennie (2007), J. Applied Geodesy 1,
doi:10.1515/jag.2007.017.  Where we depart: per epoch R_n^e . R_b^n is folded
into one quaternion, interpolated per pulse by SLERP (exact at the epochs,
below a micrometre between them); see docs/stages/georeference.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj

from lidar.geodesy import LocalFrame, MapTransform, local_level_to_ecef
from lidar.rotation import euler_quat, matrix_quat, quat_mul, slerp_weights, unwrap_signs
from pipeline.errors import InputDataError
from pipeline.executor import thread_map

#: A gap in the trajectory longer than this (s) leaves its pulses without a position, unless said otherwise.
MAX_GAP_S = 0.5
#: Pulses georeferenced per batch (memory about 200 bytes each), unless said otherwise.
BATCH_SIZE = 2_000_000


@dataclass
class Mounting:
    """Scanner -> body: boresight rotation R_s^b and lever arm a_b (m, body axes)."""

    rotation: np.ndarray  # (3, 3)
    lever_arm: np.ndarray  # (3,)


@dataclass
class Trajectory:
    """Trajectory epochs ready for per-pulse interpolation (built by :func:`prepare_trajectory`)."""

    time: np.ndarray  # (m,) GPS seconds since 1980-01-06, strictly increasing
    position: np.ndarray  # (m, 3) local ENU, metres
    attitude: np.ndarray  # (m, 4) quaternions local ENU <- body
    theta: np.ndarray  # (m-1,) SLERP angle per interval
    inv_sin: np.ndarray  # (m-1,)
    frame: LocalFrame

    def __post_init__(self) -> None:
        # contiguous columns for fast per-pulse gathers; q_columns[1] is shifted by one epoch
        self.p_columns = _columns(self.position)
        self.q_columns = (_columns(self.attitude[:-1]), _columns(self.attitude[1:]))


def prepare_trajectory(
    time: np.ndarray,
    lat: np.ndarray,
    lon: np.ndarray,
    h: np.ndarray,
    roll: np.ndarray,
    pitch: np.ndarray,
    yaw: np.ndarray,
    convention: str,
    frame: LocalFrame | None = None,
) -> Trajectory:
    """Epochs (angles in degrees, attitude relative to the *convention* local level) -> :class:`Trajectory`.

    ``NED``: yaw is the true heading, clockwise from north; ``NWU``: yaw is
    counter-clockwise from north (MTi-G).  R_b^n = Rz(yaw) Ry(pitch) Rx(roll)
    in both.
    """
    time = np.asarray(time, dtype=np.float64)
    if len(time) > 1 and not np.all(np.diff(time) > 0):
        i = int(np.flatnonzero(~(np.diff(time) > 0))[0]) + 1
        raise InputDataError(
            f"the trajectory's times must increase strictly: epoch {i} (t = {time[i]:.6f} s) is not after "
            f"epoch {i - 1} (t = {time[i - 1]:.6f} s); the navigation input's clock or record order is wrong."
        )
    if frame is None:
        frame = LocalFrame(float(lat[0]), float(lon[0]), float(h[0]))
    position = frame.from_geodetic(lat, lon, h)
    q_n_b = euler_quat(np.radians(roll), np.radians(pitch), np.radians(yaw))
    r_local_n = frame.r_enu_to_ecef.T @ local_level_to_ecef(lat, lon, convention)  # (m, 3, 3)
    return trajectory_from(time, position, quat_mul(matrix_quat(r_local_n), q_n_b), frame)


def trajectory_from(time: np.ndarray, position: np.ndarray, q: np.ndarray, frame: LocalFrame) -> Trajectory:
    """A :class:`Trajectory` from epochs already in a local frame (position, quaternion frame <- body)."""
    q = unwrap_signs(q)
    if len(time) == 1:  # one epoch: an interval of zero motion, so pulses at it interpolate to it
        time, position, q = np.append(time, time[0] + 1.0), np.repeat(position, 2, 0), np.repeat(q, 2, 0)
    theta, inv_sin = slerp_weights(q[:-1], q[1:])
    return Trajectory(time, position, q, theta, inv_sin, frame)


def _columns(a: np.ndarray) -> tuple[np.ndarray, ...]:
    return tuple(np.ascontiguousarray(a[:, k]) for k in range(a.shape[1]))


def locate(traj: Trajectory, t: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Interval index, fraction, and which pulses have a trajectory (inside the span, not in a gap).

    A pulse exactly at an epoch always has one; a pulse inside an interval
    longer than *max_gap_s* does not.
    """
    tt = traj.time
    m = len(tt)
    i = np.clip(np.searchsorted(tt, t, side="right") - 1, 0, m - 2)
    dt = tt[i + 1] - tt[i]
    f = (t - tt[i]) / dt
    ok = (t >= tt[0]) & (t <= tt[-1]) & ((dt <= max_gap_s) | (f == 0.0) | (f == 1.0))
    return i, np.clip(f, 0.0, 1.0), ok


def georeference_local(
    traj: Trajectory,
    sx: np.ndarray,
    sy: np.ndarray,
    sz: np.ndarray,
    mounting: Mounting,
    i: np.ndarray,
    f: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Local ENU columns (e, n, u) of pulses (``i``, ``f`` from :func:`locate`).

    Written on 1-D columns (structure of arrays): gathers and arithmetic on
    contiguous arrays are several times faster than on (n, 3) rows.
    """
    # lever-armed vector in the body frame: R_s^b v_s + a_b
    r, a = mounting.rotation, mounting.lever_arm
    bx = r[0, 0] * sx + r[0, 1] * sy + r[0, 2] * sz + a[0]
    by = r[1, 0] * sx + r[1, 1] * sy + r[1, 2] * sz + a[1]
    bz = r[2, 0] * sx + r[2, 1] * sy + r[2, 2] * sz + a[2]
    # SLERP between the epochs around each pulse (Shoemake 1985)
    theta = traj.theta.take(i)
    inv_sin = traj.inv_sin.take(i)
    small = inv_sin == 0.0
    w0 = np.sin((1.0 - f) * theta) * inv_sin
    w1 = np.sin(f * theta) * inv_sin
    if small.any():
        w0[small] = 1.0 - f[small]
        w1[small] = f[small]
    j = i + 1
    qa, qb = traj.q_columns
    qw = w0 * qa[0].take(i) + w1 * qb[0].take(i)
    qx = w0 * qa[1].take(i) + w1 * qb[1].take(i)
    qy = w0 * qa[2].take(i) + w1 * qb[2].take(i)
    qz = w0 * qa[3].take(i) + w1 * qb[3].take(i)
    # v' = v + 2w (u x v) + 2 u x (u x v), with u = (qx, qy, qz)
    tx = 2.0 * (qy * bz - qz * by)
    ty = 2.0 * (qz * bx - qx * bz)
    tz = 2.0 * (qx * by - qy * bx)
    px, py, pz = traj.p_columns
    e = px.take(i) + f * (px.take(j) - px.take(i)) + bx + qw * tx + (qy * tz - qz * ty)
    n = py.take(i) + f * (py.take(j) - py.take(i)) + by + qw * ty + (qz * tx - qx * tz)
    u = pz.take(i) + f * (pz.take(j) - pz.take(i)) + bz + qw * tz + (qx * ty - qy * tx)
    return e, n, u


def georeference(
    traj: Trajectory,
    t: np.ndarray,
    v_s: tuple[np.ndarray, np.ndarray, np.ndarray],
    mounting: Mounting,
    to_map: Callable[..., tuple[np.ndarray, ...]],
    *,
    max_gap_s: float = MAX_GAP_S,
    chunk: int = 32_768,
    workers: int = 1,
    advance: Callable[[int], object] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Map coordinates (n, 3) of pulses (NaN where ``ok`` is False) and the mask ``ok`` of those with a trajectory.

    Parameters
    ----------
    traj, mounting : Trajectory, Mounting
        From :func:`prepare_trajectory` (GPS seconds since 1980-01-06, as *t*); boresight and lever arm.
    t, v_s : ndarray (n,), and three of them
        Pulse times, and pulse vectors in the scanner frame (x, y, z columns, metres).
    to_map : callable
        Local ENU columns (e, n, u) -> output CRS columns, e.g. ``MapTransform.columns``.
    max_gap_s : float
        Pulses inside a trajectory interval longer than this get no position.
    chunk, workers : int
        Pulses per block (small enough for the CPU cache), and threads (NumPy and PROJ release the GIL).
    advance : callable, optional
        Told how many pulses are done, about every tenth of them (the blocks run a tenth at a time).
    """
    n = len(t)
    out = np.full((n, 3), np.nan)
    ok_all = np.zeros(n, dtype=bool)

    def block(start: int) -> None:
        sl = slice(start, min(start + chunk, n))
        tt = np.asarray(t[sl], dtype=np.float64)
        i, f, ok = locate(traj, tt, max_gap_s)
        cols = [np.asarray(c[sl], dtype=np.float64) for c in v_s]
        every = bool(ok.all())
        if not every:
            i, f, cols = i[ok], f[ok], [c[ok] for c in cols]
        x, y, z = to_map(*georeference_local(traj, *cols, mounting, i, f))
        view = out[sl]
        if every:
            view[:, 0], view[:, 1], view[:, 2] = x, y, z
        else:
            view[ok, 0], view[ok, 1], view[ok, 2] = x, y, z
        ok_all[sl] = ok

    starts = range(0, n, chunk)
    step = max(-(-len(starts) // 10), workers) if advance is not None else max(len(starts), 1)
    for g in range(0, len(starts), step):
        group = starts[g : g + step]
        thread_map(block, group, workers)
        if advance is not None:
            advance(min(group[-1] + chunk, n) - group[0])
    return out, ok_all


LAS_GPS_OFFSET = 1e9  # LAS 1.4 adjusted standard GPS time = GPS seconds - 1e9


def ltp_crs(lat0: float, lon0: float, radius: float) -> pyproj.CRS:
    """The seed-0 LTP as a PROJ CRS: equidistant cylindrical on a sphere, true scale at lat0."""
    return pyproj.CRS.from_proj4(
        f"+proj=eqc +lat_ts={float(lat0)!r} +lat_0={float(lat0)!r} +lon_0={float(lon0)!r} +x_0=0 +y_0=0 +R={float(radius)!r} +units=m +no_defs"
    )


def prepare_exact(traj: dict, convention: str, pmeta: dict) -> tuple[Trajectory, Mounting]:
    """The trajectory in the exact frame (local level at the first fix) and the mounting of the pulses.

    *traj* holds the parse stage's trajectory columns, *pmeta* the pulses'
    metadata (its ``rotation`` and ``lever_arm`` make the :class:`Mounting`).
    """
    frame = LocalFrame(float(traj["lat"][0]), float(traj["lon"][0]), float(traj["h"][0]))
    exact = prepare_trajectory(
        traj["time"], traj["lat"], traj["lon"], traj["h"], traj["roll"], traj["pitch"], traj["yaw"], convention, frame
    )
    mounting = Mounting(np.asarray(pmeta["rotation"], dtype=np.float64), np.asarray(pmeta["lever_arm"], float))
    return exact, mounting


def prepare_ltp(traj: dict, convention: str, lat0: float, lon0: float, radius: float) -> Trajectory:
    """A :class:`Trajectory` in the seed-0 LTP: formula positions, one fixed local level."""
    lat, lon, h = (np.asarray(traj[k], dtype=np.float64) for k in ("lat", "lon", "h"))
    e = radius * np.radians(lon - lon0) * np.cos(np.radians(lat0))
    n = radius * np.radians(lat - lat0)
    position = np.column_stack((e, n, h))
    # the one local level of the plane: ENU <- the convention's axes at the first fix, for every epoch
    enu, level = (local_level_to_ecef(np.array([lat0]), np.array([lon0]), f)[0] for f in ("ENU", convention))
    q_n_b = euler_quat(*(np.radians(np.asarray(traj[k], dtype=np.float64)) for k in ("roll", "pitch", "yaw")))
    q = quat_mul(matrix_quat(enu.T @ level)[None, :], q_n_b)
    time = np.asarray(traj["time"], dtype=np.float64)
    return trajectory_from(time, position, q, LocalFrame(lat0, lon0, float(h[0])))


def pulse_reach(x: np.ndarray, y: np.ndarray, z: np.ndarray, batch_size: int = BATCH_SIZE) -> float:
    """The longest pulse vector (scanner frame, metres), read *batch_size* pulses at a time."""
    reach = 0.0
    for s in range(0, len(x), batch_size):
        sl = slice(s, s + batch_size)
        r = np.sqrt(x[sl] ** 2 + y[sl] ** 2 + z[sl] ** 2)
        reach = max(reach, float(r.max()))
    return reach


def same_columns(e: np.ndarray, n: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ltp frame's map: its plane is the output CRS, so columns are written as computed."""
    return e, n, u


@dataclass
class OutputFrame:
    """Where the points are written: the CRS, the trajectory the pulses are georeferenced in, and its map.

    Built by :func:`exact_output` or :func:`ltp_output`; ``lo`` and ``hi``
    bound the survey in the trajectory's local frame.
    """

    crs: pyproj.CRS
    trajectory: Trajectory
    to_map: MapTransform | None  # None: the ltp plane, which is its own map
    lo: np.ndarray
    hi: np.ndarray

    @property
    def columns(self) -> Callable[..., tuple[np.ndarray, ...]]:
        """Local columns (e, n, u) -> output-CRS columns, the ``to_map`` of :func:`georeference`."""
        return self.to_map.columns if self.to_map is not None else same_columns

    def points(self, local: np.ndarray) -> np.ndarray:
        """Output-CRS coordinates of (n, 3) local points."""
        return self.to_map(local) if self.to_map is not None else local

    def bounds(self) -> np.ndarray:
        """Output-CRS points whose box holds the survey: four corners of the local box (exact), or the box (ltp)."""
        lo, hi = self.lo, self.hi
        if self.to_map is None:
            return np.array([lo, hi])
        return self.to_map(
            np.array([[lo[0], lo[1], lo[2]], [hi[0], hi[1], hi[2]], [lo[0], hi[1], lo[2]], [hi[0], lo[1], hi[2]]])
        )


def exact_output(exact: Trajectory, crs: pyproj.CRS, reach: float, *, geoid: Path | None = None) -> OutputFrame:
    """The exact frame: PROJ (through :class:`MapTransform`) over the platform's box widened by *reach* metres."""
    lo = exact.position.min(axis=0) - reach
    hi = exact.position.max(axis=0) + reach
    return OutputFrame(crs, exact, MapTransform(exact.frame, crs, lo, hi, geoid=geoid), lo, hi)


def ltp_output(ltp: Trajectory, radius: float, reach: float) -> OutputFrame:
    """The seed-0 ltp plane of *ltp* (from :func:`prepare_ltp`), written with its PROJ definition."""
    lo = ltp.position.min(axis=0) - reach
    hi = ltp.position.max(axis=0) + reach
    return OutputFrame(ltp_crs(ltp.frame.lat0, ltp.frame.lon0, radius), ltp, None, lo, hi)


def platform_position(traj: Trajectory, i: np.ndarray, f: np.ndarray) -> np.ndarray:
    """The platform's (n, 3) local position at pulses located by :func:`locate`, linearly interpolated."""
    return traj.position[i] + (traj.position[i + 1] - traj.position[i]) * f[:, None]


def ltp_departure(
    exact: Trajectory,
    ltp: Trajectory,
    t: np.ndarray,
    v_s: tuple[np.ndarray, np.ndarray, np.ndarray],
    mounting: Mounting,
    max_gap_s: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """How far the seed-0 ltp plane puts pulses from the exact local tangent plane.

    Returns, for the pulses that have a trajectory: ltp minus exact (n, 3),
    the exact local points and the platform's exact local position, metres.
    """
    i, f, ok = locate(exact, t, max_gap_s)
    cols = tuple(c[ok] for c in v_s)
    ex = np.column_stack(georeference_local(exact, *cols, mounting, i[ok], f[ok]))
    platform = platform_position(exact, i[ok], f[ok])
    i, f, _ = locate(ltp, t, max_gap_s)
    lt = np.column_stack(georeference_local(ltp, *cols, mounting, i[ok], f[ok]))
    lt[:, 2] -= exact.frame.h0
    return lt - ex, ex, platform
