"""Stage ``parse``: read the survey's input files into the common intermediates.

Its parameters are the configuration's ``input`` block; ``input.format``
chooses the reader.  Formats available in this version:

- ``las`` (SPEC 3.D): georeferenced LAS/LAZ.  Output: the point cloud
  (``points_georef``), already in the output CRS, so georeferencing does not
  apply.
- ``ldmrs_mtig`` (SPEC 3.A): the seed-0 acquisition log.  Outputs: the
  ``trajectory`` (one pose per accepted scan) and the ``pulses`` (valid
  points in the LD-MRS frame) as folders of ``.npy`` columns with a
  ``meta.json``, and the seed-0 QC files (``qc/debug.txt``, ``qc/scans.txt``,
  ``qc/lla_eul_vel.csv``).  Georeferencing them is the next stage to come;
  until it exists such a configuration runs with ``--until parse``.

The formats ``lmsq_nmea`` and ``lmsq_sbet`` (SPEC 3.B, 3.C) are still to come;
the configuration rejects them with the list of formats available.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator

from pipeline.config import InputFile, StrictModel
from pipeline.stage import Stage, StageIO
from stages.io import write_cloud


def _check_crs(value: str | None) -> str | None:
    if value is None or value == "auto-utm":
        return value
    import pyproj

    try:
        pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError:
        raise ValueError(f"'{value}' is not a CRS pyproj knows (use e.g. EPSG:25830 or auto-utm)") from None
    return value


class LasInput(StrictModel):
    """Already georeferenced LAS/LAZ files (SPEC 3.D)."""

    format: Literal["las"] = Field(description="input format: las | ldmrs_mtig (lmsq_nmea, lmsq_sbet to come)")
    paths: Annotated[list[InputFile], Field(min_length=1, description="LAS/LAZ files, relative to the config file")]
    crs: str | None = Field(
        None, description="CRS of input files whose header has none (a header CRS always wins); e.g. EPSG:25830"
    )
    chunk_size: int = Field(1_000_000, ge=1000, description="points read at a time")

    @field_validator("crs")
    @classmethod
    def _known_crs(cls, value: str | None) -> str | None:
        return _check_crs(value)


class LeverArm(StrictModel):
    """A mounting not in the seed's presets: LD-MRS -> MTi-G is Ry(+90 deg), then this lever arm."""

    lever_arm_m: tuple[float, float, float] = Field(description="MPOS x, y, z in MTi-G axes, metres")


class LdmrsInput(StrictModel):
    """The seed-0 acquisition log, LD-MRS scanner + MTi-G GPS/INS (SPEC 3.A)."""

    format: Literal["ldmrs_mtig"] = Field(description="input format: las | ldmrs_mtig (lmsq_nmea, lmsq_sbet to come)")
    paths: Annotated[list[InputFile], Field(min_length=1, description="acquisition logs, read in this order")]
    mounting: Literal["laboratorio", "pilatus", "cb5000"] | LeverArm = Field(
        description="seed-0 Table 15 preset, or {lever_arm_m: [x, y, z]} (required: it is never guessed)"
    )
    leap_seconds: float = Field(18.0, description="GPS - UTC, seconds (18 since 2017-01-01) to turn UTC into GPS time")


#: The ``input`` block: one model per format, chosen by ``format``.
InputConfig = Annotated[LasInput | LdmrsInput, Field(discriminator="format")]

TRAJECTORY_SCHEMA = {
    "scan": "u2",
    "time": "f8",
    "lat": "f8",
    "lon": "f8",
    "h": "f8",
    "roll": "f8",
    "pitch": "f8",
    "yaw": "f8",
    "vx": "f8",
    "vy": "f8",
    "vz": "f8",
    "status": "u1",
}
PULSES_SCHEMA = {
    "scan": "u2",
    "time": "f8",
    "layer": "u1",
    "echo": "u1",
    "flags": "u1",
    "x": "f8",
    "y": "f8",
    "z": "f8",
}


