"""The settings of the ``strip_adjust`` stage: the rigid model's, and ``model: mounting``'s."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from lidar.glossary import cell_size
from pipeline.config import InputFile, StrictModel
from pipeline.stage import StageParams


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
        description="an estimate within this many of its sigmas of zero is not applied but reported as 'not "
        "determined beyond +-(this many sigmas)' (held at the configured value, the others solved again); 0: apply "
        "every estimate",
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
