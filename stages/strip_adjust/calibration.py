"""The steps of ``model: mounting`` (issue 23): rebuild the geometry, read, link, solve, re-georeference.

The algorithm is :mod:`stages.strip_adjust.mounting`.  These steps
rebuild the trajectory exactly as the georeference stage does, find for
every point of ``points_georef`` its pulse (the georeference stage writes
the pulses that have a trajectory and a strip in pulse order, and whether a
pulse is kept depends on its time alone), estimate the corrections from the
single returns of the strips, and write the points again through the full
georeferencing equation with the corrected mounting.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lidar.checkpoints import read_control
from lidar.clouds import open_las_writer, read_chunks_counted
from lidar.crs import output_crs
from lidar.georeferencing import (
    LAS_GPS_OFFSET,  # how the georeference stage writes gps_time
    Mounting,
    OutputFrame,
    Trajectory,
    exact_output,
    georeference_local,
    locate,
    ltp_output,
    prepare_exact,
    prepare_ltp,
    pulse_reach,
)
from pipeline.errors import InputDataError
from stages.strip_adjust.difference_maps import combined_rms
from stages.strip_adjust.icp import Transform, lattice_step, match, on_lattice, patch_points, strip_patches
from stages.strip_adjust.mounting import (
    ADVICE,
    Calibration,
    Links,
    Sample,
    Unknowns,
    corrected_mounting,
    distances,
    georeference_sample,
    make_unknowns,
    solve,
)
from stages.strip_adjust.params import StripAdjustParams

if TYPE_CHECKING:
    from lidar.units import Units


@dataclass
class Geometry:
    """The georeference stage's trajectory (exact frame), mounting and output frame, rebuilt."""

    exact: Trajectory
    mounting: Mounting
    out: OutputFrame

    @property
    def output(self) -> Trajectory:
        """The trajectory the points are written from (the exact one, or the ltp plane's)."""
        return self.out.trajectory

    def to_map(self, e: np.ndarray, n: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
        """Local columns of the output trajectory -> output-CRS columns."""
        return self.out.columns(e, n, u)

    def map_to_local(self, xyz: np.ndarray) -> np.ndarray:
        """Output-CRS coordinates -> the output trajectory's local frame (Newton on the map transform)."""
        local = np.asarray(xyz, dtype=np.float64).copy()
        centre = self.output.position.mean(axis=0)
        guess = np.tile(centre, (len(local), 1))
        for _ in range(6):
            m0 = np.column_stack(self.to_map(*guess.T))
            jac = np.empty((len(guess), 3, 3))
            for k in range(3):
                step = guess.copy()
                step[:, k] += 1.0
                jac[:, :, k] = np.column_stack(self.to_map(*step.T)) - m0
            guess = guess + np.linalg.solve(jac, (local - m0)[:, :, None])[:, :, 0]
        return guess


def rebuild_geometry(
    traj: dict, tmeta: dict, pulses: dict, pmeta: dict, *, frame: str, crs: str, geoid: Path | None, ltp_radius_m: float
) -> Geometry:
    """The :class:`Geometry` of the parse stage's columns under the georeference stage's settings.

    *frame*, *geoid* and *ltp_radius_m* are the georeference stage's
    settings, *crs* the configured output CRS.  The map transform's box is
    10 m wider on every side than the georeference stage's.
    """
    convention = tmeta["convention"]
    lat0, lon0 = float(traj["lat"][0]), float(traj["lon"][0])
    exact, mounting = prepare_exact(traj, convention, pmeta)
    reach = pulse_reach(pulses["x"], pulses["y"], pulses["z"])
    reach += float(np.linalg.norm(mounting.lever_arm)) + 11.0
    if frame == "exact":
        out = exact_output(exact, output_crs(crs, None, (lon0, lat0)), reach, geoid=geoid)
    else:
        out = ltp_output(prepare_ltp(traj, convention, lat0, lon0, ltp_radius_m), ltp_radius_m, reach)
    return Geometry(exact, mounting, out)


def pulse_index(pulse_time: np.ndarray, las_time: np.ndarray) -> np.ndarray:
    """For each point of the georeferenced LAS, the index of its pulse.

    The LAS holds a subsequence of the pulses, in their order, and a pulse time is either kept with all
    its echoes or dropped with them, so the k-th point of a run of equal times is the k-th pulse of
    that time.

    >>> pulse_index(np.array([1e9 + 1, 1e9 + 2, 1e9 + 2, 1e9 + 3]), np.array([2.0, 2.0, 3.0])).tolist()
    [1, 2, 3]
    """
    tp = np.asarray(pulse_time, dtype=np.float64) - LAS_GPS_OFFSET
    tl = np.asarray(las_time, dtype=np.float64)
    if len(tl) == 0:
        return np.zeros(0, np.int64)
    if np.any(np.diff(tp) < 0):
        raise InputDataError("stages.strip_adjust.model: mounting needs the pulses in time order, and these are not.")
    new = np.concatenate(([True], tl[1:] != tl[:-1]))
    starts = np.flatnonzero(new)
    rank = np.arange(len(tl)) - starts[np.cumsum(new) - 1]
    idx = np.searchsorted(tp, tl, side="left") + rank
    ok = idx < len(tp)
    if not ok.all() or not np.array_equal(tp[idx], tl):
        raise RuntimeError("the georeferenced points do not correspond to the parsed pulses (cache out of step?)")
    return idx


def read_points(
    path: Path, advance: Callable[[int], object] | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """gps_time, strip and whether it is a single return, of every point (11 bytes a point); *advance* told the points
    read."""
    parts = {k: [] for k in ("t", "sid", "single")}
    with laspy.open(str(path)) as reader:
        for chunk in read_chunks_counted(reader, 1_000_000, advance):
            parts["t"].append(np.asarray(chunk.gps_time, dtype=np.float64))
            parts["sid"].append(np.asarray(chunk.point_source_id).astype(np.uint16))
            parts["single"].append(np.asarray(chunk.number_of_returns) <= 1)
    if not parts["t"]:
        return np.zeros(0), np.zeros(0, np.uint16), np.zeros(0, bool)
    return tuple(np.concatenate(parts[k]) for k in ("t", "sid", "single"))


def estimation_sample(
    geo: Geometry, pulses: dict, idx: np.ndarray, sid: np.ndarray, is_single: np.ndarray, cell: float, max_points: int
) -> tuple[Sample, int]:
    """The single returns of strips as a :class:`Sample`, on a lattice of cells above *max_points*; and its step.

    *idx* is each point's pulse (:func:`pulse_index`), *sid* its strip.
    """
    single = np.flatnonzero(is_single & (sid > 0))
    ids = idx[single]
    i_s, f_s, _ = locate(geo.exact, np.asarray(pulses["time"], dtype=np.float64)[ids], float("inf"))
    v_s = np.column_stack([np.asarray(pulses[k], dtype=np.float64)[ids] for k in ("x", "y", "z")])
    base = Sample(i_s, f_s, v_s, sid[single].astype(np.int64))
    unknowns0 = make_unknowns(
        lever_arm=False, range_offset=False, offset_strips=[], reference=None, limits=(1.0, 1.0, 1.0, 1.0)
    )
    local = georeference_sample(geo.exact, geo.mounting, base, np.zeros(unknowns0.size), unknowns0)
    step = lattice_step(len(single), max_points)
    if step > 1:
        base = base.subset(np.flatnonzero(on_lattice(local, cell, step)))
    return base, step


def local_control(geo: Geometry, path: Path, log: logging.Logger) -> np.ndarray | None:
    """Ground control points (output CRS) in the estimation's local frame; None with the ltp frame."""
    control = geo.map_to_local(read_control(path))
    if geo.output is not geo.exact:  # ltp output: control in the ltp plane; estimate in it too
        log.warning("control points are not used by model: mounting with frame: ltp")
        return None
    return control


def choose_unknowns(
    p: StripAdjustParams, strips: list[int], counts: np.ndarray, control: np.ndarray | None
) -> tuple[int | None, Unknowns]:
    """The reference strip (the datum of strip offsets) and the unknowns the settings ask for."""
    mp = p.mounting
    reference = p.reference_strip if p.reference_strip != "most_overlap" else None
    if mp.strip_offsets and reference is None and strips:
        reference = max(strips, key=lambda s: counts[s])  # the datum of the offsets: the best-sampled strip
    unknowns = make_unknowns(
        lever_arm=mp.lever_arm,
        range_offset=mp.range_offset,
        offset_strips=strips if mp.strip_offsets else [],
        reference=None if control is not None else reference,
        limits=(
            mp.max_sigma_boresight_deg,
            mp.max_sigma_lever_arm_m,
            mp.max_sigma_range_offset_m,
            p.max_sigma_translation_m,
        ),
    )
    return reference, unknowns


def calibrate(
    geo: Geometry,
    sample: Sample,
    strips: list[int],
    control: np.ndarray | None,
    unknowns: Unknowns,
    p: StripAdjustParams,
    log: logging.Logger,
) -> Calibration | None:
    """:func:`~stages.strip_adjust.mounting.solve` on the sample (None with fewer than two strips)."""
    if len(strips) < 2:
        return None

    def progress(rnd: int, theta: np.ndarray, sigma: float, n: int) -> None:
        log.info(
            "round %d: %d correspondences, residual sigma %.4f m, boresight correction %s deg",
            rnd + 1,
            n,
            sigma,
            np.round(np.degrees(theta[:3]), 5).tolist(),
        )

    mp = p.mounting
    finder = LinkFinder(sample.strip, strips, p.cell, p.min_points, p.max_plane_rms, p.max_distance, control)
    return solve(
        geo.exact,
        geo.mounting,
        sample,
        finder,
        unknowns,
        rounds=mp.rounds,
        max_iterations=p.max_iterations,
        max_correlation=mp.max_correlation,
        min_significance=mp.min_significance,
        log=progress,
    )


def datum_of(unknowns: Unknowns, control: np.ndarray | None, reference: int | None) -> str:
    """What the calibration is tied to: the trajectory, the control points, or a strip's held offsets."""
    if not unknowns.offset_strips:
        return "the trajectory (no strip offsets)"
    if control is not None:
        return "control points"
    return f"strip {reference} (its offsets held)"


class _LinkParts:
    """The pieces of :class:`Links` gathered link group by link group, concatenated once."""

    def __init__(self) -> None:
        self.parts = {k: [] for k in ("surf", "sg", "obs", "og", "origin", "strips", "weight", "rms", "fixed", "fg")}
        self.k = 0  # links so far

    def add(
        self,
        surface: tuple[np.ndarray, np.ndarray],
        origin: np.ndarray,
        strips: np.ndarray,
        weight: np.ndarray,
        rms: np.ndarray,
        observed: tuple[np.ndarray, np.ndarray] | None = None,
        fixed: np.ndarray | None = None,
    ) -> None:
        """One group: the surface points and their link, the observed points (or control points), per link data."""
        sa, ga = surface
        self.parts["surf"].append(sa)
        self.parts["sg"].append(ga + self.k)
        if observed is not None:
            sb, gb = observed
            self.parts["obs"].append(sb)
            self.parts["og"].append(gb + self.k)
        else:
            self.parts["fixed"].append(fixed)
            self.parts["fg"].append(np.arange(len(fixed)) + self.k)
        self.parts["origin"].append(origin)
        self.parts["strips"].append(strips)
        self.parts["weight"].append(weight)
        self.parts["rms"].append(rms)
        self.k += len(origin)

    def _cat(self, name: str, empty):
        return np.concatenate(self.parts[name]) if self.parts[name] else empty

    def links(self) -> tuple[Links, np.ndarray]:
        """The :class:`Links`, and each link's expected RMS (the two strips' patch RMS combined)."""
        i64 = np.zeros(0, np.int64)
        links = Links(
            self._cat("surf", i64),
            self._cat("sg", i64),
            self._cat("obs", i64),
            self._cat("og", i64),
            self._cat("origin", None),
            self._cat("strips", None),
            self._cat("weight", None),
            self._cat("fixed", np.zeros((0, 3))),
            self._cat("fg", i64),
        )
        return links, self._cat("rms", None)


@dataclass(frozen=True, eq=False)
class LinkFinder:
    """What :func:`~stages.strip_adjust.mounting.solve` calls in each round: patches, matches, control.

    Called with the sample's local points, it returns the :class:`Links` and
    the sample indices they use, or None without any correspondence.
    """

    strip: np.ndarray  # the sample's strip ids
    strips: list[int]
    cell: float
    min_points: int
    max_plane_rms: float
    max_distance: float
    control: np.ndarray | None  # control points, local ENU

    def __call__(self, xyz: np.ndarray) -> tuple[Links, np.ndarray] | None:
        patches, limit = strip_patches(  # smooth and well sampled, as for the rigid model
            xyz, self.strip, self.strips, cell=self.cell, min_points=self.min_points, max_rms=self.max_plane_rms
        )
        if limit is None:
            return None
        parts = _LinkParts()
        self._pairs(patches, parts)
        if self.control is not None and len(self.control):
            self._control(patches, parts)
        if parts.k == 0:
            return None
        links, rms = parts.links()
        links = _select(links, self._consistent(links, rms, xyz, parts.k))
        if links.size == 0:
            return None
        used = np.unique(np.concatenate((links.surf, links.obs)))
        links.surf = np.searchsorted(used, links.surf)
        links.obs = np.searchsorted(used, links.obs)
        return links, used

    def _pairs(self, patches: dict, parts: _LinkParts) -> None:
        """The matched patches of every strip pair: strip a's points the surface, strip b's observed."""
        ident = Transform(np.zeros(3))
        for i, a in enumerate(self.strips):
            for b in self.strips[i + 1 :]:
                ia, ib = match(patches[a], ident, patches[b], ident, max_distance=self.max_distance)
                if not len(ia):
                    continue
                parts.add(
                    patch_points(patches[a], ia),
                    patches[a].origin[ia],
                    np.tile([a, b], (len(ia), 1)),
                    patches[b].count[ib].astype(np.float64),
                    np.hypot(patches[a].rms[ia], patches[b].rms[ib]),
                    observed=patch_points(patches[b], ib),
                )

    def _control(self, patches: dict, parts: _LinkParts) -> None:
        """The control points inside a strip's patch: that patch's points the surface, the point observed."""
        control = self.control
        for s in self.strips:
            if not len(patches[s].centroid):
                continue
            dist, kk = cKDTree(patches[s].centroid[:, :2]).query(control[:, :2], distance_upper_bound=self.cell / 2)
            ok = np.isfinite(dist)
            if not ok.any():
                continue
            n = int(ok.sum())
            parts.add(
                patch_points(patches[s], kk[ok]),
                patches[s].origin[kk[ok]],
                np.tile([s, 0], (n, 1)),
                np.full(n, 100.0),  # a surveyed point weighs as 100 points
                np.full(n, np.inf),
                fixed=control[ok],
            )

    def _consistent(self, links: Links, rms: np.ndarray, xyz: np.ndarray, k: int) -> np.ndarray:
        """Which links hold: the observed points fit the surface as well as each strip fits its own.

        Else the surface is not the same there (edges, kinks, canopy); as for the rigid model.
        """
        d, g = distances(links, xyz)
        cnt = np.maximum(np.bincount(g, minlength=k), 1)
        mean = np.bincount(g, d, k) / cnt
        spread = np.sqrt(np.clip(np.bincount(g, d * d, k) / cnt - mean**2, 0, None))
        return (spread <= 2.0 * rms + 0.005) & (np.abs(mean) <= self.max_distance)


def _select(links: Links, keep: np.ndarray) -> Links:
    new = np.cumsum(keep) - 1
    ms, mo, mf = keep[links.surf_group], keep[links.obs_group], keep[links.fixed_group]
    return Links(
        links.surf[ms],
        new[links.surf_group[ms]],
        links.obs[mo],
        new[links.obs_group[mo]],
        links.origin[keep],
        links.strips[keep],
        links.weight[keep],
        links.fixed[mf],
        new[links.fixed_group[mf]],
    )


def unknown_rows(cal: Calibration | None, unknowns: Unknowns, theta: np.ndarray) -> list[dict]:
    """strip_corrections.json's ``unknowns``: per unknown its estimate, sigma, correction and fate."""
    rows = []
    for j, name in enumerate(unknowns.names):
        angle = j < 3
        scale, digits = (180 / np.pi, 7) if angle else (1.0, 5)
        estimated = cal is not None and j in cal.free
        why = cal.held.get(j) if cal is not None else None
        key = "strip_offset" if name.startswith("strip_") else name
        rows.append(
            {
                "name": name,
                "unit": "deg" if angle else "m",
                "correction": round(float(theta[j] * scale), digits),
                "estimate": round(float(cal.estimate[j] * scale), digits) if estimated else None,
                "sigma": round(float(cal.sigma[j] * scale), digits) if estimated else None,
                "estimated": bool(estimated),
                "applied": bool(estimated and j not in cal.not_significant),
                "not_applied_because": cal.not_significant.get(j) if estimated else None,
                "held_because": why,
                "determined_by": ADVICE[key] if why else None,
                "sigma_from_held": _held_effect(cal, j, scale, digits),
            }
        )
    return rows


def _held_effect(cal: Calibration | None, j: int, scale: float, digits: int) -> dict | None:
    """The held unknown whose possible error (its limit) moves unknown *j* most, and by how much (in *j*'s
    unit); None when no held unknown moves it (its sigma includes every held unknown's effect)."""
    if cal is None or j not in cal.held_effect or cal.held_effect[j][1] <= 0:
        return None
    by, shift = cal.held_effect[j]
    return {"unknown": cal.unknowns.names[by], "shift": round(float(shift * scale), digits)}


def mounting_summary(mounting: Mounting, theta: np.ndarray, pmeta: dict) -> dict:
    """strip_corrections.json's ``mounting``: the configured and estimated rotation and lever arm.

    For the lmsq formats also ``estimated_boresight_deg``, the value to configure as ``input.boresight_deg``.
    """
    new = corrected_mounting(mounting, theta)
    out = {
        "configured_rotation": np.round(mounting.rotation, 9).tolist(),
        "configured_lever_arm_m": np.round(mounting.lever_arm, 5).tolist(),
        "estimated_rotation": np.round(new.rotation, 9).tolist(),
        "estimated_lever_arm_m": np.round(new.lever_arm, 5).tolist(),
        "range_offset_m": round(float(theta[6]), 5),
    }
    if "boresight_deg" in pmeta:
        yaw, pitch, roll = Rotation.from_matrix(new.rotation).as_euler("ZYX", degrees=True)
        out["estimated_boresight_deg"] = [round(float(v), 6) for v in (roll, pitch, yaw)]
    return out


def pair_rows(cal: Calibration, geo: Geometry, theta: np.ndarray, cell: float) -> tuple[list, list, list]:
    """Per strip pair: RMS of the distances and of the per-patch means, before and after; the maps' values."""
    links, sample = cal.links, cal.sample
    d0, g = distances(links, georeference_sample(geo.exact, geo.mounting, sample, np.zeros_like(theta), cal.unknowns))
    d1, _ = distances(links, georeference_sample(geo.exact, geo.mounting, sample, theta, cal.unknowns))
    k = links.size
    cnt = np.maximum(np.bincount(g, minlength=k), 1)
    m0, m1 = np.bincount(g, d0, k) / cnt, np.bincount(g, d1, k) / cnt
    centres = np.column_stack(geo.to_map(*links.origin.T))
    rows, before, after = [], [], []
    for a, b in sorted({tuple(r) for r in links.strips.tolist() if r[1] > 0}):
        lk = (links.strips[:, 0] == a) & (links.strips[:, 1] == b)
        pts = lk[g]
        rows.append(
            {
                "strips": [a, b],
                "overlap_area_m2": round(float(lk.sum() * cell * cell), 1),
                "patches": int(lk.sum()),
                "points": int(pts.sum()),
                "rms_before_m": round(float(np.sqrt(np.mean(d0[pts] ** 2))), 4),
                "rms_after_m": round(float(np.sqrt(np.mean(d1[pts] ** 2))), 4),
                "systematic_rms_before_m": round(float(np.sqrt(np.mean(m0[lk] ** 2))), 4),
                "systematic_rms_after_m": round(float(np.sqrt(np.mean(m1[lk] ** 2))), 4),
            }
        )
        before.append((centres[lk], m0[lk]))
        after.append((centres[lk], m1[lk]))
    return rows, before, after


def summary(
    cal: Calibration | None,
    unknowns: Unknowns,
    theta: np.ndarray,
    geo: Geometry,
    note: str | None,
    pmeta: dict,
    datum: str,
    pairs: list[dict],
) -> dict:
    """strip_corrections.json for the mounting model (*pairs* from :func:`pair_rows`)."""
    return {
        "model": "mounting",
        "datum": None if note else datum,
        "note": note,
        "unknowns": unknown_rows(cal, unknowns, theta),
        "correlation": {
            "names": [unknowns.names[j] for j in cal.free] if cal else [],
            "matrix": np.round(cal.correlation, 4).tolist() if cal else [],
        },
        "mounting": mounting_summary(geo.mounting, theta, pmeta),
        "residual_sigma_m": round(float(cal.residual_sigma), 5) if cal else None,
        "iterations": cal.iterations if cal else 0,
        "pairs": pairs,
    }


def strip_rows(summary: dict, strips: list[int], counts: np.ndarray) -> dict:
    """Per strip, in the rigid model's layout (the report reads it).

    The strip's trajectory offset is its translation (zero unless
    ``strip_offsets``), with no rotation: the mounting turns it (see ``unknowns``).
    """
    by = {u["name"]: u for u in summary["unknowns"]}
    rows = {}
    for s in strips:
        names = [f"strip_{s}_offset_{a}" for a in "enu"]
        t = [by[n]["correction"] if n in by else 0.0 for n in names]
        sd = [(by[n]["sigma"] or 0.0) if n in by else 0.0 for n in names]
        rows[str(s)] = {
            "translation_m": t,
            "rotation_deg": [0.0, 0.0, 0.0],
            "sigma_translation_m": sd,
            "sigma_rotation_deg": [0.0, 0.0, 0.0],
            "points": int(counts[s]),
        }
    return rows


def rewrite_points(
    src: Path,
    dst: Path,
    geo: Geometry,
    theta: np.ndarray,
    unknowns: Unknowns,
    idx: np.ndarray,
    pulses: dict,
    units: Units,
    advance: Callable[[int], object],
) -> float:
    """Copy *src* to *dst* with every point georeferenced again under *theta*; the largest move (m)."""
    new = corrected_mounting(geo.mounting, theta)
    table = np.zeros((65536, 3))
    for k, s in enumerate(unknowns.offset_strips):
        table[s] = theta[7 + 3 * k : 10 + 3 * k]
    pulses_t = pulses["time"]
    pulses_v = [pulses[k] for k in ("x", "y", "z")]
    largest = 0.0
    start = 0
    with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
        for chunk in read_chunks_counted(reader, 1_000_000, advance):  # advanced as read, a small file's in pieces
            n = len(chunk)
            if n:
                ids = idx[start : start + n]
                t = np.asarray(pulses_t[ids], dtype=np.float64)
                v = np.column_stack([np.asarray(c[ids], dtype=np.float64) for c in pulses_v])
                v *= (1.0 + theta[6] / np.maximum(np.linalg.norm(v, axis=1), 1e-9))[:, None]
                i, f, _ = locate(geo.output, t, float("inf"))
                e, nn, u = georeference_local(geo.output, v[:, 0], v[:, 1], v[:, 2], new, i, f)
                off = table[np.asarray(chunk.point_source_id).astype(np.int64)]
                x, y, z = geo.to_map(e + off[:, 0], nn + off[:, 1], u + off[:, 2])
                old = np.column_stack((np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)))
                moved = units.to_metres(np.column_stack((x, y, z))) - units.to_metres(old)
                largest = max(largest, float(np.max(np.linalg.norm(moved, axis=1))))
                chunk.x, chunk.y, chunk.z = x, y, z
            writer.write_points(chunk)
            start += n
    return largest


def outcome_metrics(
    summary: dict, cal: Calibration | None, strips: list[int], moved: float, sample: Sample, step: int
) -> dict:
    """The stage's metrics under ``model: mounting`` (``warnings`` when an unknown was held).

    *moved* is the largest point move (m) and *step* the estimation's lattice step.
    """
    pair_rows, note = summary["pairs"], summary["note"]
    by = {u["name"]: u for u in summary["unknowns"]}
    boresight = ("boresight_roll", "boresight_pitch", "boresight_yaw")
    lever = ("lever_arm_x", "lever_arm_y", "lever_arm_z")
    held = [u["name"] for u in summary["unknowns"] if u["held_because"]]
    out = {
        "model": "mounting",
        "note": note,
        "strips": len(strips),
        "pairs": len(pair_rows),
        "datum": summary["datum"],
        "boresight_correction_deg": [by[n]["correction"] for n in boresight],
        "boresight_estimate_deg": [by[n]["estimate"] for n in boresight],
        "not_significant": [u["name"] for u in summary["unknowns"] if u["not_applied_because"]],
        "boresight_sigma_deg": [by[n]["sigma"] for n in boresight],
        "lever_arm_correction_m": [by[n]["correction"] for n in lever],
        "lever_arm_sigma_m": [by[n]["sigma"] for n in lever],
        "range_offset_m": by["range_offset"]["correction"],
        "range_offset_sigma_m": by["range_offset"]["sigma"],
        "not_determined": held,
        "overlap_rms_before_m": combined_rms([r["rms_before_m"] for r in pair_rows], [r["points"] for r in pair_rows]),
        "overlap_rms_after_m": combined_rms([r["rms_after_m"] for r in pair_rows], [r["points"] for r in pair_rows]),
        "overlap_systematic_rms_before_m": combined_rms(
            [r["systematic_rms_before_m"] for r in pair_rows], [r["patches"] for r in pair_rows]
        ),
        "overlap_systematic_rms_after_m": combined_rms(
            [r["systematic_rms_after_m"] for r in pair_rows], [r["patches"] for r in pair_rows]
        ),
        "largest_point_move_m": moved,
        "residual_sigma_m": cal.residual_sigma if cal else None,
        "iterations": cal.iterations if cal else 0,
        "correspondences": cal.links.size if cal else 0,
        "estimation_points": len(sample.strip),
        "lattice_step": step,
    }
    if held and not note:
        out["warnings"] = [f"{n} not determined: held at the configured value" for n in held]
    return out


def log_outcome(log: logging.Logger, summary: dict, m: dict) -> None:
    """The log lines of the calibration, from the summary and :func:`outcome_metrics`."""
    for u in summary["unknowns"]:
        if u["held_because"]:
            log.warning(
                "%s cannot be determined by this flight (%s): held at the configured value; "
                "it would be determined by %s",
                u["name"],
                u["held_because"],
                u["determined_by"],
            )
    if m["note"]:
        log.info("mounting calibration skipped: %s", m["note"])
        return
    est = ", ".join(
        f"{u['name']} {u['estimate']:+.5f} +- {u['sigma']:.5f} {u['unit']}"
        if u["applied"]
        else f"{u['name']} {u['not_applied_because']} (not applied)"
        for u in summary["unknowns"]
        if u["estimated"] and not u["name"].startswith("strip_")
    )
    log.info("mounting estimates: %s", est or "none (every unknown held)")
    log.info(
        "%d strips, %d pairs: overlap RMS %.4f m -> %.4f m; largest point move %.4f m",
        m["strips"],
        m["pairs"],
        m["overlap_rms_before_m"] or 0.0,
        m["overlap_rms_after_m"] or 0.0,
        m["largest_point_move_m"],
    )
