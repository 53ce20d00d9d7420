"""Strip adjustment: one small rigid correction per flight strip, from point-to-plane ICP solved jointly.

Smooth cells of each strip's single returns become patches (a quadratic
surface each, :func:`planar_patches`); patches of two strips at the same
place observe their disagreement along the normal (point-to-plane ICP; Chen
& Medioni 1992, doi:10.1016/0262-8856(92)90066-C).  Every strip gets a
correction p' = R_s (p - c_s) + c_s + t_s about its centroid, all strips
solved jointly by reweighted least squares with priors (:func:`adjust`), as
in Glira et al. (2015), ISPRS Annals II-3/W5,
doi:10.5194/isprsannals-II-3-W5-73-2015.  Where we depart: the corrections
are rigid per strip (no time-dependent trajectory terms), and the patches
are fitted once and moved with their strip.  See docs/stages/strip_adjust.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from pipeline.log import stage_progress
from stages.strip_adjust.params import StripAdjustParams

#: The stage's parameters at their defaults: the function's defaults are the configuration's.
_DEFAULT = StripAdjustParams()


@dataclass
class Patches:
    """Smooth cells of one strip (original coordinates): a quadratic surface z = q(x, y) per cell."""

    origin: np.ndarray  # (k, 3) cell reference point (the local frame of q)
    coef: np.ndarray  # (k, 6) q = c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2 in origin-relative x, y
    centroid: np.ndarray  # (k, 3)
    normal: np.ndarray  # (k, 3) unit normal of q at the centroid, pointing up
    rms: np.ndarray  # (k,)
    count: np.ndarray  # (k,)
    order: np.ndarray  # indices of the points sorted by patch
    starts: np.ndarray  # (k,) first position in `order` of each patch's points
    cell: float = 0.0

    def keep(self, mask: np.ndarray) -> None:
        """Drop the patches where *mask* is False (the point order stays: ``starts`` index into it)."""
        for name in ("origin", "coef", "centroid", "normal", "rms", "count", "starts"):
            setattr(self, name, getattr(self, name)[mask])

    def height(self, which: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """q of patches *which* at origin-relative (x, y)."""
        c = self.coef[which]
        return c[:, 0] + c[:, 1] * x + c[:, 2] * y + c[:, 3] * x * x + c[:, 4] * x * y + c[:, 5] * y * y

    def gradient(self, which: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(-dq/dx, -dq/dy, 1): the (unnormalised) normal, the gradient of z - q."""
        c = self.coef[which]
        return np.column_stack(
            (
                -(c[:, 1] + 2 * c[:, 3] * x + c[:, 4] * y),
                -(c[:, 2] + c[:, 4] * x + 2 * c[:, 5] * y),
                np.ones(len(which)),
            )
        )


@dataclass
class Transform:
    """p' = R (p - centre) + centre + t."""

    centre: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def apply(self, p: np.ndarray) -> np.ndarray:
        return (p - self.centre) @ self.rotation.T + self.centre + self.translation

    def apply_normals(self, n: np.ndarray) -> np.ndarray:
        return n @ self.rotation.T

    @property
    def rotation_vector(self) -> np.ndarray:
        """Axis x angle (radians) of R."""
        return Rotation.from_matrix(self.rotation).as_rotvec()


