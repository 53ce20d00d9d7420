"""Stage ``strip_adjust``: make overlapping flight strips agree (SPEC 6).

The algorithm is :mod:`dtm.stages.strip_adjust.icp`.  This driver splits the points
by strip (``point_source_id``; 0 = not a strip, e.g. points kept in turns,
is left as it is), finds the planar patches of each strip's single returns,
picks the datum (a reference strip or ground control points), solves, and
applies each strip's correction to all its points.

Products: ``strip_corrections.json`` (per strip: translation in metres and
rotation in degrees about its centroid, the datum, per-pair figures),
``strip_difference_before.tif`` / ``strip_difference_after.tif`` (mean
signed distance between overlapping strips at planar patches, per cell, like
LAStools' lasoverlap), and ``strip_difference.png`` (before | after).

A survey with one strip, or strips that do not overlap, passes through
unchanged with a note in the log and the metrics.

``model: mounting`` (raw flights only): instead of a correction per strip,
the system calibration itself (boresight angles, optionally the lever arm,
a range offset and per-strip trajectory offsets) is estimated from the
overlaps and every pulse is georeferenced again with it
(:mod:`dtm.stages.strip_adjust.calibration`, :mod:`dtm.stages.strip_adjust.mounting`,
docs/CALIBRATION.md).
"""

from __future__ import annotations

import json
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from dtm.common.checkpoints import read_control
from dtm.common.glossary import cell_size
from pipeline.config import InputFile, StrictModel
from pipeline.stage import Stage, StageContext, StageIO, StageParams


class MountingParams(StrictModel):
    """What ``model: mounting`` estimates besides the boresight angles, and when an unknown counts as determined."""

    lever_arm: bool = Field(
        False, description="estimate the lever arm (x, y, z) too; default: held at the configured (surveyed) values"
    )
    range_offset: bool = Field(False, description="estimate a constant range offset too")
    strip_offsets: bool = Field(
        False,
        description="estimate a 3-D trajectory offset per strip too (datum: reference_strip, else the strip with "
        "most single returns; none with control_points)",
    )
    max_sigma_boresight_deg: float = Field(
        0.005, gt=0, description="a boresight angle less certain than this (1-sigma, degrees) is held, not estimated"
    )
    max_sigma_lever_arm_m: float = Field(0.02, gt=0, description="likewise for a lever-arm component (1-sigma, metres)")
    max_sigma_range_offset_m: float = Field(0.02, gt=0, description="likewise for the range offset (1-sigma, metres)")
    max_correlation: float = Field(
        0.95, gt=0, lt=1, description="of two unknowns correlated beyond this, the less certain one is held"
    )
    min_significance: float = Field(
        3.0,
        ge=0,
        description="an estimate within this many of its sigmas of zero is reported but not applied (held at the "
        "configured value, the others solved again); 0: apply every estimate",
    )
    rounds: int = Field(3, ge=2, description="correspondence searches (each followed by Gauss-Newton iterations)")


class StripAdjustParams(StageParams):
    model: Literal["rigid", "mounting"] = Field(
        "rigid",
        description="rigid: one rigid correction per strip (any input); mounting: the boresight (and optionally lever "
        "arm, range offset, strip offsets) estimated from the overlaps and the pulses georeferenced again (raw "
        "flights only; docs/CALIBRATION.md)",
    )
    mounting: MountingParams = Field(default_factory=MountingParams, description="model: mounting settings")
    cell: float = cell_size(4.0)
    min_points: int = Field(8, ge=4, description="fewest single returns of one strip in a cell for a plane")
    max_plane_rms: float = Field(
        0.1, gt=0, description="a cell is planar when its points are this close to a plane, metres"
    )
    max_distance: float = Field(
        2.0, gt=0, description="strips farther apart than this along the normal are not matched, metres"
    )
    reference_strip: int | Literal["most_overlap"] = Field(
        "most_overlap", description="strip held fixed (the datum): a point_source_id, or most_overlap"
    )
    control_points: InputFile | None = Field(
        None, description="CSV id,x,y,z of ground control points (output CRS): the datum instead of a reference strip"
    )
    max_iterations: int = Field(10, ge=1, description="ICP iterations at most")
    prior_translation_m: float = Field(1.0, gt=0, description="prior sigma of a strip's translation, metres")
    prior_rotation_deg: float = Field(0.5, gt=0, description="prior sigma of a strip's roll and pitch, degrees")
    prior_yaw_deg: float = Field(
        0.01, gt=0, description="prior sigma of a strip's rotation about the vertical, degrees"
    )
    difference_resolution: float = Field(5.0, gt=0, description="cell of the strip-difference rasters, metres")
    max_sigma_translation_m: float = Field(
        0.05,
        gt=0,
        description="a strip whose correction is less certain than this (1-sigma, any axis) is left as it is",
    )
    max_sigma_rotation_deg: float = Field(0.01, gt=0, description="likewise for its roll and pitch (1-sigma, degrees)")
    max_points: int = Field(
        5_000_000,
        ge=10_000,
        description="single returns used for the estimation at most; beyond, only the cells of a regular lattice "
        "(every k-th cell in x and y) are used, so memory does not grow with the survey",
    )


