"""Stage ``parse``: read the survey's input files into the common intermediates.

Its parameters are the configuration's ``input`` block; ``input.format``
chooses the reader:

- ``las`` (SPEC 3.D): georeferenced LAS/LAZ.  Output: the point cloud
  (``points_georef``), already in the output CRS; georeferencing does not apply.
- ``ldmrs_mtig`` (3.A), ``lmsq_nmea`` (3.B) and ``lmsq_sbet`` (3.C), the raw
  formats.  Outputs: the ``trajectory`` and the ``pulses``
  (:mod:`stages.parse.intermediates`), which the ``georeference`` stage
  turns into points, and ``qc/`` (:mod:`stages.parse.qc`).

Times everywhere: GPS seconds since 1980-01-06.  The readers' conventions
and departures: ``docs/stages/parse.md``.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np
import pyproj

from lidar.columns import NpyColumns
from lidar.crs import heights_of, state_heights
from lidar.grid import Grid, check_grid_size
from lidar.units import Units
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext, StageIO, get_dotted
from stages.parse.intermediates import (
    LDMRS_TRAJECTORY_SCHEMA,
    PULSES_SCHEMA,
    ldmrs_conventions,
    lmsq_conventions,
    lmsq_pulses,
    scan_pose,
    scan_pulses,
    write_trajectory,
)
from stages.parse.las_index import read_headers, write_input_files_csv
from stages.parse.params import InputConfig, LasInput, LdmrsInput, LmsqNmeaInput, LmsqSbetInput
from stages.parse.qc import ScanQc, ldmrs_figures, lmsq_figures, write_debug, write_trajectory_csv
from stages.parse.read_ins import TrajectoryCounters
from stages.parse.read_las import convert_las_files
from stages.parse.read_ldmrs import Counters, read_survey
from stages.parse.read_lmsq import LmsqCounters, first_pps_week, read_streams
from stages.parse.trajectory import nmea_ins_trajectory, sbet_trajectory

if TYPE_CHECKING:
    from pydantic import BaseModel

    from stages.parse.las_report import LasReadReport


class Parse(Stage, name="parse", version="12", params=InputConfig):
    """read the input files (format from input.format)."""

    config_path = "input"
    config_keys = ("crs", "stages.georeference.geoid")  # the geoid: NMEA fixes without a geoid separation
    outputs: ClassVar = {"points_georef": "points.las"}

    def is_enabled(self, params: InputConfig, config: BaseModel) -> bool:
        return True

    def declare(self, params: InputConfig, config: BaseModel) -> StageIO:
        if params.format == "las":
            return StageIO(
                outputs={"points_georef": "points.las", "input_files": "input_files.csv"},
                products={"input_files": "qc/input_files.csv"},
            )
        return StageIO(outputs={"trajectory": "trajectory", "pulses": "pulses", "qc": "qc"}, products={"qc": "qc"})

    def external_files(self, params: InputConfig, config: BaseModel) -> list[Path]:
        files = list(params.paths)
        for key in ("nmea", "ins", "sbet", "smrmsg"):
            value = getattr(params, key, None)
            if value is not None:
                files.append(value)
        geoid = get_dotted(config, "stages.georeference.geoid")
        if params.format == "lmsq_nmea" and geoid is not None:
            files.append(geoid)
        return files

    def run(self, ctx: StageContext[InputConfig]) -> None:
        if ctx.params.format == "ldmrs_mtig":
            return self._run_ldmrs(ctx)
        if ctx.params.format in ("lmsq_nmea", "lmsq_sbet"):
            return self._run_lmsq(ctx)
        return self._run_las(ctx)

    def _run_ldmrs(self, ctx: StageContext[LdmrsInput]) -> None:
        """3.A: the logs' scans, in time order, into the trajectory, the pulses and ``qc/``."""
        p = ctx.params
        counters = Counters()
        qc = ctx.outputs["qc"]
        qc.mkdir()
        trajectory_meta, pulses_meta = ldmrs_conventions(p)
        with (
            NpyColumns(ctx.outputs["trajectory"], LDMRS_TRAJECTORY_SCHEMA, trajectory_meta) as trajectory,
            NpyColumns(ctx.outputs["pulses"], PULSES_SCHEMA, pulses_meta) as pulses,
            ScanQc(qc) as scan_qc,
            ctx.progress(sum(path.stat().st_size for path in p.paths), "reading acquisition logs", unit="B") as bar,
        ):
            for scan in read_survey(p.paths, counters, leap_seconds=p.leap_seconds, progress=bar):
                trajectory.append(**scan_pose(scan))
                scan_qc.write(scan)
                if len(scan.points):
                    pulses.append(**scan_pulses(scan))
        figures = ldmrs_figures(counters)
        write_debug(qc, figures, counters.locations, sum(path.stat().st_size for path in p.paths))
        ctx.metrics.update(figures, problems=list(counters.locations))
        _log_ldmrs_counts(ctx.log, counters)
        if counters.scans_accepted == 0:
            where = counters.locations[0] if counters.locations else ", ".join(str(x) for x in p.paths)
            raise InputDataError(
                f"no usable scan in the acquisition log ({counters.scans_total} scans read; first problem: {where})."
            )

    def _run_lmsq(self, ctx: StageContext[LmsqNmeaInput | LmsqSbetInput]) -> None:
        """3.B, 3.C: the navigation files into the trajectory, the scanner streams into the pulses; ``qc/``."""
        p = ctx.params
        qc = ctx.outputs["qc"]
        qc.mkdir()
        week = _gps_week(p, ctx.log)
        nav_counters = TrajectoryCounters()
        trajectory, extra = _navigation(ctx, week, nav_counters)
        trajectory_meta, pulses_meta = lmsq_conventions(p, week)
        write_trajectory(ctx.outputs["trajectory"], trajectory, trajectory_meta)
        write_trajectory_csv(qc / "lla_eul_vel.csv", trajectory)
        counters = LmsqCounters()
        total = sum(path.stat().st_size for path in p.paths)
        with (
            NpyColumns(ctx.outputs["pulses"], PULSES_SCHEMA, pulses_meta) as pulses,
            ctx.progress(total, "reading scanner streams", unit="B") as bar,
        ):
            for block in read_streams(p.paths, counters, bar):
                pulses.append(**lmsq_pulses(block))
        epochs = len(trajectory["time"])
        figures = lmsq_figures(counters, pulses.rows, nav_counters, extra, epochs)
        write_debug(qc, figures, nav_counters.locations, total)
        ctx.metrics.update(figures, problems=list(nav_counters.locations), gps_week=week)
        _log_lmsq_counts(ctx.log, counters, pulses.rows, epochs)
        if pulses.rows == 0:
            raise InputDataError(
                f"no usable measurement in {', '.join(str(x) for x in p.paths)} "
                f"({counters.measurements} read, {counters.pps_ambiguous} after a missed PPS and ambiguous, "
                f"{counters.invalid_quality} invalid, {counters.before_first_pps} before the first PPS)."
            )

    def _run_las(self, ctx: StageContext[LasInput]) -> None:
        """3.D: the LAS/LAZ files into one LAS 1.4 file in the output CRS."""
        params = ctx.params
        paths = distinct_files(list(params.paths), ctx.log)
        index = read_headers(paths)
        total = index.total_points()
        assign = pyproj.CRS.from_user_input(params.crs) if params.crs else None
        override = pyproj.CRS.from_user_input(params.override_crs) if params.override_crs else None
        with ctx.progress(total, "reading LAS/LAZ", unit="pt") as bar:
            crs, report, strips = convert_las_files(
                paths,
                ctx.outputs["points_georef"],
                crs_setting=ctx.setting("crs"),
                assign_crs=assign,
                chunk_size=params.chunk_size,
                progress=bar,
                override_crs=override,
                index=index,
            )
        crs_names = {}
        for path in paths:
            if str(path) in report.points:
                crs_names[str(path)] = index.file_crs(path, assign, override)[0].name
        write_input_files_csv(ctx.outputs["input_files"], index, report.points, report.kept, crs_names)
        _log_las_report(ctx.log, report, override)
        if not sum(report.points.values()):
            files = ", ".join(str(x) for x in params.paths)
            raise InputDataError(f"{files}: no point in the file (its header announces 0 and no record follows).")
        _check_dtm_size(ctx.config, report.usable_box, Units.of(crs), ", ".join(str(x) for x in params.paths))
        ctx.metrics.update(
            points_read=int(sum(report.points.values())),
            points_per_file=report.points,
            points_kept_per_file=report.kept,
            crs=crs.name,
            crs_epsg=crs.to_epsg(),
            crs_source=report.crs_source,
            strips=sorted(strips),
            units=Units.of(crs).describe(),
            return_number_zero=report.return_number_zero,
            outside_header_bounds=report.outside_header_bounds,
            far_from_survey=report.far_from_survey,
            header_count_short={k: list(v) for k, v in report.header_count_short.items()},
            crs_notes=report.crs_notes,
            crs_read_as=report.crs_read_as,
            fields_dropped=report.dropped,
        )
        ctx.log.info("%d points in %s: %s", ctx.metrics["points_read"], crs.name, ctx.metrics["units"])
        state_heights(ctx, heights_of(crs, georeferenced=False))


