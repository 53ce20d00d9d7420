"""The driver's shared work: which points may be ground, their new classes, and the grid cell of a sparse survey.

:func:`classify` runs the configured algorithm (:func:`~stages.classify_ground.filters.ground_mask`)
on the candidates of a set of points (:func:`candidates_of`) and gives every point its new class.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np
from pydantic import BaseModel

from lidar import glossary
from stages.classify_ground.filters import GROUND_FILTERS, grid_cell, ground_mask
from stages.classify_ground.params import ClassifyGroundParams

if TYPE_CHECKING:
    from lidar.clouds import CloudInfo


#: A survey is sparse for a grid filter when its points are farther apart than this many cells.
SPARSE_SPACINGS = 3.0


#: Occupancy cells (in filter cells) over which the nominal point spacing is measured.
OCCUPANCY_CELLS = 32


def for_spacing(algorithm: BaseModel, spacing: float | None) -> BaseModel:
    """The algorithm with its grid cell raised to the point spacing of a sparse survey (SMRF, PMF).

    Where the points lie more than ``SPARSE_SPACINGS`` cells apart on
    average, a minimum surface would be almost all interpolated: the cell is
    then the nominal *spacing*, rounded up to a whole multiple of the
    configured cell; windows, slopes and thresholds stay in metres.  Denser
    surveys, and filters whose declaration says their cell does not follow
    the points (CSF), run as configured (docs/stages/classify_ground.md).

    >>> from stages.classify_ground.smrf import SmrfParams
    >>> for_spacing(SmrfParams(name="smrf"), 19.4).cell_size
    20.0
    >>> for_spacing(SmrfParams(name="smrf"), 1.5).cell_size
    1.0
    """
    declared = GROUND_FILTERS[algorithm.name]
    if not declared.sparse:
        return algorithm
    cell = grid_cell(algorithm)
    if spacing is None or not np.isfinite(spacing) or spacing <= SPARSE_SPACINGS * cell:
        return algorithm
    used = float(np.ceil(spacing / cell) * cell)
    return algorithm.model_copy(update={declared.cell: used})


def nominal_spacing(path: Path, cell: float, info: CloudInfo) -> float | None:
    """Nominal point spacing (metres) of the usable points, over the area they cover; None when surely dense.

    From the header first (count over the extent's area): a survey at least
    as dense as ``1 / (SPARSE_SPACINGS cell)²`` needs no more (None).  Otherwise one
    pass counts the points that are not noise or withheld and the cells of
    ``OCCUPANCY_CELLS`` x *cell* they occupy, so that stray points and large
    voids do not count as area: spacing = sqrt(occupied area / points).
    """
    xmin, ymin, xmax, ymax = info.extent
    area = max(xmax - xmin, cell) * max(ymax - ymin, cell)
    if info.count and area / info.count <= (SPARSE_SPACINGS * cell) ** 2:
        return None
    big = OCCUPANCY_CELLS * cell
    occupied: set[int] = set()
    count = 0
    with laspy.open(str(path)) as reader:
        for chunk in reader.chunk_iterator(1_000_000):
            cls = np.asarray(chunk.classification)
            keep = glossary.usable(cls, chunk.withheld)
            xy = info.units.to_metres(np.column_stack((np.asarray(chunk.x), np.asarray(chunk.y), np.zeros(len(cls)))))
            col = np.floor(xy[keep, 0] / big).astype(np.int64)
            row = np.floor(xy[keep, 1] / big).astype(np.int64)
            occupied.update(np.unique(row * (1 << 31) + col).tolist())
            count += int(keep.sum())
    if count == 0:
        return None
    return float(np.sqrt(len(occupied) * big * big / count))


def candidates_of(
    classification: np.ndarray,
    return_number: np.ndarray,
    number_of_returns: np.ndarray,
    withheld: np.ndarray,
    params: ClassifyGroundParams,
) -> tuple[np.ndarray, np.ndarray]:
    """``(keep, candidates)``: the points whose class stays, and those the algorithm may call ground."""
    kept_classes = (glossary.LOW_NOISE, glossary.HIGH_NOISE) + ((glossary.WATER,) if params.keep_water else ())
    keep = np.isin(classification, kept_classes) | np.asarray(withheld, dtype=bool)
    candidates = ~keep
    if params.last_returns:
        candidates &= np.asarray(return_number) >= np.asarray(number_of_returns)
    return keep, candidates


def new_classes(classification: np.ndarray, keep: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """2 where *ground*, 1 for the other points not kept, the input class where *keep*."""
    cls = np.asarray(classification).copy()
    cls[~keep] = glossary.UNCLASSIFIED
    cls[ground] = glossary.GROUND
    return cls


def classify(
    points: np.ndarray,
    classification: np.ndarray,
    return_number: np.ndarray,
    number_of_returns: np.ndarray,
    withheld: np.ndarray,
    params: ClassifyGroundParams,
) -> np.ndarray:
    """New classes: 2 ground, 1 other; noise (7, 18), withheld and (``keep_water``) water (9) points unchanged."""
    keep, candidates = candidates_of(classification, return_number, number_of_returns, withheld, params)
    ground = np.zeros(len(keep), dtype=bool)
    if candidates.any():
        ground[candidates] = ground_mask(points[candidates], params.algorithm)
    return new_classes(classification, keep, ground)