class Parse(Stage):
    """Read the configured input into the pipeline's intermediates."""

    name = "parse"
    version = "2"
    Params = InputConfig
    config_path = "input"
    can_disable = False
    config_keys = ("crs",)
    description = "read the input files (format from input.format)"
    outputs: ClassVar = {"points_georef": "points.las"}

    def is_enabled(self, params, config) -> bool:
        return True

    def declare(self, params, config) -> StageIO:
        if params.format == "ldmrs_mtig":
            return StageIO(outputs={"trajectory": "trajectory", "pulses": "pulses", "qc": "qc"}, products={"qc": "qc"})
        return StageIO(outputs={"points_georef": "points.las"})

    def external_files(self, params, config) -> list[Path]:
        return list(params.paths)

    def run(self, ctx) -> None:
        if ctx.params.format == "ldmrs_mtig":
            return self._run_ldmrs(ctx)
        return self._run_las(ctx)

    def _run_ldmrs(self, ctx) -> None:
        from pipeline.errors import InputDataError
        from stages.io import NpyColumns
        from stages.readers.ldmrs import Counters, read_ldmrs_mtig

        p = ctx.params
        counters = Counters()
        qc = ctx.outputs["qc"]
        qc.mkdir()
        conventions = {
            "format": p.format,
            "time": "GPS seconds since 1980-01-06 (UTC + leap_seconds)",
            "leap_seconds": p.leap_seconds,
            "mounting": p.mounting if isinstance(p.mounting, str) else p.mounting.model_dump(),
        }
        trajectory_meta = {
            **conventions,
            "position": "WGS 84 latitude, longitude (deg), ellipsoidal height (m)",
            "attitude": "MTi-G body vs local-level NWU: R = Rz(yaw) Ry(pitch) Rx(roll), degrees, yaw counter-clockwise from north",
            "velocity": "body frame, m/s",
        }
        pulses_meta = {**conventions, "frame": "LD-MRS: x optical axis, y left, z up; metres"}
        size = sum(path.stat().st_size for path in p.paths)
        with (
            NpyColumns(ctx.outputs["trajectory"], TRAJECTORY_SCHEMA, trajectory_meta) as traj,
            NpyColumns(ctx.outputs["pulses"], PULSES_SCHEMA, pulses_meta) as pulses,
            open(qc / "scans.txt", "w", encoding="utf-8") as scans_txt,
            open(qc / "lla_eul_vel.csv", "w", encoding="utf-8") as lla_csv,
            ctx.progress(len(p.paths), "reading acquisition logs", unit="file") as bar,
        ):
            lla_csv.write("scan,time_gps,lat_deg,lon_deg,h_m,roll_deg,pitch_deg,yaw_deg,vx_ms,vy_ms,vz_ms\n")
            for path in p.paths:
                for scan in read_ldmrs_mtig(path, counters, leap_seconds=p.leap_seconds):
                    lat, lon, h = scan.lla
                    roll, pitch, yaw = scan.euler
                    vx, vy, vz = scan.vel
                    traj.append(
                        scan=[scan.number], time=[scan.time_gps], lat=[lat], lon=[lon], h=[h], roll=[roll],
                        pitch=[pitch], yaw=[yaw], vx=[vx], vy=[vy], vz=[vz], status=[scan.status],
                    )  # fmt: skip
                    lla_csv.write(
                        f"{scan.number},{scan.time_gps:.6f},{lat:.9f},{lon:.9f},{h:.3f},"
                        f"{roll:.4f},{pitch:.4f},{yaw:.4f},{vx:.3f},{vy:.3f},{vz:.3f}\n"
                    )
                    n = len(scan.points)
                    if n:
                        scans_txt.write(f"{scan.number}\n")
                        pts = scan.points
                        pulses.append(
                            scan=np.full(n, scan.number), time=np.full(n, scan.time_gps), layer=pts[:, 0],
                            echo=pts[:, 1], flags=pts[:, 2], x=pts[:, 3], y=pts[:, 4], z=pts[:, 5],
                        )  # fmt: skip
                bar.update(1)
        figures = {k: v for k, v in vars(counters).items() if k != "locations"}
        lines = [f"{k} {v}" for k, v in figures.items()]
        lines += ["", f"input bytes {size}", "first problems:" if counters.locations else "problems: none"]
        lines += [f"  {where}" for where in counters.locations]
        (qc / "debug.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")
        ctx.metrics.update(figures, problems=list(counters.locations))
        skipped = counters.invalid_scans + counters.bad_gps + counters.malformed_scans
        ctx.log.info(
            "%d of %d scans accepted (%d invalid UTC, %d bad GPS, %d malformed; %d lost, %d empty); %d valid points",
            counters.scans_accepted, counters.scans_total, counters.invalid_scans, counters.bad_gps,
            counters.malformed_scans, counters.lost_scans, counters.empty_scans, counters.points_valid,
        )  # fmt: skip
        if skipped:
            ctx.log.warning("%d scans skipped; see qc/debug.txt", skipped)
        if counters.scans_accepted == 0:
            where = counters.locations[0] if counters.locations else ", ".join(str(x) for x in p.paths)
            raise InputDataError(
                f"no usable scan in the acquisition log ({counters.scans_total} scans read; first problem: {where})."
            )

    def _run_las(self, ctx) -> None:
        import pyproj

        from stages.readers.las import count_points, read_las_files

        params = ctx.params
        total = count_points(list(params.paths))
        assign = pyproj.CRS.from_user_input(params.crs) if params.crs else None
        with ctx.progress(total, "reading LAS/LAZ", unit="pt") as bar:
            las, report = read_las_files(
                list(params.paths),
                crs_setting=ctx.config.crs,
                assign_crs=assign,
                chunk_size=params.chunk_size,
                progress=bar,
            )
        if report.gps_time_missing:
            ctx.log.warning("no GPS time in %s: gps_time set to 0", ", ".join(report.gps_time_missing))
        crs = las.header.parse_crs()
        ctx.metrics.update(
            points_read=int(sum(report.points.values())),
            points_per_file=report.points,
            crs=crs.name,
            crs_epsg=crs.to_epsg(),
            crs_source=report.crs_source,
            strips=[int(s) for s in np.unique(np.asarray(las.point_source_id))],
        )
        ctx.log.info("%d points in %s", ctx.metrics["points_read"], crs.name)
        write_cloud(las, ctx.outputs["points_georef"])
