"""Parameters of ``classify_ground``: the stage's and each ground algorithm's (SMRF, PMF, CSF).

The algorithm is a discriminated union on ``algorithm.name``; the models live
here so that the algorithm modules and the driver share them.
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from lidar import glossary
from pipeline.config import StrictModel
from pipeline.stage import StageParams


class SmrfParams(StrictModel):
    """Simple morphological filter (Pingel et al. 2013); see :func:`stages.classify_ground.smrf.smrf`."""

    name: Literal["smrf"] = Field(description="ground algorithm: smrf | pmf | csf")
    cell_size: float = glossary.cell_size(1.0)
    slope: float = glossary.slope(0.15)
    max_window_size: float = Field(18.0, gt=0, description="w_max: largest window radius, metres")
    elevation_threshold: float = Field(0.5, ge=0, description="et: base height threshold of the point test, metres")
    elevation_scalar: float = Field(1.25, ge=0, description="es: threshold added per unit of local DEM slope, metres")
    floor_window: float = Field(
        3.0,
        ge=0,
        description="objects flagged by an opening of radius up to this (metres) bound the provisional DEM under "
        "them by that opening (bridge decks; 0: off; docs/GROUND.md)",
    )
    wall_height: float = Field(
        2.0,
        ge=0,
        description="rise (metres) that walls in a plateau: walled plateaus wider than w_max inside the survey "
        "are objects (buildings wider than the window; 0: off; docs/GROUND.md)",
    )


class PmfParams(StrictModel):
    """Progressive morphological filter (Zhang et al. 2003); see :func:`stages.classify_ground.pmf.pmf`."""

    name: Literal["pmf"] = Field(description="ground algorithm: smrf | pmf | csf")
    cell_size: float = glossary.cell_size(1.0)
    max_window_size: float = glossary.max_window_size(33.0)
    slope: float = glossary.slope(0.15)
    initial_distance: float = Field(0.15, ge=0, description="dh_0: first elevation-difference threshold, metres")
    max_distance: float = Field(2.5, ge=0, description="dh_max: largest elevation-difference threshold, metres")


class CsfParams(StrictModel):
    """Cloth simulation filter (Zhang W. et al. 2016); see :func:`stages.classify_ground.csf.csf`."""

    name: Literal["csf"] = Field(description="ground algorithm: smrf | pmf | csf")
    cloth_resolution: float = Field(0.5, gt=0, description="GR: spacing of the cloth particles, metres")
    rigidness: int = Field(1, ge=1, le=3, description="RI: 1 steep, 2 relief, 3 flat")
    class_threshold: float = Field(0.5, gt=0, description="hcc: distance to the cloth for ground, metres")
    time_step: float = Field(0.65, gt=0, description="dT: simulation time step")
    iterations: int = Field(500, ge=1, description="maximum simulation iterations")
    slope_smooth: bool = Field(True, description="post-process steep slopes")


GroundAlgorithm = Annotated[SmrfParams | PmfParams | CsfParams, Field(discriminator="name")]


ALGORITHMS = {"smrf": SmrfParams, "pmf": PmfParams, "csf": CsfParams}


class ClassifyGroundParams(StageParams):
    algorithm: GroundAlgorithm = Field(
        default_factory=lambda: SmrfParams(name="smrf"), description="the ground algorithm and its parameters"
    )
    last_returns: bool = Field(True, description="only last or single returns can be ground")
    keep_water: bool = Field(True, description="points the input classified as water (9) keep it; never ground")
    one_grid_cells: int = Field(
        8_000_000,
        ge=0,
        description="SMRF filters the whole survey on one grid, in passes over the points, when the grid has at "
        "most this many cells (8 km2 of 1 m cells; about 55 bytes a cell while it is filtered, more where cells "
        "are empty); a grid up to 4 times larger is filtered in the tiles' windows (8 bytes a cell held), "
        "larger surveys are cut into tiles of points with its buffer; 0: always tiles of points",
    )
