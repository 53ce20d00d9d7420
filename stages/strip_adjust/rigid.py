"""The rigid model of ``strip_adjust``: one rigid correction per strip (:func:`.icp.adjust`).

The steps: gather the estimation sample from the LAS, pick the datum from
the overlaps, solve (holding the strips the overlaps do not determine),
measure each pair before and after, and move every strip's points.
A strip is a ``point_source_id`` (0, points kept in turns, is left as it is).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np

from lidar.clouds import open_las_writer, read_chunks_counted
from pipeline.errors import ConfigError
from stages.strip_adjust.difference_maps import combined_rms
from stages.strip_adjust.icp import (
    Pair,
    Patches,
    Solution,
    Transform,
    adjust,
    match,
    on_lattice,
    strip_patches,
    surface_residuals,
)
from stages.strip_adjust.params import StripAdjustParams

if TYPE_CHECKING:
    from lidar.units import Units


def gather(
    path: Path, units: Units, cell: float, step: int, advance: Callable[[int], object] | None = None
) -> tuple[tuple[np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """Read a LAS file in chunks: the estimation sample, and each strip's point count and coordinate sums.

    The sample is the single returns of strips (point_source_id > 0) in the
    cells whose indices are multiples of *step* (every cell for 1), as
    (points, strip ids); everything in metres.  *advance* is told the
    points read.
    """
    count = np.zeros(65536, dtype=np.int64)
    sums = np.zeros((65536, 3))
    keep_pts, keep_sid = [], []
    with laspy.open(str(path)) as reader:
        for chunk in read_chunks_counted(reader, 1_000_000, advance):  # the sums' chunks, read in pieces
            xyz = units.to_metres(np.column_stack((np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z))))
            sid = np.asarray(chunk.point_source_id).astype(np.int64)
            count += np.bincount(sid, minlength=65536)
            for k in range(3):
                sums[:, k] += np.bincount(sid, xyz[:, k], minlength=65536)
            sel = (np.asarray(chunk.number_of_returns) <= 1) & (sid > 0)
            if step > 1:
                sel &= on_lattice(xyz, cell, step)
            keep_pts.append(xyz[sel])
            keep_sid.append(sid[sel])
    pts = np.concatenate(keep_pts) if keep_pts else np.zeros((0, 3))
    sid = np.concatenate(keep_sid) if keep_sid else np.zeros(0, dtype=np.int64)
    return (pts, sid), count, sums


@dataclass
class StripSample:
    """The estimation sample: single returns (metres), and each strip's point count, centroid and patches."""

    pts: np.ndarray  # (n, 3)
    count: np.ndarray  # points (all returns) per point_source_id
    strips: list[int]  # the strips with at least min_points points
    centres: dict[int, np.ndarray]
    patches: dict[int, Patches]
    limit: float | None  # the patches' RMS limit (None without any patch)


def strip_sample(
    path: Path, units: Units, p: StripAdjustParams, step: int, advance: Callable[[int], object] | None = None
) -> StripSample:
    """Read the estimation sample (:func:`gather`, *advance* told the points read) and find each strip's patches
    (:func:`.icp.strip_patches`)."""
    (pts, sid), count, sums = gather(path, units, p.cell, step, advance)
    strips = [int(s) for s in np.flatnonzero(count) if s > 0 and count[s] >= p.min_points]
    centres = {s: sums[s] / count[s] for s in strips}
    patches, limit = strip_patches(pts, sid, strips, cell=p.cell, min_points=p.min_points, max_rms=p.max_plane_rms)
    return StripSample(pts, count, strips, centres, patches, limit)


def overlap_datum(
    sample: StripSample, max_distance: float, reference_strip: int | str
) -> tuple[dict[int, Transform], list[int], int | None]:
    """Which strips overlap (matched with identity transforms), and the reference strip held fixed.

    Returns the identity transforms, the strips with overlap and the
    reference (``most_overlap``: the strip with most matched patches).
    """
    strips, patches = sample.strips, sample.patches
    ident = {s: Transform(sample.centres[s]) for s in strips}
    overlap = dict.fromkeys(strips, 0)
    for i, a in enumerate(strips):
        for b in strips[i + 1 :]:
            ia, _ = match(patches[a], ident[a], patches[b], ident[b], max_distance=max_distance)
            overlap[a] += len(ia)
            overlap[b] += len(ia)
    linked = [s for s in strips if overlap[s] > 0]
    if reference_strip == "most_overlap":
        return ident, linked, (max(linked, key=lambda s: overlap[s]) if linked else None)
    if linked and reference_strip not in linked:
        raise ConfigError(
            f"stages.strip_adjust.reference_strip: strip {reference_strip} has no overlap with another strip "
            f"(strips with overlap: {', '.join(map(str, linked))})."
        )
    return ident, linked, reference_strip


