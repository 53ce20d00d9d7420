"""Parameters of ``classify_ground``: the stage's; each ground algorithm's model lives beside its function.

``algorithm`` holds one of the registered filters (:data:`stages.classify_ground.filters.GROUND_FILTERS`)
with its parameters, validated by the model of the one it names.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import BaseModel, Field

from pipeline.stage import StageParams
from stages.classify_ground.filters import GROUND_FILTERS


class ClassifyGroundParams(StageParams):
    algorithm: Annotated[BaseModel, GROUND_FILTERS.field()] = Field(
        default_factory=GROUND_FILTERS.default("smrf"), description="the ground algorithm and its parameters"
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
