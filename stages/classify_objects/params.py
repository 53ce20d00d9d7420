"""Parameters of ``classify_objects``: the grid, buildings (6) and vegetation (3, 4, 5)."""

from __future__ import annotations

from pydantic import Field, model_validator

from lidar import glossary
from pipeline.config import StrictModel
from pipeline.stage import StageParams


class BuildingParams(StrictModel):
    """Roofs: planar surfaces with a step down (walls) along most of their edge (docs/stages/classify_objects.md)."""

    enabled: bool = Field(True, description="look for buildings (class 6)")
    min_height: float = Field(
        2.0, gt=0, description="a roof stands at least this high (m) above the ground at its edge (LAStools' 2 m)"
    )
    min_area: float = Field(20.0, gt=0, description="smallest roof (m², in whole cells); smaller objects stay 1")
    max_size: float = Field(
        100.0, gt=0, description="widest building (m, either axis): wider surfaces are terrain; sets the tile buffer"
    )
    planarity: float = Field(
        0.15,
        gt=0,
        description="a roof cell's surface departs from the plane of its 3 x 3 cells by at most this (m RMS)",
    )
    wall_share: float = Field(
        0.5, gt=0, le=1, description="share of the cells around a roof (with points) lying min_height or more below it"
    )
    single_returns: float = Field(
        0.7, ge=0, le=1, description="share of a roof's points that are single returns (where the survey has several)"
    )


class BridgeParams(StrictModel):
    """Bridge decks: planar surfaces over a gap, open beneath their sides, joined to the ground at both ends."""

    enabled: bool = Field(True, description="look for bridge decks (class 17)")
    clearance: float = Field(
        2.0, gt=0, description="a deck stands at least this high (m) above the ground or water on both its sides"
    )
    max_width: float = Field(
        40.0, gt=0, description="widest deck (m): the ground or water below is looked for this far on each side"
    )
    planarity: float = Field(
        0.3,
        gt=0,
        description="a deck cell's surface departs from the plane of its 3 x 3 cells by at most this (m RMS);"
        " more than a roof's: railings and parapets line a deck a few cells wide",
    )


class VegetationParams(StrictModel):
    """Vegetation by height above the ground, where the surface is rough or the pulse returned several times."""

    enabled: bool = Field(True, description="classify vegetation (classes 3, 4, 5)")
    breaks: list[float] = Field(
        [0.5, 2.0, 5.0],
        min_length=3,
        max_length=3,
        description="heights above ground (m) where low (3), medium (4) and high (5) vegetation begin; below: 1",
    )
    multiple_returns: float = Field(
        0.1,
        ge=0,
        le=1,
        description="vegetation cell, in a survey with several returns per pulse: at least this share of the "
        "returns of its 3 x 3 cells are of multiple-return pulses",
    )
    roughness: float = Field(
        0.3,
        gt=0,
        description="vegetation cell, in a single-return survey: its surface departs from its 3 x 3 cells' plane "
        "by more (m RMS), or its points span the medium-vegetation break",
    )

    @model_validator(mode="after")
    def _ascending(self) -> VegetationParams:
        if not all(a < b for a, b in zip(self.breaks, self.breaks[1:], strict=False)) or self.breaks[0] < 0:
            raise ValueError("breaks must be three ascending heights >= 0")
        return self


class ClassifyObjectsParams(StageParams):
    cell_size: float = glossary.cell_size(1.0)
    sparse_cells: float = Field(
        1.5, gt=0, description="cells are at least this many nominal point spacings wide (a sparse survey's cells grow)"
    )
    one_grid_cells: int = Field(
        4_000_000,
        ge=0,
        description="the whole survey is classified on one grid, in two passes over the points, when the grid has "
        "at most this many cells (4 km2 of 1 m cells; about 230 bytes a cell at the peak: 0.9 GB, within the 1.2 GB "
        "a survey job holds); a grid up to 4 times larger is worked in the tiles' windows (48 bytes a cell held), "
        "larger surveys are cut into tiles of points with the buffer; 0: always tiles of points",
    )
    buildings: BuildingParams = Field(default_factory=BuildingParams, description="buildings (class 6)")
    bridges: BridgeParams = Field(default_factory=BridgeParams, description="bridge decks (class 17)")
    vegetation: VegetationParams = Field(default_factory=VegetationParams, description="vegetation (classes 3, 4, 5)")
