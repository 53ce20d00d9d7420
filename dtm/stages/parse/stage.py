"""Stage ``parse``: read the survey's input files into the common intermediates.

Its parameters are the configuration's ``input`` block; ``input.format``
chooses the reader:

- ``las`` (SPEC 3.D): georeferenced LAS/LAZ.  Output: the point cloud
  (``points_georef``), already in the output CRS; georeferencing does not
  apply.
- ``ldmrs_mtig`` (3.A), ``lmsq_nmea`` (3.B) and ``lmsq_sbet`` (3.C), the raw
  formats.  Outputs: the ``trajectory`` (time, lat, lon, h, roll, pitch,
  yaw and, when the files give them, sigmas) and the ``pulses`` (time,
  vector in the scanner frame, echo, channel, angle, amplitude, flags,
  scan), folders of ``.npy`` columns with a ``meta.json`` that states the
  conventions (time system, attitude frame, mounting); and ``qc/`` with the
  counters of everything skipped (``debug.txt``) and the trajectory as CSV
  (``lla_eul_vel.csv``; for 3.A also the seed-0 ``scans.txt``).  The
  ``georeference`` stage turns them into points.

Times everywhere: GPS seconds since 1980-01-06 (UTC + ``leap_seconds`` for
the UTC-stamped formats; week x 604800 + seconds of week for the others).
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np

from dtm.stages.parse.params import InputConfig
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext, StageIO, get_dotted

LDMRS_TRAJECTORY_SCHEMA = {
    "time": "f8", "lat": "f8", "lon": "f8", "h": "f8", "roll": "f8", "pitch": "f8", "yaw": "f8",
    "scan": "u2", "vx": "f8", "vy": "f8", "vz": "f8", "status": "u1",
}  # fmt: skip
#: ``flags`` bit of an .lmsq measurement dated from the us counter after a missed PPS
RECOVERED_FLAG = 0x80
#: The pulses of every raw format.
PULSES_SCHEMA = {
    "time": "f8", "x": "f8", "y": "f8", "z": "f8", "echo": "u1", "channel": "u1", "angle": "f8",
    "amplitude": "u1", "flags": "u1", "scan": "u2",
}  # fmt: skip


class Parse(Stage):
    """Read the configured input into the pipeline's intermediates."""

    name = "parse"
    # 9: LD-MRS scans in time order; LAS: override_crs, header checks, stray points withheld, return 0 read as 1,
    # the input's GPS time type, RGB, NIR, extra bytes kept; 8: .lmsq measurements after a missed PPS dated by the
    # us counter; NMEA dated by ZDA/RMC anywhere; angles modulo 360; 7: LAS 1.4 format 6 copied as delivered
    version = "9"
    Params = InputConfig
    config_path = "input"
    config_keys = ("crs", "stages.georeference.geoid")  # the geoid: NMEA fixes without a geoid separation
    description = "read the input files (format from input.format)"
    outputs: ClassVar = {"points_georef": "points.las"}

    def is_enabled(self, params, config) -> bool:
        return True

    def declare(self, params, config) -> StageIO:
        if params.format == "las":
            return StageIO(outputs={"points_georef": "points.las"})
        return StageIO(outputs={"trajectory": "trajectory", "pulses": "pulses", "qc": "qc"}, products={"qc": "qc"})

    def external_files(self, params, config) -> list[Path]:
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

    def _run_ldmrs(self, ctx) -> None:
        from dtm.common.columns import NpyColumns
        from dtm.common.rotation import rot_y
        from dtm.stages.parse.read_ldmrs import MOUNTINGS, Counters, TimeOrder, TimeOrderError, read_ldmrs_mtig

        p = ctx.params
        counters = Counters()
        qc = ctx.outputs["qc"]
        qc.mkdir()
        lever = MOUNTINGS[p.mounting] if isinstance(p.mounting, str) else p.mounting.lever_arm_m
        conventions = {
            "format": p.format,
            "time": "GPS seconds since 1980-01-06 (UTC + leap_seconds)",
            "leap_seconds": p.leap_seconds,
        }
        trajectory_meta = {
            **conventions,
            "convention": "NWU",
            "position": "WGS 84 latitude, longitude (deg), ellipsoidal height (m)",
            "attitude": "MTi-G body (x forward, y left, z up) vs local-level NWU: R = Rz(yaw) Ry(pitch) Rx(roll), "
            "degrees, yaw counter-clockwise from north",
            "velocity": "body frame, m/s",
        }
        pulses_meta = {
            **conventions,
            "frame": "LD-MRS: x optical axis, y left, z up; metres",
            "mounting": p.mounting if isinstance(p.mounting, str) else "custom",
            "rotation": rot_y(np.pi / 2).round(15).tolist(),
            "lever_arm": list(lever),
            "body_axes": "MTi-G: x forward, y left, z up",
        }
        with (
            NpyColumns(ctx.outputs["trajectory"], LDMRS_TRAJECTORY_SCHEMA, trajectory_meta) as traj,
            NpyColumns(ctx.outputs["pulses"], PULSES_SCHEMA, pulses_meta) as pulses,
            open(qc / "scans.txt", "w", encoding="utf-8") as scans_txt,
            open(qc / "lla_eul_vel.csv", "w", encoding="utf-8") as lla_csv,
            ctx.progress(len(p.paths), "reading acquisition logs", unit="file") as bar,
        ):
            lla_csv.write("scan,time_gps,lat_deg,lon_deg,h_m,roll_deg,pitch_deg,yaw_deg,vx_ms,vy_ms,vz_ms\n")

            def write(scans: list) -> None:
                for scan in scans:
                    lat, lon, h = scan.lla
                    roll, pitch, yaw = scan.euler
                    vx, vy, vz = scan.vel
                    traj.append(
                        scan=[scan.number], time=[scan.time_gps], lat=[lat], lon=[lon], h=[h], roll=[roll],
                        pitch=[pitch], yaw=[yaw], vx=[vx], vy=[vy], vz=[vz], status=[scan.status],
                    )  # fmt: skip
                    lla_csv.write(
                        f"{scan.number},{scan.time_gps:.6f},{lat:.10f},{lon:.10f},{h:.4f},"
                        f"{roll:.7f},{pitch:.7f},{yaw:.7f},{vx:.3f},{vy:.3f},{vz:.3f}\n"
                    )
                    n = len(scan.points)
                    if n:
                        scans_txt.write(f"{scan.number}\n")
                        pts = scan.points
                        pulses.append(
                            time=np.full(n, scan.time_gps), x=pts[:, 3], y=pts[:, 4], z=pts[:, 5], echo=pts[:, 1],
                            channel=pts[:, 0], angle=np.degrees(np.arctan2(pts[:, 4], pts[:, 3])),
                            amplitude=np.zeros(n), flags=pts[:, 2], scan=np.full(n, scan.number),
                        )  # fmt: skip

            order = TimeOrder(counters)  # across files: a survey's logs in time order
            try:
                for path in p.paths:
                    for scan in _guard_stream(
                        read_ldmrs_mtig(path, counters, leap_seconds=p.leap_seconds), path, counters
                    ):
                        write(order.feed(scan))
                    bar.update(1)
                write(order.flush())
            except TimeOrderError as exc:
                raise InputDataError(f"{exc}.") from None
        figures = {k: v for k, v in vars(counters).items() if k != "locations"}
        _write_debug(qc, figures, counters.locations, sum(path.stat().st_size for path in p.paths))
        ctx.metrics.update(figures, problems=list(counters.locations))
        skipped = counters.invalid_scans + counters.bad_gps + counters.malformed_scans
        skipped += counters.duplicate_scans + counters.out_of_order_scans
        ctx.log.info(
            "%d of %d scans accepted (%d invalid UTC, %d bad GPS, %d malformed, %d repeated, %d out of time order; "
            "%d lost, %d empty); %d valid points",
            counters.scans_accepted, counters.scans_total, counters.invalid_scans, counters.bad_gps,
            counters.malformed_scans, counters.duplicate_scans, counters.out_of_order_scans, counters.lost_scans,
            counters.empty_scans, counters.points_valid,
        )  # fmt: skip
        if skipped:
            ctx.log.warning("%d scans skipped; see qc/debug.txt", skipped)
        if counters.scans_accepted == 0:
            where = counters.locations[0] if counters.locations else ", ".join(str(x) for x in p.paths)
            raise InputDataError(
                f"no usable scan in the acquisition log ({counters.scans_total} scans read; first problem: {where})."
            )

    def _run_lmsq(self, ctx) -> None:
        from dtm.common.columns import NpyColumns
        from dtm.common.rotation import euler_matrix
        from dtm.stages.parse.read_ins import TrajectoryCounters
        from dtm.stages.parse.read_lmsq import LmsqCounters, first_pps_week, read_lmsq
        from dtm.stages.parse.trajectory import nmea_ins_trajectory, sbet_trajectory

        p = ctx.params
        qc = ctx.outputs["qc"]
        qc.mkdir()
        week = p.gps_week
        if week is None:
            week = first_pps_week(p.paths[0])
            if week is None:
                raise InputDataError(
                    f"{p.paths[0]}: no PPS record at the start of the stream, so the GPS week of the "
                    "navigation files is unknown; set input.gps_week."
                )
            ctx.log.info("GPS week %d (from the first PPS record of %s)", week, p.paths[0].name)
        nav_counters = TrajectoryCounters()
        if p.format == "lmsq_nmea":
            geoid = ctx.setting("stages.georeference.geoid")
            trajectory, extra = nmea_ins_trajectory(p, week, nav_counters, ctx.log, geoid)
        else:
            trajectory, extra = sbet_trajectory(p, week, nav_counters)
        if len(trajectory["time"]) < 2:
            where = nav_counters.locations[0] if nav_counters.locations else "no epoch with position and attitude"
            files = ", ".join(str(f) for f in ((p.nmea, p.ins) if p.format == "lmsq_nmea" else (p.sbet,)) if f)
            raise InputDataError(f"{files}: fewer than two usable navigation epochs (first problem: {where}).")
        conventions = {"format": p.format, "time": "GPS seconds since 1980-01-06", "gps_week": week}
        traj_meta = {
            **conventions,
            "convention": "NED",
            "position": "WGS 84 latitude, longitude (deg), ellipsoidal height (m)",
            "attitude": "body (x forward, y right, z down) vs local-level NED: R = Rz(yaw) Ry(pitch) Rx(roll), degrees, "
            "yaw = true heading, clockwise from north",
        }
        schema = {name: "f8" for name in trajectory}
        with NpyColumns(ctx.outputs["trajectory"], schema, traj_meta) as traj:
            traj.append(**trajectory)
        _write_trajectory_csv(qc / "lla_eul_vel.csv", trajectory)
        pulses_meta = {
            **conventions,
            "frame": "scanner: x forward, y starboard, z down; a pulse at mirror angle t is range x (0, sin t, cos t)",
            "rotation": euler_matrix(*np.radians(p.boresight_deg)).tolist(),
            "boresight_deg": list(p.boresight_deg),
            "lever_arm": list(p.lever_arm_m),
            "body_axes": "x forward, y right, z down",
            "flags": "bits 0-5: the measurement's quality; bit 7 (0x80): time recovered from the us counter "
            "after a missed PPS",
        }
        counters = LmsqCounters()
        total = sum(path.stat().st_size for path in p.paths)
        with (
            NpyColumns(ctx.outputs["pulses"], PULSES_SCHEMA, pulses_meta) as pulses,
            ctx.progress(total, "reading scanner streams", unit="B") as bar,
        ):
            for path in p.paths:
                last = 0
                for block in read_lmsq(path, counters):
                    th = np.radians(block["angle_deg"])
                    r = block["range_m"]
                    n = len(r)
                    pulses.append(
                        time=block["time"], x=np.zeros(n), y=r * np.sin(th), z=r * np.cos(th), echo=block["echo"],
                        channel=np.zeros(n), angle=block["angle_deg"], amplitude=block["amplitude"],
                        flags=block["quality"] | np.where(block["recovered"], RECOVERED_FLAG, 0).astype(np.uint8),
                        scan=np.zeros(n),
                    )  # fmt: skip
                    done = int(block["byte"][-1])
                    bar.update(done - last)
                    last = done
        figures = {f"scanner_{k}": v for k, v in vars(counters).items()}
        figures["pulses_read"] = pulses.rows
        figures.update({f"navigation_{k}": v for k, v in vars(nav_counters).items() if k != "locations"})
        figures.update(extra)
        figures["trajectory_epochs"] = len(trajectory["time"])
        _write_debug(qc, figures, nav_counters.locations, total)
        ctx.metrics.update(figures, problems=list(nav_counters.locations), gps_week=week)
        skipped = counters.before_first_pps + counters.pps_ambiguous + counters.invalid_quality
        ctx.log.info(
            "%d measurements read: %d kept, %d after a missed PPS (%d dated from the us counter and kept, "
            "%d ambiguous), %d invalid quality, %d before the first PPS; %d trajectory epochs",
            counters.measurements, pulses.rows, counters.missed_pps, counters.pps_recovered,
            counters.pps_ambiguous, counters.invalid_quality, counters.before_first_pps, len(trajectory["time"]),
        )  # fmt: skip
        if skipped or counters.truncated_bytes:
            ctx.log.warning("%d measurements skipped, %d bytes cut off; see qc/debug.txt", skipped,
                            counters.truncated_bytes)  # fmt: skip
        if pulses.rows == 0:
            raise InputDataError(
                f"no usable measurement in {', '.join(str(x) for x in p.paths)} "
                f"({counters.measurements} read, {counters.pps_ambiguous} after a missed PPS and ambiguous, "
                f"{counters.invalid_quality} invalid, {counters.before_first_pps} before the first PPS)."
            )

    def _run_las(self, ctx) -> None:
        import pyproj

        from dtm.stages.parse.read_las import convert_las_files, count_points

        params = ctx.params
        total = count_points(list(params.paths))
        assign = pyproj.CRS.from_user_input(params.crs) if params.crs else None
        override = pyproj.CRS.from_user_input(params.override_crs) if params.override_crs else None
        with ctx.progress(total, "reading LAS/LAZ", unit="pt") as bar:
            crs, report, strips = convert_las_files(
                list(params.paths),
                ctx.outputs["points_georef"],
                crs_setting=ctx.setting("crs"),
                assign_crs=assign,
                chunk_size=params.chunk_size,
                progress=bar,
                override_crs=override,
            )
        _log_las_report(ctx.log, report, override)
        if not sum(report.points.values()):
            files = ", ".join(str(x) for x in params.paths)
            raise InputDataError(f"{files}: no point in the file (its header announces 0 and no record follows).")
        from dtm.common.units import Units

        _check_dtm_size(ctx.config, report.usable_box, Units.of(crs), ", ".join(str(x) for x in params.paths))

        ctx.metrics.update(
            points_read=int(sum(report.points.values())),
            points_per_file=report.points,
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


def _check_dtm_size(config, box, units, source: str) -> None:
    """Refuse, right after reading, a survey whose DTM grid the machine cannot hold (not hours later).

    It reads ``stages.rasterize`` undeclared: a refusal changes no product,
    and declaring it would re-read the survey when the DTM's cell changes.
    """
    raster = getattr(config.stages, "rasterize", None)
    if box is None or raster is None or not raster.enabled:
        return
    from dtm.common.grid import Grid, check_grid_size

    lo = units.to_metres(np.array([[box[0], box[1], 0.0]]))[0]
    hi = units.to_metres(np.array([[box[2], box[3], 0.0]]))[0]
    metres = (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))
    check_grid_size(Grid.covering(*metres, raster.resolution), metres, units, source=source)