def planar_patches(
    xyz: np.ndarray, *, cell: float, min_points: int, max_rms: float, min_normal_z: float = 0.3
) -> Patches:
    """The smooth cells of a strip's points (docs/stages/strip_adjust.md, "Patches").

    Each cell's points are fitted with a quadratic surface (least squares,
    from moment sums: one pass, no per-cell Python); a cell is kept when it
    has *min_points*, its points spread over both directions (not one scan
    line), the fit's RMS is at most *max_rms* and it is not steeper than
    ``acos(min_normal_z)``.
    """
    if len(xyz) < min_points:
        return _no_patches(cell)
    order, starts, counts, origin, q = _cells(xyz, cell)
    good = counts >= min_points
    if not good.any():
        return _no_patches(cell)
    ata, atb, zz = _moment_sums(q, starts)
    n = counts.astype(np.float64)
    mx, my = ata[:, 0, 1] / n, ata[:, 0, 2] / n
    vxx, vyy, vxy = ata[:, 0, 3] / n - mx * mx, ata[:, 0, 5] / n - my * my, ata[:, 0, 4] / n - mx * my
    # smaller eigenvalue of the horizontal spread: the points must cover the cell in both directions
    spread = (vxx + vyy) / 2 - np.sqrt(((vxx - vyy) / 2) ** 2 + vxy**2)
    good &= spread > (cell / 8) ** 2
    if not good.any():
        return _no_patches(cell)
    idx = np.flatnonzero(good)
    coef = np.linalg.solve(ata[idx] + np.eye(6) * 1e-9, atb[idx][:, :, None])[:, :, 0]
    sse = zz[idx] - 2 * np.einsum("ki,ki->k", coef, atb[idx]) + np.einsum("ki,kij,kj->k", coef, ata[idx], coef)
    rms = np.sqrt(np.clip(sse, 0, None) / n[idx])
    cx, cy = mx[idx], my[idx]
    centroid = origin[idx] + np.column_stack((cx, cy, atb[idx, 0] / n[idx]))
    c = coef
    g = np.column_stack(
        (-(c[:, 1] + 2 * c[:, 3] * cx + c[:, 4] * cy), -(c[:, 2] + c[:, 4] * cx + 2 * c[:, 5] * cy), np.ones(len(idx)))
    )
    normal = g / np.linalg.norm(g, axis=1)[:, None]
    keep = (rms <= max_rms) & (normal[:, 2] >= min_normal_z)
    sel = idx[keep]
    return Patches(
        origin[sel], coef[keep], centroid[keep], normal[keep], rms[keep], counts[sel], order, starts[sel], cell
    )


def _no_patches(cell: float) -> Patches:
    """A strip without any patch."""
    return Patches(
        np.zeros((0, 3)),
        np.zeros((0, 6)),
        np.zeros((0, 3)),
        np.zeros((0, 3)),
        np.zeros(0),
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        np.zeros(0, np.int64),
        cell,
    )


def _cells(xyz: np.ndarray, cell: float) -> tuple[np.ndarray, ...]:
    """The points sorted by cell: the order, each cell's first position and count, its origin, and the
    sorted points relative to their cell's origin (the cell's centre at its first point's height)."""
    ix = np.floor(xyz[:, 0] / cell).astype(np.int64)
    iy = np.floor(xyz[:, 1] / cell).astype(np.int64)
    key = (ix - ix.min()) * (iy.max() - iy.min() + 1) + (iy - iy.min())
    order = np.argsort(key, kind="stable")
    k_sorted = key[order]
    starts = np.flatnonzero(np.concatenate(([True], k_sorted[1:] != k_sorted[:-1])))
    counts = np.diff(np.append(starts, len(order)))
    p = xyz[order]
    origin = np.column_stack(((ix[order][starts] + 0.5) * cell, (iy[order][starts] + 0.5) * cell, p[starts, 2]))
    return order, starts, counts, origin, p - np.repeat(origin, counts, axis=0)