class StripAdjust(Stage):
    name = "strip_adjust"
    version = "8"
    Params = StripAdjustParams
    description = "joint point-to-plane ICP: one rigid correction per strip, or (raw flights) the mounting calibration"
    inputs: ClassVar = ("points_georef",)
    outputs: ClassVar = {
        "points_adjusted": "points.las",
        "strip_corrections": "strip_corrections.json",
        "strip_difference_before": "strip_difference_before.tif",
        "strip_difference_after": "strip_difference_after.tif",
        "strip_difference_png": "strip_difference.png",
    }
    products: ClassVar = {
        "strip_corrections": "strip_corrections.json",
        "strip_difference_before": "strip_difference_before.tif",
        "strip_difference_after": "strip_difference_after.tif",
        "strip_difference_png": "strip_difference.png",
    }
    passthrough: ClassVar = {"points_adjusted": "points_georef"}
    config_keys = ("crs", "stages.georeference")  # model: mounting georeferences the pulses again

    def external_files(self, params, config):
        return [params.control_points] if params.control_points is not None else []

    def is_enabled(self, params, config) -> bool:
        from dtm.stages.strip_adjust.calibration import check_model

        check_model(params, config)
        return super().is_enabled(params, config)

    def declare(self, params, config) -> StageIO:
        io = super().declare(params, config)
        if params.model == "mounting" and config.input.format != "las":
            return StageIO((*io.inputs, "trajectory", "pulses"), io.outputs, io.products)
        return io

    def run(self, ctx: StageContext[StripAdjustParams]) -> None:
        from dtm.common.clouds import cloud_info

        p = ctx.params
        if p.model == "mounting":
            from dtm.stages.strip_adjust.calibration import run

            run(ctx, _difference_rasters)
            return
        src = ctx.inputs["points_georef"]
        info = cloud_info(src)
        extent, units, total, crs = info.extent, info.units, info.count, info.crs
        # One pass gathers what the estimation needs (everything in metres, like the
        # parameters): each strip's point count and centroid, and its single returns,
        # on every cell or, for a survey above max_points, on a regular lattice of cells.
        step = max(1, int(np.ceil(np.sqrt(total / p.max_points))))
        sample, count, sums = _gather(src, units, p.cell, step)
        pts, sid = sample
        strips = [int(s) for s in np.flatnonzero(count) if s > 0 and count[s] >= p.min_points]
        patches, centres, limit = _strip_patches(pts, sid, count, sums, strips, p)
        ctx.metrics.update(estimation_points=int(len(pts)), lattice_step=step)
        if limit is not None:
            ctx.metrics.update(plane_rms_limit_m=limit)
        if step > 1:
            ctx.log.info("estimation on every %d-th cell in x and y: %d single returns", step, len(pts))
        ident, linked, reference = _datum(strips, patches, centres, p)
        control = units.to_metres(read_control(p.control_points)) if p.control_points is not None else None
        skipped_note = None
        if len(linked) < 2:
            skipped_note = (
                f"{len(strips)} strip(s), {len(linked)} with overlap: nothing to adjust, points passed on unchanged"
            )
        if control is not None and len(control):
            reference = None
        corrections, weak, pair_rows, transforms = {}, {}, [], {}
        before = after = None
        if skipped_note is None:
            sol, weak = _solve(linked, patches, centres, pts, reference, control, p)
            if weak:
                ctx.log.warning("strips %s left unadjusted: their corrections are not determined by the overlaps "
                                "(1-sigma translation %s m)", ", ".join(map(str, weak)), list(weak.values()))  # fmt: skip
            ctx.metrics.update(strips_not_determined=sorted(weak))
            corrections = _corrections(sol, count)
            before, after = [], []
            for pair in sol.pairs:
                row, b_vals, a_vals = _pair_figures(pair, patches, pts, ident, sol.transforms, p.cell)
                pair_rows.append(row)
                before.append(b_vals)
                after.append(a_vals)
            ctx.metrics.update(iterations=sol.iterations, correspondences=sol.correspondences,
                               residual_sigma_m=sol.sigma)  # fmt: skip
            transforms = sol.transforms
        if not pair_rows:  # no overlap measured: the difference maps would be empty, so they are not published
            from pipeline.runner import UNPUBLISHED

            ctx.metrics[UNPUBLISHED] = ["strip_difference_before", "strip_difference_after", "strip_difference_png"]
        _apply(src, ctx.outputs["points_adjusted"], transforms, units, ctx)
        _difference_rasters(ctx, extent, before, after, p.difference_resolution, crs, units)
        datum = "control points" if reference is None and control is not None else f"strip {reference}"
        summary = {
            "datum": datum if skipped_note is None else None,
            "note": skipped_note,
            "strips": corrections,
            "not_determined": {str(k): {"sigma_translation_m": v} for k, v in weak.items()},
            "pairs": pair_rows,
        }
        ctx.outputs["strip_corrections"].write_text(json.dumps(summary, indent=2) + "\n")
        _report(ctx, summary, strips, reference, weak, skipped_note)