def solve_determined(
    linked: list[int],
    sample: StripSample,
    reference: int | None,
    control: np.ndarray | None,
    p: StripAdjustParams,
) -> tuple[Solution, dict[int, list[float]]]:
    """The joint adjustment, strips whose correction the overlaps do not determine held as they are.

    A correction less certain than ``max_sigma_*`` (small or flat overlap) is
    not applied: the strip is fixed and the others are solved again without
    it moving.  Returns the solution and the held strips' 1-sigma translations.
    """
    weak: dict[int, list[float]] = {}
    while True:
        sol = adjust(
            {s: sample.patches[s] for s in linked},
            sample.centres,
            sample.pts,
            reference=reference,
            control=control,
            fixed=tuple(weak),
            max_distance=p.max_distance,
            max_iterations=p.max_iterations,
            prior_translation=p.prior_translation_m,
            prior_rotation=np.radians(p.prior_rotation_deg),
            prior_yaw=np.radians(p.prior_yaw_deg),
        )
        new_weak = {
            s: sd
            for s, sd in sol.std.items()
            if np.max(sd[:3]) > p.max_sigma_translation_m or np.degrees(np.max(sd[3:5])) > p.max_sigma_rotation_deg
        }
        if not new_weak:
            return sol, weak
        weak.update({s: [round(float(v), 4) for v in sd[:3]] for s, sd in new_weak.items()})


def corrections(sol: Solution, count: np.ndarray) -> dict:
    """strip_corrections.json's ``strips``: each strip's correction, its sigmas and its point count."""
    out = {}
    for s, tf in sol.transforms.items():
        out[str(s)] = {
            "translation_m": [round(float(v), 5) for v in tf.translation],
            "rotation_deg": [round(float(v), 6) for v in np.degrees(tf.rotation_vector)],
            "centre": [round(float(v), 3) for v in tf.centre],
            "sigma_translation_m": [round(float(v), 5) for v in sol.std.get(s, np.zeros(6))[:3]],
            "sigma_rotation_deg": [round(float(v), 6) for v in np.degrees(sol.std.get(s, np.zeros(6))[3:])],
            "points": int(count[s]),
        }
    return out


def pair_figures(
    pair: Pair,
    patches: dict[int, Patches],
    pts: np.ndarray,
    ident: dict[int, Transform],
    final: dict[int, Transform],
    cell: float,
) -> tuple[dict, tuple, tuple]:
    """A pair's row of strip_corrections.json, and its patches' mean distances before and after.

    Distances are those of strip b's patch points to strip a's surfaces; the
    per-patch means (with the patch centres) feed the difference maps.
    """
    pa, pb = patches[pair.a], patches[pair.b]
    out = {}
    for label, tf in (("before", ident), ("after", final)):
        dist, which, _, _ = surface_residuals(pa, tf[pair.a], pb, tf[pair.b], pair.ia, pair.ib, pts)
        out[label] = dist
    row = {
        "strips": [pair.a, pair.b],
        "overlap_area_m2": round(float(len(pair.ia) * cell * cell), 1),
        "patches": int(len(pair.ia)),
        "points": int(len(which)),
        "rms_before_m": round(float(np.sqrt(np.mean(out["before"] ** 2))), 4),
        "rms_after_m": round(float(np.sqrt(np.mean(out["after"] ** 2))), 4),
    }
    centre = pa.centroid[pair.ia]
    cnt = np.maximum(np.bincount(which, minlength=len(pair.ia)), 1)
    mean_b = np.bincount(which, out["before"], len(pair.ia)) / cnt
    mean_a = np.bincount(which, out["after"], len(pair.ia)) / cnt
    return row, (centre, mean_b), (centre, mean_a)


@dataclass
class RigidFit:
    """The rigid model's outcome: the solution (None when skipped, with a note) and what is published of it."""

    solution: Solution | None = None
    weak: dict[int, list[float]] = field(default_factory=dict)  # held strips: 1-sigma translations
    corrections: dict = field(default_factory=dict)
    pairs: list[dict] = field(default_factory=list)
    before: list | None = None  # (patch centres, mean distances) per pair, for the difference maps
    after: list | None = None
    note: str | None = None

    @property
    def transforms(self) -> dict[int, Transform]:
        return self.solution.transforms if self.solution is not None else {}

    def metrics(self) -> dict:
        """The solution's metrics (none when skipped)."""
        if self.solution is None:
            return {}
        sol = self.solution
        return {
            "strips_not_determined": sorted(self.weak),
            "iterations": sol.iterations,
            "correspondences": sol.correspondences,
            "residual_sigma_m": sol.sigma,
        }


