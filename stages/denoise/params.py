"""Parameters of ``denoise``: the isolated-point test and the low-outlier test."""

from __future__ import annotations

from pydantic import Field

from lidar import glossary
from pipeline.config import StrictModel
from pipeline.stage import StageParams


class IsolatedParams(StrictModel):
    """Isolation in 3-D at the local point spacing (:func:`stages.denoise.outliers.isolated_points`)."""

    enabled: bool = Field(True, description="look for isolated points")
    neighbors: int = Field(
        2, ge=1, description="the test looks at the distance (3-D) to this nearest point (2: pairs are found too)"
    )
    spacing_neighbors: int = Field(
        8, ge=1, description="the local point spacing is the distance (plan) to this nearest point"
    )
    multiplier: float = Field(10.0, gt=0, description="isolated: farther than this many local spacings")
    min_distance: float = Field(2.0, ge=0, description="and farther than this (m): closer is never isolated")
    radius: float = Field(
        30.0, gt=0, description="distances are counted up to this (m); it bounds how far the test looks"
    )


class LowParams(StrictModel):
    """Extended local minimum test (:func:`stages.denoise.outliers.low_outliers`)."""

    enabled: bool = Field(
        False, description="look for low outliers (off: on steep ground under canopy it flags real ground)"
    )
    cell_size: float = glossary.cell_size(10.0)
    elevation_threshold: float = Field(
        2.0, gt=0, description="height gap (m) between a low outlier and the points above it in its cell"
    )


class DenoiseParams(StageParams):
    isolated: IsolatedParams = Field(default_factory=IsolatedParams, description="isolated points")
    low: LowParams = Field(default_factory=LowParams, description="low outliers (multipath, below-ground echoes)")