def _log_las_report(log, report, override) -> None:
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
            "%s: %d points lie outside the header's bounds: flagged withheld (kept in points.laz, "
            "left out of every grid and filter)",
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


def _guard_stream(iterator, path: Path, counters):
    """Iterate a reader; a damaged compressed stream ends the file with a note, not a traceback."""
    import zlib

    try:
        yield from iterator
    except (EOFError, zlib.error, OSError) as exc:
        counters.malformed_scans += 1
        counters.note(f"{path}: the compressed stream is damaged ({exc}); the rest of the file is unreadable")


def _write_debug(qc: Path, figures: dict, locations: list[str], size: int) -> None:
    """``qc/debug.txt``: every counter, the input size, the first problems with their locations."""
    lines = [f"{k} {v}" for k, v in figures.items()]
    lines += ["", f"input bytes {size}", "first problems:" if locations else "problems: none"]
    lines += [f"  {where}" for where in locations]
    (qc / "debug.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")


def _write_trajectory_csv(path: Path, traj: dict[str, np.ndarray]) -> None:
    names = list(traj)
    table = np.column_stack([traj[n] for n in names])
    fmt = ["%.6f", "%.10f", "%.10f", "%.4f"] + ["%.7f"] * (len(names) - 4)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, table, fmt=fmt, delimiter=",")