def _strip_patches(pts, sid, count, sums, strips, p):
    """Each strip's centroid and planar patches of its single returns, kept where smooth and well sampled.

    Smooth means smooth for this survey: at most 2.5 x the median patch RMS
    (the noise level); well sampled means at least half the strip's median
    points per patch, which drops water (specular: most pulses return
    nothing) and the thinly sampled swath edges.  Returns the patches, the
    centroids and the RMS limit used (None without any patch).
    """
    from dtm.stages.strip_adjust.icp import planar_patches

    patches, centres = {}, {}
    for s in strips:
        sel = np.flatnonzero(sid == s)
        centres[s] = sums[s] / count[s]
        patches[s] = planar_patches(pts[sel], cell=p.cell, min_points=p.min_points, max_rms=p.max_plane_rms)
        patches[s].order = sel[patches[s].order]  # indices into the sample
    all_rms = np.concatenate([patches[s].rms for s in strips]) if strips else np.zeros(0)
    if not len(all_rms):
        return patches, centres, None
    limit = min(p.max_plane_rms, 2.5 * float(np.median(all_rms)))
    for s in strips:
        dense = patches[s].count >= 0.5 * np.median(patches[s].count) if len(patches[s].count) else True
        patches[s].keep((patches[s].rms <= limit) & dense)
    return patches, centres, limit


def _datum(strips, patches, centres, p):
    """Which strips overlap (matched with identity transforms), and the reference strip held fixed.

    Returns the identity transforms, the strips with overlap and the
    reference (``most_overlap``: the strip with most matched patches).
    """
    from dtm.stages.strip_adjust.icp import Transform, match

    ident = {s: Transform(centres[s]) for s in strips}
    overlap = dict.fromkeys(strips, 0)
    for i, a in enumerate(strips):
        for b in strips[i + 1 :]:
            ia, _ = match(patches[a], ident[a], patches[b], ident[b], max_distance=p.max_distance)
            overlap[a] += len(ia)
            overlap[b] += len(ia)
    linked = [s for s in strips if overlap[s] > 0]
    if p.reference_strip == "most_overlap":
        return ident, linked, (max(linked, key=lambda s: overlap[s]) if linked else None)
    if linked and p.reference_strip not in linked:
        from pipeline.errors import ConfigError

        raise ConfigError(
            f"stages.strip_adjust.reference_strip: strip {p.reference_strip} has no overlap with another strip "
            f"(strips with overlap: {', '.join(map(str, linked))})."
        )
    return ident, linked, p.reference_strip


