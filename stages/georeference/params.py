"""The settings of the ``georeference`` stage: frame, strips, batches and per-point uncertainty."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from lidar.georeferencing import BATCH_SIZE, MAX_GAP_S
from pipeline.config import InputFile, StrictModel
from pipeline.stage import StageParams


class StripParams(StrictModel):
    turn_rate_deg_s: float = Field(1.0, gt=0, description="a turn rate above this (deg/s, smoothed over 2 s) is a turn")
    min_line_s: float = Field(10.0, ge=0, description="a steady-heading run shorter than this (s) is not a strip")
    keep_turns: bool = Field(False, description="keep the points flown in turns (strip id 0); default: drop and count")


class UncertaintyParams(StrictModel):
    """One-sigma errors for the per-point propagated uncertainty (none is guessed)."""

    range_m: float = Field(gt=0, description="scanner range error, metres (e.g. 0.025 for the LMS-Q140i)")
    scan_angle_deg: float = Field(ge=0, description="scanner angle error, degrees (e.g. 0.005 for the LMS-Q140i)")
    position_m: float | None = Field(
        None, gt=0, description="position error per axis, metres; default: the trajectory's own sigmas (GST, smrmsg)"
    )
    attitude_deg: float | None = Field(
        None, gt=0, description="roll, pitch and heading error, degrees; default: the trajectory's sigmas (smrmsg)"
    )
    boresight_deg: float = Field(0.0, ge=0, description="boresight calibration error, degrees (0: treated as exact)")
    lever_arm_m: float = Field(0.0, ge=0, description="lever-arm measurement error per axis, metres (0: exact)")


class GeoreferenceParams(StageParams):
    frame: Literal["exact", "ltp"] = Field(
        "exact",
        description="exact (PROJ to crs) or ltp (one local tangent plane at the first fix, the LD-MRS system's formula)",
    )
    max_gap_s: float = Field(
        MAX_GAP_S, gt=0, description="pulses inside a gap of the trajectory longer than this get no position, seconds"
    )
    geoid: InputFile | None = Field(
        None, description="geoid grid (GeoTIFF/GTX, PROJ vgridshift) for orthometric heights"
    )
    ltp_radius_m: float = Field(
        6_371_000.0, gt=0, description="ltp: the Earth radius R of the local tangent plane's formula, metres"
    )
    strips: StripParams = Field(default_factory=StripParams)
    batch_size: int = Field(BATCH_SIZE, ge=10_000, description="pulses georeferenced per batch (memory ~ 200 B each)")
    uncertainty: UncertaintyParams | None = Field(
        None,
        description="per-point propagated uncertainty (LAS extra bytes sigma_horizontal, sigma_vertical); off when absent",
    )