def distinct_files(paths: list[Path], log: logging.LoggerAdapter) -> list[Path]:
    """*paths* with every file once (the same (st_dev, st_ino): a second spelling, a link, a glob); each repeat warned."""
    seen: dict[tuple[int, int], Path] = {}
    out = []
    for path in paths:
        st = path.stat()
        key = (st.st_dev, st.st_ino)
        if key in seen:
            log.warning("%s is %s again (listed twice in input.paths): read once", path, seen[key])
        else:
            seen[key] = path
            out.append(path)
    return out


def _gps_week(p: LmsqNmeaInput | LmsqSbetInput, log: logging.LoggerAdapter) -> int:
    """The GPS week of the navigation files: ``input.gps_week``, else the first PPS record's."""
    if p.gps_week is not None:
        return p.gps_week
    week = first_pps_week(p.paths[0])
    if week is None:
        raise InputDataError(
            f"{p.paths[0]}: no PPS record at the start of the stream, so the GPS week of the "
            "navigation files is unknown; set input.gps_week."
        )
    log.info("GPS week %d (from the first PPS record of %s)", week, p.paths[0].name)
    return week


def _navigation(
    ctx: StageContext[LmsqNmeaInput | LmsqSbetInput], week: int, counters: TrajectoryCounters
) -> tuple[dict, dict]:
    """The trajectory of 3.B (NMEA + INS) or 3.C (SBET) and its figures; fewer than two epochs is an error."""
    p = ctx.params
    if p.format == "lmsq_nmea":
        geoid = ctx.setting("stages.georeference.geoid")
        trajectory, extra = nmea_ins_trajectory(p, week, counters, ctx.log, geoid)
    else:
        trajectory, extra = sbet_trajectory(p, week, counters)
    if len(trajectory["time"]) < 2:
        where = counters.locations[0] if counters.locations else "no epoch with position and attitude"
        files = ", ".join(str(f) for f in ((p.nmea, p.ins) if p.format == "lmsq_nmea" else (p.sbet,)) if f)
        raise InputDataError(f"{files}: fewer than two usable navigation epochs (first problem: {where}).")
    return trajectory, extra