def _solve(linked, patches, centres, pts, reference, control, p):
    """The joint adjustment, strips whose correction the overlaps do not determine held as they are.

    A correction less certain than ``max_sigma_*`` (small or flat overlap) is
    not applied: the strip is fixed and the others are solved again without
    it moving.  Returns the solution and the held strips' 1-sigma translations.
    """
    from dtm.stages.strip_adjust.icp import adjust

    weak: dict[int, list[float]] = {}
    while True:
        sol = adjust({s: patches[s] for s in linked}, centres, pts, reference=reference, control=control,
                     fixed=tuple(weak), max_distance=p.max_distance, max_iterations=p.max_iterations,
                     prior_translation=p.prior_translation_m, prior_rotation=np.radians(p.prior_rotation_deg),
                     prior_yaw=np.radians(p.prior_yaw_deg))  # fmt: skip
        new_weak = {
            s: sd for s, sd in sol.std.items()
            if np.max(sd[:3]) > p.max_sigma_translation_m or np.degrees(np.max(sd[3:5])) > p.max_sigma_rotation_deg
        }  # fmt: skip
        if not new_weak:
            return sol, weak
        weak.update({s: [round(float(v), 4) for v in sd[:3]] for s, sd in new_weak.items()})


def _corrections(sol, count) -> dict:
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


def _report(ctx, summary: dict, strips, reference, weak, skipped_note) -> None:
    """The stage's metrics and log line: overlap RMS before and after, the largest correction."""
    corrections, pair_rows = summary["strips"], summary["pairs"]
    rms_b = _combined_rms([r["rms_before_m"] for r in pair_rows], [r["points"] for r in pair_rows])
    rms_a = _combined_rms([r["rms_after_m"] for r in pair_rows], [r["points"] for r in pair_rows])
    largest_t = max((float(np.linalg.norm(c["translation_m"])) for c in corrections.values()), default=0.0)
    largest_r = max((float(np.max(np.abs(c["rotation_deg"]))) for c in corrections.values()), default=0.0)
    estimated = len([s for s in corrections if int(s) != reference and int(s) not in weak])
    ctx.metrics.update(
        strips=len(strips), strips_adjusted=len(corrections), datum=summary["datum"], note=skipped_note,
        strips_estimated=estimated, overlap_rms_before_m=rms_b, overlap_rms_after_m=rms_a,
        largest_translation_m=largest_t, largest_rotation_deg=largest_r, pairs=len(pair_rows),
    )  # fmt: skip
    if skipped_note:
        ctx.log.info("strip adjustment skipped: %s", skipped_note)
    else:
        ctx.log.info(
            "%d strips, %d corrected (datum %s): overlap RMS %.3f m -> %.3f m; largest correction %.3f m, %.4f deg",
            len(corrections), estimated, summary["datum"], rms_b or 0.0, rms_a or 0.0, largest_t, largest_r,
        )  # fmt: skip


def _gather(path, units, cell: float, step: int):
    """Read a LAS file in chunks: the single returns of strips (point_source_id > 0) in the cells
    whose indices are multiples of *step* (every cell for 1), and each strip's count and sum of
    coordinates (metres)."""
    import laspy

    count = np.zeros(65536, dtype=np.int64)
    sums = np.zeros((65536, 3))
    keep_pts, keep_sid = [], []
    with laspy.open(str(path)) as reader:
        for chunk in reader.chunk_iterator(1_000_000):
            xyz = units.to_metres(np.column_stack((np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z))))
            sid = np.asarray(chunk.point_source_id).astype(np.int64)
            count += np.bincount(sid, minlength=65536)
            for k in range(3):
                sums[:, k] += np.bincount(sid, xyz[:, k], minlength=65536)
            sel = (np.asarray(chunk.number_of_returns) <= 1) & (sid > 0)
            if step > 1:
                ix = np.floor(xyz[:, 0] / cell).astype(np.int64)
                iy = np.floor(xyz[:, 1] / cell).astype(np.int64)
                sel &= (ix % step == 0) & (iy % step == 0)
            keep_pts.append(xyz[sel])
            keep_sid.append(sid[sel])
    pts = np.concatenate(keep_pts) if keep_pts else np.zeros((0, 3))
    sid = np.concatenate(keep_sid) if keep_sid else np.zeros(0, dtype=np.int64)
    return (pts, sid), count, sums


