"""System calibration from overlapping strips: boresight, lever arm, range offset (issue 23).

Every pulse is georeferenced again (:mod:`lidar.georeferencing`) with a corrected mounting::

    p = pos(t) + R(t) . (dR . R_s^b . v_s (1 + dr / |v_s|) + a_b + da) [+ o_strip]

The unknowns (boresight dR, lever arm da, range offset dr, strip offsets) are
estimated from the overlaps by Gauss-Newton with Huber weights and a numerical
Jacobian, correspondences searched again each round, undeterminable unknowns
held: Skaloud & Lichti (2006), doi:10.1016/j.isprsjprs.2006.07.001; Glira et
al. (2015), doi:10.5194/isprsannals-II-3-W5-73-2015; Filin (2003),
doi:10.14358/PERS.69.11.1235.  Where we depart: each link's surface is refitted
from one strip's points at every evaluation (no plane unknowns); see
docs/CALIBRATION.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from lidar.georeferencing import Mounting, Trajectory, georeference_local
from lidar.rotation import euler_matrix
from stages.strip_adjust.params import MountingParams, StripAdjustParams

#: The parameters at their defaults: the function's defaults are the configuration's.
_DEFAULT, _MOUNTING = StripAdjustParams(), MountingParams()

NAMES = (
    "boresight_roll",
    "boresight_pitch",
    "boresight_yaw",
    "lever_arm_x",
    "lever_arm_y",
    "lever_arm_z",
    "range_offset",
)
#: which flight lines determine an unknown that the flight could not
ADVICE = {
    "boresight_roll": "overlapping lines flown in opposite directions (a roll error tilts the swath one way on "
    "one line and the other way on the other)",
    "boresight_pitch": "lines flown in opposite directions over the same ground with slopes or roofs (a pitch "
    "error shifts the points forward on one line, backward on the other; on lines flown one way it is an "
    "along-track offset)",
    "boresight_yaw": "lines flown in opposite directions with overlapping swath edges over ground with slopes or "
    "roofs, or a cross line (a yaw error shifts the swath edges along track, in opposite senses: over level "
    "ground only horizontally)",
    "lever_arm_x": "lines at two flying heights (a lever-arm error moves the points the same at any height, a "
    "boresight error more the higher the flight), in opposite directions",
    "lever_arm_y": "lines at two flying heights (a lever-arm error moves the points the same at any height, a "
    "boresight error more the higher the flight), in opposite directions",
    "lever_arm_z": "ground control points (a vertical lever-arm error lifts or lowers every strip alike)",
    "range_offset": "ground control points, or a cross line (a range offset moves the swath edges differently "
    "from its centre)",
    "strip_offset": "more overlap with other strips, or ground control points in the strip",
}


@dataclass
class Sample:
    """The pulses of the estimation: trajectory interval and fraction, scanner vector, strip."""

    i: np.ndarray
    f: np.ndarray
    v: np.ndarray  # (n, 3) scanner-frame vectors, metres
    strip: np.ndarray  # (n,) strip id

    def __post_init__(self) -> None:
        self.range = np.linalg.norm(self.v, axis=1)

    def subset(self, idx: np.ndarray) -> Sample:
        return Sample(self.i[idx], self.f[idx], self.v[idx], self.strip[idx])


@dataclass
class Unknowns:
    """The unknowns' names, finite-difference steps, sigma limits and which are estimated."""

    names: list[str]
    step: np.ndarray
    limit: np.ndarray
    free: list[int]
    offset_strips: list[int] = field(default_factory=list)  # strips with an offset, in column order

    @property
    def size(self) -> int:
        return len(self.names)


def make_unknowns(
    *,
    lever_arm: bool,
    range_offset: bool,
    offset_strips: list[int],
    reference: int | None,
    limits: tuple[float, float, float, float],
) -> Unknowns:
    """Boresight (always), lever arm, range offset, per-strip offsets (not of the *reference* strip)."""
    b, la, ro, so = limits
    names = list(NAMES)
    step = [1e-6] * 3 + [1e-3] * 4
    limit = [np.radians(b)] * 3 + [la] * 3 + [ro]
    free = [0, 1, 2] + ([3, 4, 5] if lever_arm else []) + ([6] if range_offset else [])
    for s in offset_strips:
        for axis in "enu":
            names.append(f"strip_{s}_offset_{axis}")
            step.append(1e-3)
            limit.append(so)
            if s != reference:
                free.append(len(names) - 1)
    return Unknowns(names, np.asarray(step), np.asarray(limit), free, list(offset_strips))


