"""Stage ``strip_adjust``: make overlapping flight strips agree (SPEC 6).

The driver of two models.  ``rigid`` (:mod:`.rigid`, the algorithm in
:mod:`.icp`): one rigid correction per strip, from planar patches of the
strips' single returns matched across overlaps, with a reference strip or
ground control points as the datum.  ``mounting`` (raw flights only;
:mod:`.calibration`, the algorithm in :mod:`.mounting`): the system
calibration estimated from the overlaps and every pulse georeferenced
again.  Products: ``strip_corrections.json`` and the strip-difference maps
(:mod:`.difference_maps`).  A survey with one strip, or strips that do not
overlap, passes through unchanged with a note.  See
``docs/stages/strip_adjust.md`` and ``docs/CALIBRATION.md``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from lidar.checkpoints import read_control
from lidar.clouds import cloud_info
from lidar.columns import read_columns
from lidar.rasters import dem_nodata
from pipeline.errors import ConfigError
from pipeline.runner import UNPUBLISHED
from pipeline.stage import Stage, StageContext, StageIO
from stages.strip_adjust import calibration, rigid
from stages.strip_adjust.difference_maps import DIFFERENCE_MAPS, write_difference_maps
from stages.strip_adjust.icp import lattice_step
from stages.strip_adjust.params import StripAdjustParams


class StripAdjust(Stage, name="strip_adjust", version="11", params=StripAdjustParams):
    """joint point-to-plane ICP: one rigid correction per strip, or (raw flights) the mounting calibration."""

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
    # model: mounting georeferences the pulses again; the difference maps take the elevation rasters' nodata
    config_keys = ("crs", "stages.georeference", "stages.rasterize.nodata", "stages.report.specification")

    def spreads_changes(self, params: StripAdjustParams, previous: dict) -> str | None:
        """Strip adjustment fits whole strips: one changed file may move every point (unless no strip was adjusted)."""
        return "strip adjustment fits whole strips" if previous.get("metrics", {}).get("strips_adjusted", 1) else None

    def external_files(self, params: StripAdjustParams, config: BaseModel) -> list[Path]:
        return [params.control_points] if params.control_points is not None else []

    def is_enabled(self, params: StripAdjustParams, config: BaseModel) -> bool:
        if params.model == "mounting" and config.input.format == "las":
            raise ConfigError(
                "stages.strip_adjust.model: mounting needs a raw flight's pulses and trajectory, and input.format "
                "las has none; use model: rigid (the default) for LAS input."
            )
        return super().is_enabled(params, config)

    def declare(self, params: StripAdjustParams, config: BaseModel) -> StageIO:
        io = super().declare(params, config)
        if params.model == "mounting" and config.input.format != "las":
            return StageIO((*io.inputs, "trajectory", "pulses"), io.outputs, io.products)
        return io

    def run(self, ctx: StageContext[StripAdjustParams]) -> None:
        if ctx.params.model == "mounting":
            self._mounting(ctx)
        else:
            self._rigid(ctx)

    def _rigid(self, ctx: StageContext[StripAdjustParams]) -> None:
        """One rigid correction per strip (any input)."""
        p = ctx.params
        src = ctx.inputs["points_georef"]
        info = cloud_info(src)
        # the estimation sample (everything in metres, like the parameters): each strip's point count and
        # centroid, and its single returns on every cell or, above max_points, on a regular lattice of cells
        step = lattice_step(info.count, p.max_points)
        with ctx.progress(info.count, "reading the estimation sample", unit="pt") as bar:
            sample = rigid.strip_sample(src, info.units, p, step, bar.update)
        ctx.metrics.update(estimation_points=int(len(sample.pts)), lattice_step=step)
        if sample.limit is not None:
            ctx.metrics.update(plane_rms_limit_m=sample.limit)
        if step > 1:
            ctx.log.info("estimation on every %d-th cell in x and y: %d single returns", step, len(sample.pts))
        # the datum, the joint adjustment, the figures of each pair
        ident, linked, reference = rigid.overlap_datum(sample, p.max_distance, p.reference_strip)
        control = info.units.to_metres(read_control(p.control_points)) if p.control_points is not None else None
        if control is not None and len(control):
            reference = None
        fit = rigid.fit_strips(sample, linked, ident, reference, control, p, ctx.log)
        ctx.metrics.update(fit.metrics())
        self._unpublish_empty_maps(ctx, fit.pairs)
        # the products
        with ctx.progress(info.count, "writing", unit="pt") as bar:
            rigid.apply_transforms(src, ctx.outputs["points_adjusted"], fit.transforms, info.units, bar.update)
        maps = {name: ctx.outputs[name] for name in DIFFERENCE_MAPS}
        write_difference_maps(
            maps,
            info.extent,
            fit.before,
            fit.after,
            p.difference_resolution,
            info.crs,
            info.units,
            _nodata(ctx),
        )
        summary = rigid.summary(fit, reference, control)
        ctx.outputs["strip_corrections"].write_text(json.dumps(summary, indent=2) + "\n")
        outcome = rigid.outcome_metrics(summary, sample.strips, reference, fit.weak)
        ctx.metrics.update(outcome)
        rigid.log_outcome(ctx.log, outcome)

    def _mounting(self, ctx: StageContext[StripAdjustParams]) -> None:
        """The system calibration from the overlaps, every pulse georeferenced again (raw flights)."""
        p = ctx.params
        src = ctx.inputs["points_georef"]
        traj, tmeta = read_columns(ctx.inputs["trajectory"])
        pulses, pmeta = read_columns(ctx.inputs["pulses"])
        g = ctx.setting("stages.georeference")
        geo = calibration.rebuild_geometry(
            traj,
            tmeta,
            pulses,
            pmeta,
            frame=g.frame,
            crs=ctx.setting("crs"),
            geoid=g.geoid,
            ltp_radius_m=g.ltp_radius_m,
        )
        info = cloud_info(src)
        # the points and their pulses; the estimation sample: single returns of strips, a lattice above max_points
        with ctx.progress(info.count, "reading the points' pulses", unit="pt") as bar:
            t_las, sid, is_single = calibration.read_points(src, bar.update)
        idx = calibration.pulse_index(pulses["time"], t_las)
        del t_las
        sample, step = calibration.estimation_sample(geo, pulses, idx, sid, is_single, p.cell, p.max_points)
        if step > 1:
            ctx.log.info("estimation on every %d-th cell in x and y: %d single returns", step, len(sample.strip))
        counts = np.bincount(sample.strip, minlength=1)
        strips = [int(s) for s in np.flatnonzero(counts) if s > 0 and counts[s] >= p.min_points]
        # link patches and solve
        control = calibration.local_control(geo, p.control_points, ctx.log) if p.control_points is not None else None
        reference, unknowns = calibration.choose_unknowns(p, strips, counts, control)
        cal = calibration.calibrate(geo, sample, strips, control, unknowns, p, ctx.log)
        note = None
        if cal is None:
            note = f"{len(strips)} strip(s) without planar overlap: nothing to estimate, points passed on unchanged"
        theta = cal.theta if cal is not None else np.zeros(unknowns.size)
        datum = calibration.datum_of(unknowns, control, reference)
        pairs, before, after = calibration.pair_rows(cal, geo, theta, p.cell) if cal else ([], None, None)
        summary = calibration.summary(cal, unknowns, theta, geo, note, pmeta, datum, pairs)
        summary["strips"] = calibration.strip_rows(
            summary, strips, np.bincount(sid, minlength=max(strips, default=0) + 1)
        )
        self._unpublish_empty_maps(ctx, pairs)
        # write the points again, the products
        with ctx.progress(info.count, "writing", unit="pt") as bar:
            moved = calibration.rewrite_points(
                src, ctx.outputs["points_adjusted"], geo, theta, unknowns, idx, pulses, info.units, bar.update
            )
        summary["largest_point_move_m"] = round(moved, 5)
        ctx.outputs["strip_corrections"].write_text(json.dumps(summary, indent=2) + "\n")
        maps = {name: ctx.outputs[name] for name in DIFFERENCE_MAPS}
        write_difference_maps(
            maps,
            info.extent,
            before,
            after,
            p.difference_resolution,
            info.crs,
            info.units,
            _nodata(ctx),
        )
        outcome = calibration.outcome_metrics(summary, cal, strips, moved, sample, step)
        ctx.metrics.update(outcome)
        calibration.log_outcome(ctx.log, summary, outcome)

    @staticmethod
    def _unpublish_empty_maps(ctx: StageContext, pairs: list) -> None:
        """No overlap measured: the difference maps would be empty, so they are not published."""
        if not pairs:
            ctx.metrics[UNPUBLISHED] = list(DIFFERENCE_MAPS)


def _nodata(ctx: StageContext) -> float:
    """The difference maps' nodata: the elevation rasters' (:func:`lidar.rasters.dem_nodata`)."""
    return dem_nodata(ctx.setting("stages.report.specification"), ctx.setting("stages.rasterize.nodata"))
