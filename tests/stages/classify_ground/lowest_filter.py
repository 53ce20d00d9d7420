"""A trivial ground filter, registered as a product's filter would be: the lowest point of each cell and those near it.

Used by ``test_filter_registry.py`` to show what adding a ground filter
takes: this module and one :meth:`~pipeline.registry.Registry.register`
call.  It registers when imported (in the run's worker processes too,
which import the module that declared a filter before they use it).
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from pipeline.config import StrictModel
from stages.classify_ground.filters import GROUND_FILTERS, GroundFilter


class LowestParams(StrictModel):
    """The parameters of :func:`lowest`."""

    name: Literal["lowest"] = Field(description="the ground algorithm: lowest")
    cell_size: float = Field(2.0, gt=0, description="side of the cells (m)")
    tolerance: float = Field(0.1, ge=0, description="a point within this (m) of its cell's lowest is ground")


def lowest(xyz: np.ndarray, *, cell_size: float, tolerance: float) -> np.ndarray:
    """True where a point lies within *tolerance* of the lowest point of its cell of *cell_size* (whole multiples)."""
    col = np.floor(xyz[:, 0] / cell_size).astype(np.int64)
    row = np.floor(xyz[:, 1] / cell_size).astype(np.int64)
    _, k = np.unique(np.column_stack((row, col)), axis=0, return_inverse=True)
    k = k.ravel()
    low = np.full(k.max() + 1 if len(k) else 0, np.inf)
    np.minimum.at(low, k, xyz[:, 2])
    return xyz[:, 2] <= low[k] + tolerance


def reach(params: LowestParams) -> float:
    """A point's cell: one cell around it (its cell may straddle a tile's edge)."""
    return params.cell_size


DECLARED = GroundFilter(
    name="lowest",
    params=LowestParams,
    reach=reach,
    function=lowest,
    summary="the lowest point of each cell, and those within a tolerance of it",
    sparse=False,
)


def register() -> None:
    """Register the filter (once)."""
    if DECLARED.name not in GROUND_FILTERS:
        GROUND_FILTERS.register(DECLARED)


register()
