"""The ``input`` block: one parameter model per input format, chosen by ``format``.

The driver (:mod:`stages.parse.stage`) takes :data:`InputConfig` as its
``Params``; the trajectory builders of the raw formats read the models too.
"""

from __future__ import annotations

from datetime import date
from typing import Annotated, Literal

from pydantic import Field, field_validator

from lidar.crs import check_crs_setting
from lidar.glossary import LEAP_SECONDS
from pipeline.config import InputFile, StrictModel, input_files

FORMAT_HELP = (
    "input format: las (georeferenced LAS/LAZ) | ldmrs_mtig (SICK LD-MRS + Xsens MTi-G log) | lmsq_nmea "
    "(RIEGL .lmsq + NMEA + INS CSV) | lmsq_sbet (RIEGL .lmsq + Applanix SBET)"
)
#: The file names a folder or a glob pattern in ``input.paths`` picks (``.copc.laz`` ends with ``.laz``).
LAS_SUFFIXES = (".las", ".laz")


class LasInput(StrictModel):
    """Already georeferenced LAS/LAZ files (SPEC 3.D)."""

    format: Literal["las"] = Field(description=FORMAT_HELP)
    paths: Annotated[
        input_files(LAS_SUFFIXES),
        Field(
            min_length=1,
            description="LAS/LAZ/COPC files, folders (their .las/.laz files directly inside, not in subfolders) "
            "or glob patterns (tiles/*.laz; ** for any depth: survey/**/*.laz), relative to the config file; "
            "a folder's or pattern's files in sorted order, which is the order of the points",
        ),
    ]
    crs: str | None = Field(
        None,
        description="CRS of input files whose header has none or an unreadable one (PDAL's default_srs); e.g. EPSG:25830",
    )
    override_crs: str | None = Field(
        None,
        description="CRS of every input file, replacing whatever its header says (PDAL's override_srs); e.g. "
        "EPSG:26912; a compound CRS states the heights' vertical datum too, e.g. EPSG:28992+5709 (RD New + NAP)",
    )
    chunk_size: int = Field(1_000_000, ge=1000, description="points read at a time")

    @field_validator("crs", "override_crs")
    @classmethod
    def _known_crs(cls, value: str | None) -> str | None:
        return check_crs_setting(value)


class LeverArm(StrictModel):
    """A mounting not in the seed's presets: LD-MRS -> MTi-G is Ry(+90 deg), then this lever arm."""

    lever_arm_m: tuple[float, float, float] = Field(description="MPOS x, y, z in MTi-G axes, metres")


class LdmrsInput(StrictModel):
    """The seed-0 acquisition log, LD-MRS scanner + MTi-G GPS/INS (SPEC 3.A)."""

    format: Literal["ldmrs_mtig"] = Field(description=FORMAT_HELP)
    paths: Annotated[list[InputFile], Field(min_length=1, description="acquisition logs (.log or .log.gz), in order")]
    mounting: Literal["laboratorio", "pilatus", "cb5000"] | LeverArm = Field(
        description="a mounting of the LD-MRS system (docs/stages/parse.md: laboratorio, pilatus, cb5000), or "
        "{lever_arm_m: [x, y, z]} (required: it is never guessed)"
    )
    leap_seconds: float = Field(
        LEAP_SECONDS, description="GPS - UTC, seconds (18 since 2017-01-01) to turn UTC into GPS time"
    )


class _LmsqCommon(StrictModel):
    paths: Annotated[list[InputFile], Field(min_length=1, description=".lmsq scanner streams, in time order")]
    boresight_deg: tuple[float, float, float] = Field(
        description="scanner -> body rotation: roll, pitch, yaw in degrees, R = Rz(yaw) Ry(pitch) Rx(roll) (required)"
    )
    lever_arm_m: tuple[float, float, float] = Field(
        description="scanner origin in the body frame (x forward, y right, z down), metres, from the INS centre (required)"
    )
    gps_week: int | None = Field(
        None, ge=0, description="GPS week of the seconds-of-week times (default: from the stream's first PPS record)"
    )


class LmsqNmeaInput(_LmsqCommon):
    """The seed-2 design: .lmsq scanner stream + NMEA GNSS log + INS attitude CSV (SPEC 3.B)."""

    format: Literal["lmsq_nmea"] = Field(description=FORMAT_HELP)
    nmea: InputFile = Field(
        description="NMEA log (any talker: $xxGGA or GNS, HDT, VTG, GST, ZDA, RMC; $PASHR); .gz accepted"
    )
    ins: InputFile | None = Field(
        None,
        description="INS CSV gps_sow,roll_deg,pitch_deg,heading_deg (NED); .gz accepted; "
        "default: the NMEA log's $PASHR attitude (an error when it has none)",
    )
    nmea_date: date | None = Field(
        None, description="UTC date of the first NMEA time when the log has no $xxZDA or $xxRMC (never guessed)"
    )
    geoid_separation_m: float | None = Field(
        None,
        description="geoid separation (m) of fixes whose GGA/GNS separation field is empty (default: from "
        "stages.georeference.geoid; neither: an error, never 0)",
    )
    leap_seconds: float = Field(
        LEAP_SECONDS, description="GPS - UTC, seconds (18 since 2017-01-01) to turn UTC into GPS time"
    )
    max_gap_s: float = Field(
        1.0, gt=0, description="INS epochs inside a gap of GNSS positions longer than this get no position, seconds"
    )


class LmsqSbetInput(_LmsqCommon):
    """The same .lmsq stream with an Applanix SBET trajectory (+ optional smrmsg) (SPEC 3.C)."""

    format: Literal["lmsq_sbet"] = Field(description=FORMAT_HELP)
    sbet: InputFile = Field(description="SBET trajectory (17 float64 per record)")
    smrmsg: InputFile | None = Field(None, description="smrmsg accuracy file (10 float64 per record), optional")


#: The ``input`` block: one model per format, chosen by ``format``.
InputConfig = Annotated[LasInput | LdmrsInput | LmsqNmeaInput | LmsqSbetInput, Field(discriminator="format")]
