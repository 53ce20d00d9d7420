"""``classify_objects``' work for the run service: the survey's grid of cells, each window's cell grids, each point's class.

Pass 1 gathers each cell's statistics (:func:`~stages.classify_objects.objects.add_sums`,
on the grid :func:`~stages.classify_objects.objects.surface` makes of the
usable points); a window's cell grids are :func:`~stages.classify_objects.objects.object_cells`
of its statistics, and each point takes its class by its cell
(:func:`~stages.classify_objects.objects.point_classes`): the classes of
:func:`~stages.classify_objects.objects.object_classes` on all the points at
once.  Cells are those of the stage's north-up :class:`~lidar.grid.Grid`:
a cell holds ``x`` in ``[c, c + 1)`` cells and ``y`` in ``(r - 1, r]`` cells.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import laspy
import numpy as np

from lidar import glossary
from lidar.grid import Grid
from lidar.gridrun.kernel import Axis, Frame, StageKernel
from stages.classify_objects.objects import (
    BRIDGE,
    BUILDING,
    HIGH_VEGETATION,
    LOW_VEGETATION,
    MEDIUM_VEGETATION,
    WALLS,
    ObjectCells,
    add_sums,
    cell_index,
    cell_sums,
    object_cells,
    object_classes,
    point_classes,
    surface_of,
)
from stages.classify_objects.params import ClassifyObjectsParams
from stages.classify_objects.regions import RING, SHADOW

if TYPE_CHECKING:
    from lidar.clouds import CloudInfo

#: Widest cell (m) the tile buffer allows for (a survey sparser than about 3 m between points).
MAX_CELL = 5.0

#: The counts every tile returns, summed by the driver.
COUNTS = (
    "points",
    "buildings",
    "roof_was_ground",
    "bridge_decks",
    "low_vegetation",
    "medium_vegetation",
    "high_vegetation",
)


def reach(params: ClassifyObjectsParams) -> float:
    """The buffer (m) a tile needs for results equal to untiled ones.

    A roof is at most ``max_size`` wide, the walls are looked for ``RING``
    cells and ``SHADOW`` metres beyond it, and a gap in the ground under it
    is filled from at most ``max_size`` away: a region cut by the tile's
    edge is wider than ``max_size`` in the tile as in the survey, so it is
    no roof in either (docs/stages/classify_objects.md).
    """
    return params.buildings.max_size + SHADOW + WALLS + (RING + 2) * max(params.cell_size, MAX_CELL)


def survey_cell(params: ClassifyObjectsParams, info: CloudInfo) -> float:
    """The grid cell (m): ``cell_size``, or ``sparse_cells`` nominal spacings (count over extent), whole cells.

    >>> from types import SimpleNamespace
    >>> survey_cell(ClassifyObjectsParams(), SimpleNamespace(extent=(0, 0, 100, 100), count=40_000))
    1.0
    >>> survey_cell(ClassifyObjectsParams(), SimpleNamespace(extent=(0, 0, 100, 100), count=1_000))
    5.0
    """
    xmin, ymin, xmax, ymax = info.extent
    area = max(xmax - xmin, params.cell_size) * max(ymax - ymin, params.cell_size)
    spacing = math.sqrt(area / max(info.count, 1))
    return float(max(1.0, math.ceil(params.sparse_cells * spacing / params.cell_size)) * params.cell_size)


def several_returns(path: Path) -> bool:
    """Whether the survey's pulses returned more than once (the header's count of second returns)."""
    with laspy.open(str(path)) as reader:
        by_return = reader.header.number_of_points_by_return
    return len(by_return) > 1 and int(by_return[1]) > 0


def class_counts(new: np.ndarray, was: np.ndarray) -> tuple[int, ...]:
    """:data:`COUNTS` of points whose classes were *was* and are *new*."""
    building = new == BUILDING
    return (
        len(new),
        int(building.sum()),
        int((building & (was == glossary.GROUND)).sum()),
        int((new == BRIDGE).sum()),
        int((new == LOW_VEGETATION).sum()),
        int((new == MEDIUM_VEGETATION).sum()),
        int((new == HIGH_VEGETATION).sum()),
    )


@dataclass(frozen=True)
class ObjectsKernel(StageKernel):
    """The stage's parameters (*params*: their JSON dump), the survey's *cell* (m) and whether it has several returns."""

    params: dict
    cell: float
    multi_echo: bool

    Params: ClassVar = ClassifyObjectsParams
    counts: ClassVar = COUNTS
    axes: ClassVar = (Axis(1, down=True), Axis(0))  # the rows of a north-up grid
    fields: ClassVar = ("classification", "return_number", "number_of_returns", "withheld")

    @property
    def reach(self) -> float:
        return reach(self.model)

    def tested(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        return glossary.usable(cols["classification"], cols["withheld"])

    def classes(
        self, cols: dict[str, np.ndarray], tested: np.ndarray, values: np.ndarray
    ) -> tuple[np.ndarray, tuple[int, ...]]:
        out = cols["classification"].copy()
        out[tested] = values
        return out, class_counts(out, cols["classification"])

    def tile(self, xyz: np.ndarray, cols: dict[str, np.ndarray], tested: np.ndarray) -> np.ndarray:
        cls = cols["classification"]
        new, _ = object_classes(
            xyz,
            cls,
            cols["number_of_returns"],
            tested,
            self.model,
            self.cell,
            self.multi_echo,
            return_number=cols["return_number"],
        )
        return new[tested]

    # the grid form: each cell's statistics

    def selected(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        return self.tested(cols)

    def stats(self, size: int) -> dict[str, np.ndarray]:
        return cell_sums(size)

    def gather(self, stats: dict, step: int, k: np.ndarray, xyz: np.ndarray, cols: dict) -> None:
        nret = cols["number_of_returns"]
        last = cols["return_number"] >= nret
        add_sums(stats, k, xyz[:, 2], nret <= 1, cols["classification"] == glossary.GROUND, last)

    def occupied(self, stats: dict[str, np.ndarray]) -> np.ndarray:
        return stats["count"] > 0

    def window(self, stats: dict[str, np.ndarray], frame: Frame, threads: int = 1) -> dict[str, np.ndarray]:
        surface = surface_of(_grid(frame), **stats)
        cells = object_cells(surface, self.model, self.multi_echo)
        return {f.name: getattr(cells, f.name) for f in fields(cells) if f.name != "grid"}

    def values(self, xyz: np.ndarray, cols: dict, results: dict | None, frame: Frame | None) -> np.ndarray:
        cls = cols["classification"]
        if results is None:
            return cls.copy()
        cells = ObjectCells(_grid(frame), **results)
        k = cell_index(xyz, cells.grid)
        if (k < 0).any():  # pragma: no cover - each point's cell is in its window by construction
            raise RuntimeError(f"a point lies outside its window's grid {cells.grid}")
        return point_classes(cells, k, cls, xyz[:, 2], cols["number_of_returns"], self.model, cols["return_number"])[0]


def _grid(frame: Frame) -> Grid:
    """The north-up grid of a frame (its rows' labels are the cells' tops)."""
    return Grid(frame.corner(1), frame.corner(0), frame.cell, frame.shape[1], frame.shape[0])