def _log_ldmrs_counts(log: logging.LoggerAdapter, counters: Counters) -> None:
    """Say how many scans were accepted and why the others were not."""
    log.info(
        "%d of %d scans accepted (%d invalid UTC, %d bad GPS, %d malformed, %d repeated, %d out of time order; "
        "%d lost, %d empty); %d valid points",
        counters.scans_accepted,
        counters.scans_total,
        counters.invalid_scans,
        counters.bad_gps,
        counters.malformed_scans,
        counters.duplicate_scans,
        counters.out_of_order_scans,
        counters.lost_scans,
        counters.empty_scans,
        counters.points_valid,
    )
    skipped = counters.invalid_scans + counters.bad_gps + counters.malformed_scans
    skipped += counters.duplicate_scans + counters.out_of_order_scans
    if skipped:
        log.warning("%d scans skipped; see qc/debug.txt", skipped)


def _log_lmsq_counts(log: logging.LoggerAdapter, counters: LmsqCounters, kept: int, epochs: int) -> None:
    """Say what became of the scanner's measurements."""
    log.info(
        "%d measurements read: %d kept, %d after a missed PPS (%d dated from the us counter and kept, "
        "%d ambiguous), %d invalid quality, %d before the first PPS; %d trajectory epochs",
        counters.measurements,
        kept,
        counters.missed_pps,
        counters.pps_recovered,
        counters.pps_ambiguous,
        counters.invalid_quality,
        counters.before_first_pps,
        epochs,
    )
    skipped = counters.before_first_pps + counters.pps_ambiguous + counters.invalid_quality
    if skipped or counters.truncated_bytes:
        log.warning("%d measurements skipped, %d bytes cut off; see qc/debug.txt", skipped, counters.truncated_bytes)


def _check_dtm_size(config, box, units, source: str) -> None:
    """Refuse, right after reading, a survey whose DTM grid the machine cannot hold (not hours later).

    It reads ``stages.rasterize`` undeclared: a refusal changes no product,
    and declaring it would re-read the survey when the DTM's cell changes.
    """
    raster = getattr(config.stages, "rasterize", None)
    if box is None or raster is None or not raster.enabled:
        return

    lo = units.to_metres(np.array([[box[0], box[1], 0.0]]))[0]
    hi = units.to_metres(np.array([[box[2], box[3], 0.0]]))[0]
    metres = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    check_grid_size(Grid.covering(*metres, raster.resolution), metres, units, source=source)


def _log_las_report(log: logging.LoggerAdapter, report: LasReadReport, override) -> None:
    """Say what the LAS reader repaired or assumed: every count, never silently."""
    if override is not None:
        log.info("input.override_crs: %s replaces the header CRS of every input file", override.name)
    for path, note in report.crs_read_as.items():  # GDAL's reading of the GeoKeys, not a repair
        log.info("%s: %s", path, note)
    for path, note in report.crs_notes.items():
        log.warning("%s: %s", path, note)
    for note in report.dropped:
        log.warning("%s", note)
    if report.gps_time_missing:
        log.warning("no GPS time in %s: gps_time set to 0", ", ".join(report.gps_time_missing))
    for path, n in report.return_number_zero.items():
        log.warning("%s: %d points have return number 0 (invalid in LAS): read as 1", path, n)
    for path, n in report.outside_header_bounds.items():
        log.warning(
            "%s: %d points lie outside the header's bounds (damaged records or strays): left out of points.laz "
            "and of every grid and filter",
            path,
            n,
        )
    if report.far_from_survey:
        log.warning(
            "%d points lie far from the survey's dense core: flagged withheld (kept in points.laz, left out of every "
            "grid and filter)",
            report.far_from_survey,
        )
    for path, (announced, held) in report.header_count_short.items():
        log.warning("%s: the header announces %d points but the file holds %d records: all read", path, announced, held)