def _apply(src, dst, transforms: dict, units, ctx) -> None:
    """Copy the LAS *src* to *dst* in chunks, each strip's points moved by its transform."""
    import laspy

    from dtm.common.clouds import open_las_writer

    with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
        with ctx.progress(reader.header.point_count, "writing", unit="pt") as bar:
            for chunk in reader.chunk_iterator(1_000_000):
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
                bar.update(len(chunk))


def _combined_rms(values: list[float], weights: list[int]) -> float | None:
    if not values:
        return None
    v, w = np.asarray(values), np.asarray(weights, dtype=np.float64)
    return float(np.sqrt(np.sum(w * v**2) / np.sum(w)))


def _pair_figures(pair, patches, pts, ident, final, cell):
    """Per-point distances of strip b's patch points to strip a's surfaces, before and after."""
    from dtm.stages.strip_adjust.icp import surface_residuals

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
    # per patch, for the difference maps: the patch centre and its mean distance
    centre = pa.centroid[pair.ia]
    cnt = np.maximum(np.bincount(which, minlength=len(pair.ia)), 1)
    mean_b = np.bincount(which, out["before"], len(pair.ia)) / cnt
    mean_a = np.bincount(which, out["after"], len(pair.ia)) / cnt
    return row, (centre, mean_b), (centre, mean_a)


def _difference_rasters(ctx, extent, before, after, resolution, crs, units) -> None:
    """Mean signed strip-to-strip distance per cell (nodata where no planar overlap), before and after.

    The grid covers the overlap patches (one cell when there is none), so a sparse survey over a large
    area costs nothing.  Computed in metres; the rasters are written in the CRS's units (cells and values)."""
    from dtm.common.grid import Grid, cell_mean
    from dtm.common.rasters import NODATA, colour_ramp, png_bytes, write_cog

    # the grid covers the overlaps measured, not the survey: its cost follows the patches, not the area
    centres_all = [c for parts in (before or [], after or []) for c, _ in parts if len(c)]
    if centres_all:
        xy = np.concatenate(centres_all)[:, :2]
        box = (*xy.min(axis=0), *xy.max(axis=0))
    else:
        box = (extent[0], extent[1], extent[0], extent[1])
    grid = Grid.covering(*box, resolution)
    images = []
    for name, parts in (("strip_difference_before", before), ("strip_difference_after", after)):
        centres = np.concatenate([c for c, _ in parts]) if parts else np.zeros((0, 3))
        values = np.concatenate([v for _, v in parts]) if parts else np.zeros(0)
        grid_values = cell_mean(centres, values, grid)
        values_crs = grid_values / units.vertical
        write_cog(ctx.outputs[name], np.where(np.isfinite(values_crs), values_crs, NODATA).astype(np.float32),
                  transform=units.transform_from_metres(grid.transform), crs=crs)  # fmt: skip
        images.append(grid_values)
    # PNG: before | after, blue (-0.3 m) - white (0) - red (+0.3 m), grey where no overlap
    ramp = [(0.0, (59, 76, 192)), (0.5, (245, 245, 245)), (1.0, (180, 4, 38))]
    panels = []
    for image in images:
        rgb = colour_ramp(np.nan_to_num(image), ramp, -0.3, 0.3)
        rgb[~np.isfinite(image)] = 200.0
        panels.append(rgb)
    gap = np.full((grid.rows, 4, 3), 255.0)
    ctx.outputs["strip_difference_png"].write_bytes(
        png_bytes(np.concatenate((panels[0], gap, panels[1]), axis=1).round())
    )
