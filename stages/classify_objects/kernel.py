"""The driver's shared work: the grid cell of a survey, the tile buffer, and one tile's classes in a worker."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar import glossary
from lidar.tile_classes import PointTask
from stages.classify_objects.objects import (
    BRIDGE,
    BUILDING,
    HIGH_VEGETATION,
    LOW_VEGETATION,
    MEDIUM_VEGETATION,
    WALLS,
    object_classes,
)
from stages.classify_objects.params import ClassifyObjectsParams
from stages.classify_objects.regions import RING, SHADOW

if TYPE_CHECKING:
    import laspy

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
    import laspy

    with laspy.open(str(path)) as reader:
        by_return = reader.header.number_of_points_by_return
    return len(by_return) > 1 and int(by_return[1]) > 0


def objects_columns(chunk: laspy.ScaleAwarePointRecord) -> dict[str, np.ndarray]:
    """The columns a tile needs besides x, y, z (:func:`lidar.tile_points.split_cloud`)."""
    return {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "number_of_returns": np.asarray(chunk.number_of_returns, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }


def objects_tile(task: PointTask) -> dict:
    """Buildings and vegetation of one tile (core plus buffer) in a worker; the classes of its core points.

    ``task.params``: ``{"params": ClassifyObjectsParams dump, "cell": m, "multi_echo": bool}``.
    """
    from lidar.tile_points import read_column, read_xyz, write_result

    source = Path(task.source)
    params = ClassifyObjectsParams.model_validate(task.params["params"])
    cls = read_column(source, "classification")
    usable = glossary.usable(cls, read_column(source, "withheld"))
    new, _ = object_classes(
        read_xyz(source),
        cls,
        read_column(source, "number_of_returns"),
        usable,
        params,
        float(task.params["cell"]),
        bool(task.params["multi_echo"]),
    )
    core = read_column(source, "core")
    write_result(Path(task.result), idx=read_column(source, "idx")[core], classification=new[core])
    return {"tile": task.tile, **dict(zip(COUNTS, class_counts(new[core], cls[core]), strict=True))}


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