def fit_strips(
    sample: StripSample,
    linked: list[int],
    ident: dict[int, Transform],
    reference: int | None,
    control: np.ndarray | None,
    p: StripAdjustParams,
    log: logging.Logger,
) -> RigidFit:
    """Solve the strips with overlap and measure every pair (or a note: fewer than two strips overlap)."""
    if len(linked) < 2:
        return RigidFit(
            note=f"{len(sample.strips)} strip(s), {len(linked)} with overlap: nothing to adjust, points passed on unchanged"
        )
    sol, weak = solve_determined(linked, sample, reference, control, p)
    if weak:
        log.warning(
            "strips %s left unadjusted: their corrections are not determined by the overlaps (1-sigma translation %s m)",
            ", ".join(map(str, weak)),
            list(weak.values()),
        )
    fit = RigidFit(sol, weak, corrections(sol, sample.count), [], [], [])
    for pair in sol.pairs:
        row, b_vals, a_vals = pair_figures(pair, sample.patches, sample.pts, ident, sol.transforms, p.cell)
        fit.pairs.append(row)
        fit.before.append(b_vals)
        fit.after.append(a_vals)
    return fit


def summary(fit: RigidFit, reference: int | None, control: np.ndarray | None) -> dict:
    """strip_corrections.json of the rigid model."""
    datum = "control points" if reference is None and control is not None else f"strip {reference}"
    return {
        "datum": datum if fit.note is None else None,
        "note": fit.note,
        "strips": fit.corrections,
        "not_determined": {str(k): {"sigma_translation_m": v} for k, v in fit.weak.items()},
        "pairs": fit.pairs,
    }


def apply_transforms(
    src: Path, dst: Path, transforms: dict[int, Transform], units: Units, advance: Callable[[int], object]
) -> None:
    """Copy the LAS *src* to *dst* in chunks, each strip's points moved by its transform; *advance* told the points
    read (a small file's in pieces of the chunks)."""
    with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
        for chunk in read_chunks_counted(reader, 1_000_000, advance):
            if transforms:
                sid = np.asarray(chunk.point_source_id).astype(np.int64)
                x, y, z = np.array(chunk.x), np.array(chunk.y), np.array(chunk.z)
                for s, tf in transforms.items():
                    m = sid == s
                    if m.any():
                        moved = units.from_metres(tf.apply(units.to_metres(np.column_stack((x[m], y[m], z[m])))))
                        x[m], y[m], z[m] = moved[:, 0], moved[:, 1], moved[:, 2]
                chunk.x, chunk.y, chunk.z = x, y, z
            writer.write_points(chunk)


def outcome_metrics(summary: dict, strips: list[int], reference: int | None, weak: dict) -> dict:
    """The stage's metrics of the outcome: overlap RMS before and after, the largest correction."""
    corrections, pair_rows = summary["strips"], summary["pairs"]
    rms_b = combined_rms([r["rms_before_m"] for r in pair_rows], [r["points"] for r in pair_rows])
    rms_a = combined_rms([r["rms_after_m"] for r in pair_rows], [r["points"] for r in pair_rows])
    largest_t = max((float(np.linalg.norm(c["translation_m"])) for c in corrections.values()), default=0.0)
    largest_r = max((float(np.max(np.abs(c["rotation_deg"]))) for c in corrections.values()), default=0.0)
    estimated = len([s for s in corrections if int(s) != reference and int(s) not in weak])
    return {
        "strips": len(strips),
        "strips_adjusted": len(corrections),
        "datum": summary["datum"],
        "note": summary["note"],
        "strips_estimated": estimated,
        "overlap_rms_before_m": rms_b,
        "overlap_rms_after_m": rms_a,
        "largest_translation_m": largest_t,
        "largest_rotation_deg": largest_r,
        "pairs": len(pair_rows),
    }


def log_outcome(log: logging.Logger, m: dict) -> None:
    """The stage's log line, from :func:`outcome_metrics`."""
    if m["note"]:
        log.info("strip adjustment skipped: %s", m["note"])
        return
    log.info(
        "%d strips, %d corrected (datum %s): overlap RMS %.3f m -> %.3f m; largest correction %.3f m, %.4f deg",
        m["strips_adjusted"],
        m["strips_estimated"],
        m["datum"],
        m["overlap_rms_before_m"] or 0.0,
        m["overlap_rms_after_m"] or 0.0,
        m["largest_translation_m"],
        m["largest_rotation_deg"],
    )