def _moment_sums(q: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per cell (rows of *q* from each of *starts*): A'A and A'z of the quadratic's basis, and z'z."""
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    basis = [np.ones_like(x), x, y, x * x, x * y, y * y]
    ata = np.empty((len(starts), 6, 6))
    atb = np.empty((len(starts), 6))
    for i in range(6):
        atb[:, i] = np.add.reduceat(basis[i] * z, starts)
        for j in range(i, 6):
            ata[:, i, j] = ata[:, j, i] = np.add.reduceat(basis[i] * basis[j], starts)
    return ata, atb, np.add.reduceat(z * z, starts)


def patch_points(patches: Patches, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (into the strip's points) of the points of patches *which*, and the patch of each."""
    counts = patches.count[which]
    first = patches.starts[which]
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    return patches.order[np.repeat(first, counts) + offsets], np.repeat(np.arange(len(which)), counts)


def strip_patches(
    xyz: np.ndarray, strip: np.ndarray, strips: list[int], *, cell: float, min_points: int, max_rms: float
) -> tuple[dict[int, Patches], float | None]:
    """Each strip's planar patches, kept where smooth and well sampled; and the RMS limit used.

    Smooth means smooth for this survey: at most 2.5 x the median patch RMS
    (the noise level); well sampled means at least half the strip's median
    points per patch, which drops water (specular: most pulses return
    nothing) and the thinly sampled swath edges.  The patches' ``order``
    indexes *xyz*.  Without any patch the limit is None and nothing is dropped.
    """
    patches = {}
    for s in strips:
        sel = np.flatnonzero(strip == s)
        patches[s] = planar_patches(xyz[sel], cell=cell, min_points=min_points, max_rms=max_rms)
        patches[s].order = sel[patches[s].order]
    all_rms = np.concatenate([patches[s].rms for s in strips]) if strips else np.zeros(0)
    if not len(all_rms):
        return patches, None
    limit = min(max_rms, 2.5 * float(np.median(all_rms)))
    for s in strips:
        dense = patches[s].count >= 0.5 * np.median(patches[s].count) if len(patches[s].count) else True
        patches[s].keep((patches[s].rms <= limit) & dense)
    return patches, limit


def lattice_step(points: int, max_points: int) -> int:
    """Every how many cells in x and y the estimation samples, so that it uses about *max_points* (1: all)."""
    return max(1, int(np.ceil(np.sqrt(points / max_points))))


def on_lattice(xyz: np.ndarray, cell: float, step: int) -> np.ndarray:
    """Which points lie in the cells whose indices are multiples of *step* in x and y."""
    ix = np.floor(xyz[:, 0] / cell).astype(np.int64)
    iy = np.floor(xyz[:, 1] / cell).astype(np.int64)
    return (ix % step == 0) & (iy % step == 0)


@dataclass
class Pair:
    """Correspondences between patches of strip ``a`` (planes) and strip ``b`` (centroids)."""

    a: int
    b: int
    ia: np.ndarray
    ib: np.ndarray


def match(
    pa: Patches,
    ta: Transform,
    pb: Patches,
    tb: Transform,
    *,
    max_distance: float,
    max_angle_deg: float = 10.0,
    max_offset: float | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Patch pairs of two strips at the same place and on the same surface, under their current transforms.

    The two centroids must be within *max_offset* horizontally (default: half a cell).
    """
    if not len(pa.centroid) or not len(pb.centroid):
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ca, cb = ta.apply(pa.centroid), tb.apply(pb.centroid)
    na, nb = ta.apply_normals(pa.normal), tb.apply_normals(pb.normal)
    limit = pa.cell / 2 if max_offset is None else max_offset
    dist, ia = cKDTree(ca[:, :2]).query(cb[:, :2], distance_upper_bound=limit)
    ok = np.isfinite(dist)
    ib = np.flatnonzero(ok)
    ia = ia[ok]
    r = np.einsum("ij,ij->i", na[ia], cb[ib] - ca[ia])
    same = (np.abs(r) <= max_distance) & (np.einsum("ij,ij->i", na[ia], nb[ib]) >= np.cos(np.radians(max_angle_deg)))
    return ia[same], ib[same]


def _rotation(omega: np.ndarray) -> np.ndarray:
    return Rotation.from_rotvec(omega).as_matrix()


def surface_residuals(
    ps: Patches, ts: Transform, pt: Patches, tt: Transform, ia: np.ndarray, ib: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Distances of strip t's points to strip s's surfaces, for matched patches (``ia`` of s, ``ib`` of t).

    Returns per point: the signed distance along the surface normal and the
    pair index; per pair: the mean (x, y) of t's points in s's patch frame
    and t's points' world centroid.
    """
    idx, which = patch_points(pt, ib)
    world = tt.apply(points[idx])
    local = (world - ts.centre - ts.translation) @ ts.rotation + ts.centre - ps.origin[ia[which]]
    k = ia[which]
    g = ps.gradient(k, local[:, 0], local[:, 1])
    dist = (local[:, 2] - ps.height(k, local[:, 0], local[:, 1])) / np.linalg.norm(g, axis=1)
    npair = len(ia)
    cnt = np.maximum(np.bincount(which, minlength=npair), 1)
    mean_xy = np.column_stack([np.bincount(which, local[:, j], npair) / cnt for j in range(2)])
    centre = np.column_stack([np.bincount(which, world[:, j], npair) / cnt for j in range(3)])
    return dist, which, mean_xy, centre


@dataclass
class Solution:
    transforms: dict[int, Transform]
    iterations: int
    pairs: list[Pair]
    sigma: float  # robust scale of the last iteration's residuals, metres
    correspondences: int
    std: dict[int, np.ndarray] = field(default_factory=dict)  # 1-sigma of (tx, ty, tz, wx, wy, wz), m and rad


def adjust(
    patches: dict[int, Patches],
    centres: dict[int, np.ndarray],
    points: np.ndarray,
    *,
    reference: int | None,
    control: np.ndarray | None = None,
    fixed: tuple[int, ...] = (),
    max_distance: float = _DEFAULT.max_distance,
    max_iterations: int = _DEFAULT.max_iterations,
    prior_translation: float = 1.0,
    prior_rotation: float = np.radians(0.5),
    prior_yaw: float = np.radians(0.01),
    tolerance: float = 1e-4,
) -> Solution:
    """Joint ICP over every overlapping strip pair: the transforms and their sigmas.

    Parameters
    ----------
    patches, centres : dict
        Strip id -> :class:`Patches` (their ``order`` indexes *points*, (n, 3)), and -> its rotation centre.
    reference : int or None
        Strip held fixed (the datum); None when *control* (ground control points, (m, 3)) fixes it.
    fixed : tuple of int
        Strips held as they are besides the reference (e.g. poorly determined ones).
    max_distance, prior_translation, prior_rotation, prior_yaw : float
        Patches farther apart along the normal are not matched (m); prior sigmas of a correction (m, rad).
    tolerance : float
        Stop when no translation changes by more than this (m) and no rotation by more than this / 1000 (rad).
    """
    strips = sorted(patches)
    free = [s for s in strips if s != reference and s not in fixed]
    col = {s: 6 * i for i, s in enumerate(free)}
    tf = {s: Transform(np.asarray(centres[s], float)) for s in strips}
    priors = (prior_translation, prior_rotation, prior_yaw)
    pairs: list[Pair] = []
    sigma = 0.0
    n_corr = 0
    it = 0
    cov = np.zeros((0, 0))
    bar = stage_progress(max_iterations, f"joint ICP, at most {max_iterations} iterations", unit="iterations")
    for it in range(1, max_iterations + 1):  # noqa: B007 - reported
        if it > 1:
            bar.update(1)
        rows, pairs = _pair_observations(patches, tf, points, col, 6 * len(free), max_distance)
        if control is not None and len(control):
            rows += _control_observations(patches, tf, control, col, 6 * len(free))
        if not rows or not free:
            break
        jac = np.vstack([j for j, _, _ in rows])
        r = np.concatenate([v for _, v, _ in rows])
        cnt = np.concatenate([w for _, _, w in rows])
        n_corr = len(r)
        dx, cov, sigma = _irls_step(jac, r, cnt, tf, free, priors)
        for s in free:
            d = dx[col[s] : col[s] + 6]
            tf[s].rotation = _rotation(d[3:]) @ tf[s].rotation
            tf[s].translation = tf[s].translation + d[:3]
        moves = dx.reshape(-1, 6)
        if np.max(np.abs(moves[:, :3])) < tolerance and np.max(np.abs(moves[:, 3:])) < tolerance / 1000:
            break
    bar.close()
    std = {}
    if free and n_corr:
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        std = {s: sd[col[s] : col[s] + 6] for s in free}
    return Solution(tf, it, pairs, sigma, n_corr, std)


def _rigid_columns(jac: np.ndarray, c: int, tf: Transform, at: np.ndarray, n_w: np.ndarray, sign: float) -> None:
    """Fill the six columns from *c* of a strip moved by *tf*: d(distance along n_w at *at*)/d(t, omega)."""
    if sign > 0:
        jac[:, c : c + 3] = n_w
        jac[:, c + 3 : c + 6] = np.cross(at - (tf.centre + tf.translation), n_w)
    else:
        jac[:, c : c + 3] = -n_w
        jac[:, c + 3 : c + 6] = -np.cross(at - (tf.centre + tf.translation), n_w)


def _fitting(ps: Patches, ts: Transform, pt: Patches, tt: Transform, ia: np.ndarray, ib: np.ndarray, points):
    """Matched patches whose points fit the other strip's surface, with each's mean distance and point count.

    Strip t's points must fit s's surface as well as each fits its own: where they do not, the surface is
    not the same or not smooth enough there (edges, kinks, canopy).  Returns ia, ib, the mean distances,
    the counts, t's point centroids and their mean (x, y) in s's patch frame.
    """
    dist, which, mean_xy, ct = surface_residuals(ps, ts, pt, tt, ia, ib, points)
    cnt = np.bincount(which, minlength=len(ia)).astype(np.float64)
    r = np.bincount(which, dist, len(ia)) / np.maximum(cnt, 1)
    spread = np.sqrt(np.bincount(which, dist**2, len(ia)) / np.maximum(cnt, 1) - r**2)
    fits = spread <= 2.0 * np.hypot(ps.rms[ia], pt.rms[ib]) + 0.005
    if not fits.all():
        return ia[fits], ib[fits], r[fits], cnt[fits], ct[fits], mean_xy[fits]
    return ia, ib, r, cnt, ct, mean_xy


def _pair_observations(patches, tf, points, col, n_cols, max_distance):
    """The observation rows (Jacobian, mean distance, weight) of every strip pair, both ways, and the pairs.

    A pair (a < b) is listed whenever its patches match, even when none of them fits.
    """
    strips = sorted(patches)
    rows, pairs = [], []
    for i, a in enumerate(strips):
        for b in strips[i + 1 :]:
            for s, t in ((a, b), (b, a)):
                ia, ib = match(patches[s], tf[s], patches[t], tf[t], max_distance=max_distance)
                if len(ia) == 0:
                    continue
                ia, ib, r, cnt, ct, mean_xy = _fitting(patches[s], tf[s], patches[t], tf[t], ia, ib, points)
                if s < t:
                    pairs.append(Pair(s, t, ia, ib))
                if len(ia) == 0:
                    continue
                g = patches[s].gradient(ia, mean_xy[:, 0], mean_xy[:, 1])
                n_w = tf[s].apply_normals(g / np.linalg.norm(g, axis=1)[:, None])
                jac = np.zeros((len(r), n_cols))
                if t in col:
                    _rigid_columns(jac, col[t], tf[t], ct, n_w, 1.0)
                if s in col:
                    _rigid_columns(jac, col[s], tf[s], ct, n_w, -1.0)
                rows.append((jac, r, cnt))
    return rows, pairs


def _control_observations(patches, tf, control, col, n_cols):
    """The observation rows of ground control points: each one's distance to the patch of a strip it lies in."""
    rows = []
    for s in sorted(patches):
        if not len(patches[s].centroid) or s not in col:
            continue
        cs = tf[s].apply(patches[s].centroid)
        dist, k = cKDTree(cs[:, :2]).query(control[:, :2], distance_upper_bound=patches[s].cell / 2)
        ok = np.isfinite(dist)
        if not ok.any():
            continue
        k = k[ok]
        local = (control[ok] - tf[s].centre - tf[s].translation) @ tf[s].rotation + tf[s].centre
        local -= patches[s].origin[k]
        g = patches[s].gradient(k, local[:, 0], local[:, 1])
        norm = np.linalg.norm(g, axis=1)
        r = (local[:, 2] - patches[s].height(k, local[:, 0], local[:, 1])) / norm
        n_w = tf[s].apply_normals(g / norm[:, None])
        jac = np.zeros((len(r), n_cols))
        _rigid_columns(jac, col[s], tf[s], control[ok], n_w, -1.0)
        rows.append((jac, r, np.full(len(r), 100.0)))  # a surveyed point weighs as a patch of 100 points
    return rows


def _irls_step(jac, r, cnt, tf, free, priors):
    """One reweighted least-squares step: the correction of every free strip, its covariance, the robust scale.

    Huber weights (k = 2 robust sigmas) per point, and a prior on the total correction: (x + dx) ~ N(0, diag).
    """
    prior_translation, prior_rotation, prior_yaw = priors
    # residuals are means of `cnt` points: scale them to one point before the robust estimate
    z = r * np.sqrt(cnt)
    sigma = max(1.4826 * np.median(np.abs(z - np.median(z))), 0.002)
    w = cnt * np.minimum(1.0, 2.0 * sigma / np.maximum(np.abs(z), 1e-12))  # Huber, per point
    x = np.concatenate([np.concatenate((tf[s].translation, tf[s].rotation_vector)) for s in free])
    prior = np.tile(
        np.r_[np.full(3, 1 / prior_translation**2), np.full(2, 1 / prior_rotation**2), 1 / prior_yaw**2], len(free)
    )
    jw = jac * (w / sigma**2)[:, None]
    normal = jac.T @ jw + np.diag(prior)
    rhs = -(jw.T @ r) - prior * x
    dx = np.linalg.solve(normal, rhs)
    return dx, np.linalg.inv(normal), sigma