def georeference_sample(
    traj: Trajectory, mounting: Mounting, sample: Sample, theta: np.ndarray, unknowns: Unknowns
) -> np.ndarray:
    """Local ENU points (n, 3) of *sample* under the corrections *theta* (radians and metres)."""
    scale = 1.0 + theta[6] / np.maximum(sample.range, 1e-9)
    corrected = corrected_mounting(mounting, theta)
    v = sample.v * scale[:, None]
    e, n, u = georeference_local(traj, v[:, 0], v[:, 1], v[:, 2], corrected, sample.i, sample.f)
    xyz = np.column_stack((e, n, u))
    if unknowns.offset_strips:
        table = np.zeros((int(sample.strip.max(initial=0)) + 1, 3))
        for k, s in enumerate(unknowns.offset_strips):
            if s < len(table):
                table[s] = theta[7 + 3 * k : 10 + 3 * k]
        xyz += table[sample.strip]
    return xyz


@dataclass
class Links:
    """Correspondences: per link, the points fitted with a surface and the points (or one control point)
    measured against it; indices into one :class:`Sample`."""

    surf: np.ndarray
    surf_group: np.ndarray
    obs: np.ndarray
    obs_group: np.ndarray
    origin: np.ndarray  # (k, 3) the local frame of each link's surface
    strips: np.ndarray  # (k, 2) surface strip, observed strip (0: a control point)
    weight: np.ndarray  # (k,) base weight: points observed (a control point: 100)
    fixed: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # control points, local ENU
    fixed_group: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))

    @property
    def size(self) -> int:
        return len(self.origin)


def _fit_quadratics(q: np.ndarray, group: np.ndarray, k: int, normals: bool = False):
    """Least-squares z = c0 + c1 x + c2 y + c3 x^2 + c4 x y + c5 y^2 per group (coef (k, 6)); with
    *normals*, also the regularised normal matrices (k, 6, 6)."""
    x, y, z = q[:, 0], q[:, 1], q[:, 2]
    basis = (np.ones_like(x), x, y, x * x, x * y, y * y)
    ata = np.empty((k, 6, 6))
    atb = np.empty((k, 6))
    for i in range(6):
        atb[:, i] = np.bincount(group, basis[i] * z, k)
        for j in range(i, 6):
            ata[:, i, j] = ata[:, j, i] = np.bincount(group, basis[i] * basis[j], k)
    ata += 1e-9 * np.maximum(np.einsum("kii->k", ata), 1.0)[:, None, None] * np.eye(6)
    coef = np.linalg.solve(ata, atb[:, :, None])[:, :, 0]
    return (coef, ata) if normals else coef


