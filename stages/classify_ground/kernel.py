"""``classify_ground``'s work for the run service: the configured filter on tiles of points, or on the survey's grid.

Pass 1 gathers the lowest candidate of each cell; a filter with a grid form
(SMRF: :class:`~stages.classify_ground.filters.GridForm`) turns a window of
that grid into the surfaces its point test reads, and pass 2 tests every
candidate against its window's surfaces: the classes of the filter run on
all the points at once (docs/stages/classify_ground.md).  Grids here follow
the filters' own (:mod:`stages.classify_ground.surface`): rows from south to
north, a cell holding ``[k c, (k + 1) c)`` on both axes.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from lidar import glossary
from lidar.gridrun.kernel import Axis, Frame, StageKernel
from stages.classify_ground.filters import GROUND_FILTERS, GroundFilter, grid_cell, ground_mask, reach
from stages.classify_ground.ground_classes import candidates_of, new_classes
from stages.classify_ground.params import ClassifyGroundParams
from stages.classify_ground.surface import CellIndex


@dataclass(frozen=True)
class GroundKernel(StageKernel):
    """The stage's parameters (*params*: their JSON dump, with the filter's cell as the run uses it) as a kernel.

    *declared_in*: the module that declares the filter, imported where the
    kernel runs (a worker process) so that the filter is registered there.
    """

    params: dict
    declared_in: str = "stages.classify_ground.filters"

    Params: ClassVar = ClassifyGroundParams
    counts: ClassVar = ("points", "ground", "non_ground", "last_returns")
    fields: ClassVar = ("classification", "return_number", "number_of_returns", "withheld")
    axes: ClassVar = (Axis(1), Axis(0))  # rows from south to north, as the filters' grids
    margin: ClassVar = 1  # the point test samples the surfaces bilinearly: a point reads its cell's neighbours

    @classmethod
    def of(cls, params: ClassifyGroundParams) -> GroundKernel:
        return cls(params.model_dump(mode="json"), GROUND_FILTERS[params.algorithm.name].module)

    @cached_property
    def model(self) -> ClassifyGroundParams:
        __import__(self.declared_in)  # the filter's registration, in a worker process too
        return self.Params.model_validate(self.params)

    @property
    def algorithm(self) -> BaseModel:
        return self.model.algorithm

    @property
    def declared(self) -> GroundFilter:
        return GROUND_FILTERS[self.algorithm.name]

    @property
    def grid_form(self) -> bool:
        return self.declared.grid is not None

    @property
    def cell(self) -> float:
        return grid_cell(self.algorithm)

    @property
    def reach(self) -> float:
        return reach(self.algorithm)

    def tested(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        return candidates_of(**_point_columns(cols), params=self.model)[1]

    def classes(
        self, cols: dict[str, np.ndarray], tested: np.ndarray, values: np.ndarray
    ) -> tuple[np.ndarray, tuple[int, ...]]:
        keep = candidates_of(**_point_columns(cols), params=self.model)[0]
        ground = np.zeros(len(keep), dtype=bool)
        ground[tested] = values
        cls = new_classes(cols["classification"], keep, ground)
        last = int((cols["return_number"] >= cols["number_of_returns"]).sum())
        return cls, (len(cls), int((cls == glossary.GROUND).sum()), int((cls == glossary.UNCLASSIFIED).sum()), last)

    def tile(self, xyz: np.ndarray, cols: dict[str, np.ndarray], tested: np.ndarray) -> np.ndarray:
        if not tested.any():
            return np.zeros(0, dtype=bool)
        return ground_mask(xyz[tested], self.algorithm)

    # the grid form: the lowest candidate of each cell

    def selected(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        return self.tested(cols)

    def stats(self, size: int) -> dict[str, np.ndarray]:
        return {"zmin": np.full(size, np.inf)}

    def gather(self, stats: dict, step: int, k: np.ndarray, xyz: np.ndarray, cols: dict) -> None:
        np.minimum.at(stats["zmin"], k, xyz[:, 2])

    def occupied(self, stats: dict[str, np.ndarray]) -> np.ndarray:
        return np.isfinite(stats["zmin"])

    def window(self, stats: dict[str, np.ndarray], frame: Frame, threads: int = 1) -> dict[str, np.ndarray] | None:
        zmin = stats["zmin"]
        zmin = np.where(np.isfinite(zmin), zmin, np.nan)  # NaN where a cell holds no candidate
        surfaces = self.declared.grid.surfaces(zmin, self.algorithm, threads)
        return None if surfaces is None else {f"surface_{i}": s for i, s in enumerate(surfaces)}

    def values(self, xyz: np.ndarray, cols: dict, results: dict | None, frame: Frame | None) -> np.ndarray:
        if results is None or not len(xyz):
            return np.zeros(len(xyz), dtype=bool)
        # the corner as the filters' grids make it: a whole number of cells times the cell
        empty = np.zeros(0, np.int64)
        index = CellIndex(frame.corner(1), frame.corner(0), frame.cell, *frame.shape, empty, empty)
        surfaces = tuple(results[f"surface_{i}"] for i in range(len(results)))
        return self.declared.grid.test(xyz, index, surfaces, self.algorithm)


def _point_columns(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {k: cols[k] for k in ("classification", "return_number", "number_of_returns", "withheld")}