def _observed(links: Links, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every observed point (the strips' points, then the control points) in its link's surface frame, and
    its link."""
    g = np.concatenate((links.obs_group, links.fixed_group))
    return np.vstack((xyz[links.obs], links.fixed)) - links.origin[g], g


def distances(links: Links, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signed distance of every observed point to its link's surface, and the link of each."""
    k = links.size
    coef = _fit_quadratics(xyz[links.surf] - links.origin[links.surf_group], links.surf_group, k)
    q, g = _observed(links, xyz)
    c = coef[g]
    x, y = q[:, 0], q[:, 1]
    height = c[:, 0] + c[:, 1] * x + c[:, 2] * y + c[:, 3] * x * x + c[:, 4] * x * y + c[:, 5] * y * y
    gx = c[:, 1] + 2 * c[:, 3] * x + c[:, 4] * y
    gy = c[:, 2] + c[:, 4] * x + 2 * c[:, 5] * y
    return (q[:, 2] - height) / np.sqrt(1.0 + gx * gx + gy * gy), g


def link_weights(links: Links, xyz: np.ndarray) -> np.ndarray:
    """Inverse variance of each link's residual, in units of one point's variance: 1 / (1/n + h), with n
    the points observed (a control point counts as *weight* points) and h the variance factor of the
    fitted surface at their mean position (x_mean' (A'A)^-1 x_mean): a surface fitted to few points
    is uncertain, and its uncertainty enters the mean distance undiminished."""
    k = links.size
    _, ata = _fit_quadratics(xyz[links.surf] - links.origin[links.surf_group], links.surf_group, k, normals=True)
    q, g = _observed(links, xyz)
    x, y = q[:, 0], q[:, 1]
    cnt = np.maximum(np.bincount(g, minlength=k), 1)
    mean = np.column_stack([np.bincount(g, v, k) / cnt for v in (np.ones_like(x), x, y, x * x, x * y, y * y)])
    h = np.einsum("ki,ki->k", mean, np.linalg.solve(ata, mean[:, :, None])[:, :, 0])
    return 1.0 / (1.0 / links.weight + h)


def residuals(links: Links, xyz: np.ndarray) -> np.ndarray:
    """Per link: the mean signed distance of its observed points to its surface."""
    d, g = distances(links, xyz)
    cnt = np.maximum(np.bincount(g, minlength=links.size), 1)
    return np.bincount(g, d, links.size) / cnt


def jacobian(
    traj: Trajectory,
    mounting: Mounting,
    sample: Sample,
    links: Links,
    theta: np.ndarray,
    unknowns: Unknowns,
    cols: list[int],
) -> np.ndarray:
    """d residuals / d unknowns (columns *cols*) by central differences of the georeferencing."""
    jac = np.empty((links.size, len(cols)))
    base = None
    for c, j in enumerate(cols):
        h = unknowns.step[j]
        out = []
        for sign in (1.0, -1.0):
            if j >= 7:  # a strip offset: the points of that strip move; no need to georeference again
                if base is None:
                    base = georeference_sample(traj, mounting, sample, theta, unknowns)
                s = unknowns.offset_strips[(j - 7) // 3]
                xyz = base.copy()
                xyz[sample.strip == s, (j - 7) % 3] += sign * h
            else:
                t = theta.copy()
                t[j] += sign * h
                xyz = georeference_sample(traj, mounting, sample, t, unknowns)
            out.append(residuals(links, xyz))
        jac[:, c] = (out[0] - out[1]) / (2 * h)
    return jac


#: A patch's fitted slope counts in :func:`geometry_jacobian` only when it is this far from level, in the
#: squared Mahalanobis distance of its two components: 25 (5 sigma), so that the level patches taken for
#: sloping by chance (at 3 sigma, 1 in 90 of them) do not add up to information on a large flight.
LEVEL_T2 = 25.0


def geometry_jacobian(
    traj: Trajectory,
    mounting: Mounting,
    sample: Sample,
    links: Links,
    theta: np.ndarray,
    unknowns: Unknowns,
    cols: list[int],
    sigma: float,
) -> np.ndarray:
    """d residuals / d unknowns (columns *cols*) from what the geometry shows, not from the patches' noise.

    A link's residual moves by ``n . (d_obs - d_surf)`` when the unknown moves the observed points by
    ``d_obs`` and the surface's by ``d_surf`` (means over each side), ``n`` the surface's normal.  Over a
    level surface a horizontal move is invisible; but the slope fitted to noisy points is never exactly
    level, and :func:`jacobian` (which differentiates the refitted surfaces) sees a random slope times a
    horizontal move as information.  Here a patch's slope counts only where it differs from level by
    :data:`LEVEL_T2` (5 sigma, from the quadratic fit's covariance with the one-point noise *sigma*);
    elsewhere only the vertical part of the move counts.
    """
    xyz = georeference_sample(traj, mounting, sample, theta, unknowns)
    k = links.size
    coef, ata = _fit_quadratics(xyz[links.surf] - links.origin[links.surf_group], links.surf_group, k, normals=True)
    q, g = _observed(links, xyz)
    cnt = np.maximum(np.bincount(g, minlength=k), 1)[:, None]
    scnt = np.maximum(np.bincount(links.surf_group, minlength=k), 1)[:, None]
    x, y = (np.bincount(g, q[:, i], k) / cnt[:, 0] for i in (0, 1))
    zero, one = np.zeros(k), np.ones(k)
    grad = np.stack(
        (np.stack((zero, one, zero, 2 * x, y, zero), axis=1), np.stack((zero, zero, one, zero, x, 2 * y), axis=1)),
        axis=1,
    )  # (k, 2, 6): the slope at the observed points' mean, as a linear function of the coefficients
    slope = np.einsum("kij,kj->ki", grad, coef)
    cov = sigma**2 * grad @ np.linalg.solve(ata, grad.transpose(0, 2, 1))
    cov += 1e-18 * np.eye(2)
    t2 = np.einsum("ki,ki->k", slope, np.linalg.solve(cov, slope[:, :, None])[:, :, 0])
    seen = np.where((t2 >= LEVEL_T2)[:, None], slope, 0.0)
    norm = np.sqrt(1.0 + np.sum(slope**2, axis=1))
    jac = np.empty((k, len(cols)))
    for c, j in enumerate(cols):
        if j >= 7:  # a strip offset moves that strip's points by one unit
            disp = np.zeros_like(xyz)
            disp[sample.strip == unknowns.offset_strips[(j - 7) // 3], (j - 7) % 3] = 1.0
        else:
            h = unknowns.step[j]
            plus, minus = theta.copy(), theta.copy()
            plus[j] += h
            minus[j] -= h
            disp = georeference_sample(traj, mounting, sample, plus, unknowns)
            disp = (disp - georeference_sample(traj, mounting, sample, minus, unknowns)) / (2 * h)
        d_obs = np.vstack((disp[links.obs], np.zeros_like(links.fixed)))
        move = np.column_stack([np.bincount(g, d_obs[:, i], k) for i in range(3)]) / cnt
        d_surf = disp[links.surf]
        move -= np.column_stack([np.bincount(links.surf_group, d_surf[:, i], k) for i in range(3)]) / scnt
        jac[:, c] = (move[:, 2] - np.sum(seen * move[:, :2], axis=1)) / norm
    return jac


def robust_weights(r: np.ndarray, base: np.ndarray) -> tuple[np.ndarray, float]:
    """Huber weights (k = 2) of residuals whose variances are sigma^2 / *base*, and the robust scale sigma
    (of one point)."""
    z = r * np.sqrt(base)
    sigma = max(1.4826 * float(np.median(np.abs(z - np.median(z)))), 1e-4)
    return base * np.minimum(1.0, 2.0 * sigma / np.maximum(np.abs(z), 1e-12)), sigma


#: Why an unknown no observation depends on is held: its error moves nothing, so it biases no other.
NO_OBSERVATION = "no observation depends on it"


def determinability(
    jac: np.ndarray,
    w: np.ndarray,
    sigma: float,
    unknowns: Unknowns,
    cols: list[int],
    max_correlation: float,
    held: dict[int, str] | None = None,
) -> dict[int, str]:
    """Unknowns (column numbers of the full vector) the observations cannot determine, with the reason.

    One at a time, the worst first: an unknown with no observation depending on it, then the one whose
    1-sigma (from the inverse normal matrix) is the largest multiple of its limit among those above the
    limit or correlated beyond *max_correlation* with another.  Those already in *held* stay held.
    """
    held = dict(held or {})
    while True:
        keep = [c for c in cols if c not in held]
        if not keep:
            return held
        sel = [cols.index(c) for c in keep]
        a = jac[:, sel]
        normal = a.T @ (a * (w / sigma**2)[:, None])
        d = np.sqrt(np.clip(np.diag(normal), 0, None))
        dead = [c for c, dd in zip(keep, d, strict=True) if dd <= 1e-12 * max(float(d.max()), 1e-300)]
        if dead:
            held[dead[0]] = NO_OBSERVATION
            continue
        scaled = normal / np.outer(d, d)
        vals, vecs = np.linalg.eigh(scaled)
        inv = (vecs / np.maximum(vals, 1e-15)) @ vecs.T
        cov = inv / np.outer(d, d)
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        corr = cov / np.outer(sd, sd)
        ratio = sd / unknowns.limit[keep]
        worst, why = None, ""
        for a_i, c in enumerate(keep):
            reason = None
            if ratio[a_i] > 1:
                reason = f"1-sigma {_fmt(sd[a_i], c, unknowns)} above the limit {_fmt(unknowns.limit[c], c, unknowns)}"
            others = [b_i for b_i in range(len(keep)) if b_i != a_i and abs(corr[a_i, b_i]) > max_correlation]
            others = [b_i for b_i in others if ratio[b_i] <= ratio[a_i]]
            if others and reason is None:
                b_i = max(others, key=lambda b: abs(corr[a_i, b]))
                reason = f"correlated {corr[a_i, b_i]:+.3f} with {unknowns.names[keep[b_i]]}"
            if reason is not None and (worst is None or ratio[a_i] > ratio[keep.index(worst)]):
                worst, why = c, reason
        if worst is None:
            return held
        held[worst] = why


def consider(
    jac: np.ndarray, w: np.ndarray, sigma: float, unknowns: Unknowns, free: list[int], held: list[int]
) -> tuple[np.ndarray, np.ndarray]:
    """The variances of the unknowns *free* (columns of *jac*, then *held*'s), and how far each held one moves them.

    Each held unknown is taken as right to within its own limit (the accuracy the calibration asks of an
    estimate; the flight cannot say more).  Through the correlation, an error ``e`` of a held unknown moves
    the estimates by ``-inv(N_ff) N_fh e`` (consider analysis): the shifts, (free, held), for ``e`` its
    limit.  *w* are the links' weights in units of one point, *sigma* one point's noise.
    """
    a, b = jac[:, : len(free)], jac[:, len(free) :]
    nff = a.T @ (a * w[:, None])
    vals, vecs = np.linalg.eigh(nff)
    variance = sigma**2 * np.diag((vecs / np.maximum(vals, 1e-300)) @ vecs.T)
    if not held:
        return variance, np.zeros((len(free), 0))
    shift = np.linalg.lstsq(nff, a.T @ (b * w[:, None]), rcond=None)[0] * unknowns.limit[held]
    return variance, np.abs(shift)


def leakage(
    jac: np.ndarray, w: np.ndarray, sigma: float, unknowns: Unknowns, cols: list[int], held: dict[int, str]
) -> tuple[int, str] | None:
    """The estimated unknown that a held one would bias beyond its limit, and why; None when there is none.

    An estimate whose sigma with the held unknowns' effect (:func:`consider`) added in quadrature exceeds
    its limit cannot be told from the held unknown that moves it most with these lines.
    """
    free = [c for c in cols if c not in held]
    considered = [c for c in held if c in cols and held[c] != NO_OBSERVATION]
    if not free or not considered:
        return None
    order = [cols.index(c) for c in free + considered]
    variance, shift = consider(jac[:, order], w, sigma, unknowns, free, considered)
    ratio = np.sqrt(variance + np.sum(shift**2, axis=1)) / unknowns.limit[free]
    worst = int(np.argmax(ratio))
    if ratio[worst] <= 1.0:
        return None
    h = int(np.argmax(shift[worst]))
    c, by = free[worst], considered[h]
    return c, (
        f"cannot be told from {unknowns.names[by]} with these lines: an error of "
        f"{_fmt(unknowns.limit[by], by, unknowns)} in the held {unknowns.names[by]} would move it by "
        f"{_fmt(shift[worst, h], c, unknowns)}, with its own 1-sigma above the limit "
        f"{_fmt(unknowns.limit[c], c, unknowns)}"
    )


def _fmt(value: float, col: int, unknowns: Unknowns) -> str:
    return f"{np.degrees(value):.4f} deg" if col < 3 else f"{value:.4f} m"


@dataclass
class Calibration:
    """The applied corrections (radians, metres), the estimates with their sigmas and correlations, what was
    held and why."""

    theta: np.ndarray
    unknowns: Unknowns
    free: list[int]
    # (size,) NaN where not estimated; for an applied unknown the larger of the formal and the geometric
    # sigma, with the held unknowns' effect added
    sigma: np.ndarray
    correlation: np.ndarray  # (len(free), len(free))
    held: dict[int, str]
    residual_sigma: float
    iterations: int
    links: Links
    sample: Sample
    estimate: np.ndarray  # (size,) the estimate of every determinable unknown, before the significance test
    not_significant: dict[int, str]  # estimated but not applied (held at the configured value), and why
    # applied unknown -> (the held unknown that moves it most, by how much for an error of that one's limit);
    # its sigma includes the effect of every held unknown
    held_effect: dict[int, tuple[int, float]] = field(default_factory=dict)


def solve(
    traj: Trajectory,
    mounting: Mounting,
    sample: Sample,
    find_links: Callable[[np.ndarray], tuple[Links, np.ndarray] | None],
    unknowns: Unknowns,
    *,
    rounds: int = _MOUNTING.rounds,
    max_iterations: int = _DEFAULT.max_iterations,
    max_correlation: float = _MOUNTING.max_correlation,
    min_significance: float = _MOUNTING.min_significance,
    log: Callable | None = None,
) -> Calibration | None:
    """Gauss-Newton over *rounds* correspondence searches (docs/CALIBRATION.md).

    *find_links(xyz)* returns the :class:`Links` of the sample's points *xyz* (local ENU) and the sample
    indices they use.  Returns None when there is no correspondence.  After the first round the unknowns
    the flight cannot determine are held (:func:`determinability`); after the last, an estimate within
    *min_significance* of its sigmas of zero is not applied (0: apply every estimate).  *log(round, theta,
    sigma, links)* is told of each round.
    """
    theta = np.zeros(unknowns.size)
    free = list(unknowns.free)
    held: dict[int, str] = {}
    gn = _GaussNewton(traj, mounting, unknowns, max_iterations)
    for rnd in range(max(rounds, 2)):
        found = find_links(georeference_sample(traj, mounting, sample, theta, unknowns))
        if found is None:
            if rnd == 0:
                return None
            break
        gn.links, used = found
        gn.sample = sample.subset(used)
        gn.iterate(theta, free, prior_on=rnd == 0)
        if log is not None:
            log(rnd, theta, gn.sigma, gn.links.size)
        if rnd == 0:
            held = gn.undetermined(theta, free, max_correlation)
            free = [c for c in free if c not in held]
            theta[list(held)] = 0.0
    estimate = theta.copy()
    sd_full = np.full(unknowns.size, np.nan)
    corr = np.zeros((len(free), len(free)))
    if free and gn.cov.size:
        sd = np.sqrt(np.clip(np.diag(gn.cov), 0, None))
        sd_full[free] = sd
        corr = gn.cov / np.outer(sd, sd)
    not_significant = gn.drop_insignificant(theta, free, min_significance)
    applied = [c for c in free if c not in not_significant]
    geometric, added, effect = gn.held_effect(theta, applied, held)
    sd_full[applied] = np.sqrt(np.maximum(sd_full[applied] ** 2, geometric) + added)
    return Calibration(
        theta,
        unknowns,
        free,
        sd_full,
        corr,
        held,
        gn.sigma,
        gn.iterations,
        gn.links,
        gn.sample,
        estimate,
        not_significant,
        effect,
    )


@dataclass
class _GaussNewton:
    """The iterations of :func:`solve` on one round's links and sample, and what they leave behind."""

    traj: Trajectory
    mounting: Mounting
    unknowns: Unknowns
    max_iterations: int
    links: Links | None = None
    sample: Sample | None = None
    cov: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # of the columns last solved for
    sigma: float = 0.0  # robust residual scale of one point, metres
    iterations: int = 0

    def iterate(self, theta: np.ndarray, cols: list[int], prior_on: bool) -> None:
        """Gauss-Newton steps on the unknowns *cols* of *theta* (in place), until they stop moving."""
        traj, mounting, sub, links, unknowns = self.traj, self.mounting, self.sample, self.links, self.unknowns
        for _ in range(self.max_iterations):
            xyz = georeference_sample(traj, mounting, sub, theta, unknowns)
            r = residuals(links, xyz)
            w, self.sigma = robust_weights(r, link_weights(links, xyz))
            if not cols:
                return
            jac = jacobian(traj, mounting, sub, links, theta, unknowns, cols)
            jw = jac * (w / self.sigma**2)[:, None]
            # first round: a weak prior (1 unit: degree or metre) keeps what the flight cannot determine from
            # wandering before the determinability check; afterwards the solution is the plain least squares
            prior = 1.0 / np.where(np.asarray(cols) < 3, np.radians(1.0), 1.0) ** 2 if prior_on else np.zeros(len(cols))
            normal = jac.T @ jw + np.diag(prior)
            dx = np.linalg.solve(normal, -(jw.T @ r) - prior * theta[cols])
            self.cov = np.linalg.inv(normal)
            theta[cols] += dx
            self.iterations += 1
            if all(abs(v) < (1e-8 if c < 3 else 1e-5) for v, c in zip(dx, cols, strict=True)):
                return

    def undetermined(self, theta: np.ndarray, free: list[int], max_correlation: float) -> dict[int, str]:
        """The unknowns this flight cannot determine, at the first round's solution and residual scale.

        Not that of the uncorrected flight, which the errors themselves inflate; and with the geometry's
        weights, not the robust ones: what the flight can determine does not depend on how well the first
        round fitted.  The Jacobian is the geometry's (:func:`geometry_jacobian`: slopes only where they
        are significant), so the decision does not rest on the patches' noise.  Then the held unknowns'
        possible error is carried into the others (:func:`leakage`), one more held at a time.
        """
        base, sigma = self._scale(theta)
        jac = geometry_jacobian(self.traj, self.mounting, self.sample, self.links, theta, self.unknowns, free, sigma)
        held: dict[int, str] = {}
        while True:
            held.update(determinability(jac, base, sigma, self.unknowns, free, max_correlation, held))
            leak = leakage(jac, base, sigma, self.unknowns, free, held)
            if leak is None:
                return held
            held[leak[0]] = leak[1]

    def held_effect(
        self, theta: np.ndarray, applied: list[int], held: dict[int, str]
    ) -> tuple[np.ndarray, np.ndarray, dict[int, tuple[int, float]]]:
        """The applied unknowns' variances from the geometry, what the held unknowns add, and the largest.

        The first: from :func:`geometry_jacobian` (slopes only where significant) and the residual scale,
        so not lowered by the patches' noise as the formal variance can be.  Each held unknown is taken as
        right to within its limit; through the geometry's correlations it moves the estimates
        (:func:`consider`): the second, and per applied unknown the held one that moves it most and by how
        much.  All in *applied*'s order.
        """
        if not applied:
            return np.zeros(0), np.zeros(0), {}
        considered = [c for c in held if held[c] != NO_OBSERVATION]
        base, sigma = self._scale(theta)
        cols = applied + considered
        jac = geometry_jacobian(self.traj, self.mounting, self.sample, self.links, theta, self.unknowns, cols, sigma)
        geometric, shift = consider(jac, base, sigma, self.unknowns, applied, considered)
        if not considered:
            return geometric, np.zeros(len(applied)), {}
        effect = {c: (considered[int(np.argmax(shift[i]))], float(shift[i].max())) for i, c in enumerate(applied)}
        return geometric, np.sum(shift**2, axis=1), effect

    def _scale(self, theta: np.ndarray) -> tuple[np.ndarray, float]:
        """The links' geometric weights (units of one point) and the robust noise of one point at *theta*."""
        xyz = georeference_sample(self.traj, self.mounting, self.sample, theta, self.unknowns)
        base = link_weights(self.links, xyz)
        return base, robust_weights(residuals(self.links, xyz), base)[1]

    def drop_insignificant(self, theta: np.ndarray, free: list[int], min_significance: float) -> dict[int, str]:
        """Backward elimination of the estimates that do not differ from zero; which were dropped, and why.

        The least significant is held at its configured value (zero in *theta*) and the others solved again.
        """
        applied = list(free)
        not_significant: dict[int, str] = {}
        while min_significance > 0 and applied and self.cov.size:
            sd = np.sqrt(np.clip(np.diag(self.cov), 0, None))
            ratio = np.abs(theta[applied]) / np.maximum(sd, 1e-300)
            k = int(np.argmin(ratio))
            if ratio[k] >= min_significance:
                break
            c = applied.pop(k)
            bound = _fmt(min_significance * sd[k], c, self.unknowns)
            not_significant[c] = f"not determined beyond +-{bound} ({min_significance:g} sigma) of the configured value"
            theta[c] = 0.0
            if applied:
                self.iterate(theta, applied, prior_on=False)
        return not_significant


def corrected_mounting(mounting: Mounting, theta: np.ndarray) -> Mounting:
    """The mounting with the boresight and lever-arm corrections applied."""
    return Mounting(euler_matrix(*theta[:3]) @ mounting.rotation, mounting.lever_arm + theta[3:6])
