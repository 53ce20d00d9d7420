"""The driver's shared work: which points may be ground, their new classes, grid cell and tile buffer.

:func:`classify` runs the configured algorithm (:func:`ground_mask`) on the
candidates of a set of points (:func:`candidates_of`) and gives every point
its new class; :func:`classify_tile` does it for one tile in a worker.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar import glossary
from lidar.tile_classes import PointTask
from pipeline.config import StrictModel
from stages.classify_ground.params import ClassifyGroundParams

if TYPE_CHECKING:
    import laspy

    from lidar.clouds import CloudInfo


def reach(algorithm: StrictModel) -> float:
    """How far (metres) the algorithm looks from a point: the buffer a tile needs.

    SMRF: an opening of radius ``w_max`` reads ``2 w_max`` around a cell, and
    a gap it fills (a building, at most ``2 w_max`` wide by the parameter's
    definition) takes its values from cells that far again, so ``4 w_max``
    plus two cells for the provisional DEM; the second pass (low cells below
    that DEM left out of the openings, :func:`stages.classify_ground.smrf.smrf`)
    opens and fills again around cells decided by it: ``8 w_max`` plus two
    cells.  PMF: the largest square window, twice, plus two cells.
    CSF: the cloth is one global simulation; 50 m is a practical margin and
    tiled CSF results may differ from untiled ones within a few metres of
    tile edges (docs/stages/classify_ground.md, "Tiled and untiled runs").
    """
    if algorithm.name == "smrf":
        return 8.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size
    if algorithm.name == "pmf":
        return 2.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size
    return 50.0


#: A survey is sparse for a grid filter when its points are farther apart than this many cells.
SPARSE_SPACINGS = 3.0


#: Occupancy cells (in filter cells) over which the nominal point spacing is measured.
OCCUPANCY_CELLS = 32


def grid_cell(algorithm: StrictModel) -> float:
    """The cell (metres) of the algorithm's grid: SMRF's and PMF's ``cell_size``, CSF's cloth spacing."""
    return float(algorithm.cloth_resolution if algorithm.name == "csf" else algorithm.cell_size)


def for_spacing(algorithm: StrictModel, spacing: float | None) -> StrictModel:
    """The algorithm with its grid cell raised to the point spacing of a sparse survey (SMRF, PMF).

    Where the points lie more than ``SPARSE_SPACINGS`` cells apart on
    average, a minimum surface would be almost all interpolated: the cell is
    then the nominal *spacing*, rounded up to a whole multiple of the
    configured cell; windows, slopes and thresholds stay in metres.  Denser
    surveys, and CSF always, run as configured (docs/stages/classify_ground.md).

    >>> from stages.classify_ground.params import SmrfParams
    >>> for_spacing(SmrfParams(name="smrf"), 19.4).cell_size
    20.0
    >>> for_spacing(SmrfParams(name="smrf"), 1.5).cell_size
    1.0
    """
    if algorithm.name == "csf":  # a cloth particle needs no point in its cell: CSF is run as configured
        return algorithm
    cell = grid_cell(algorithm)
    if spacing is None or not np.isfinite(spacing) or spacing <= SPARSE_SPACINGS * cell:
        return algorithm
    used = float(np.ceil(spacing / cell) * cell)
    return algorithm.model_copy(update={"cell_size": used})


def nominal_spacing(path: Path, cell: float, info: CloudInfo) -> float | None:
    """Nominal point spacing (metres) of the usable points, over the area they cover; None when surely dense.

    From the header first (count over the extent's area): a survey at least
    as dense as ``1 / (SPARSE_SPACINGS cell)²`` needs no more (None).  Otherwise one
    pass counts the points that are not noise or withheld and the cells of
    ``OCCUPANCY_CELLS`` x *cell* they occupy, so that stray points and large
    voids do not count as area: spacing = sqrt(occupied area / points).
    """
    import laspy

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


def ground_mask(points: np.ndarray, algorithm: StrictModel) -> np.ndarray:
    """Run the configured algorithm on (n, 3) coordinates; True = ground."""
    params = algorithm.model_dump(exclude={"name"})
    if algorithm.name == "smrf":
        from stages.classify_ground.smrf import smrf

        return smrf(points, **params)
    if algorithm.name == "pmf":
        from stages.classify_ground.pmf import pmf

        return pmf(points, **params)
    if algorithm.name == "csf":
        from stages.classify_ground.csf import csf

        return csf(points, **params)
    raise ValueError(f"unknown ground algorithm {algorithm.name}")  # pragma: no cover - config rejects it


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


def classify_columns(chunk: laspy.ScaleAwarePointRecord) -> dict[str, np.ndarray]:
    """The columns :func:`classify` needs besides x, y, z, of a chunk of points."""
    return {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "return_number": np.asarray(chunk.return_number, dtype=np.uint8),
        "number_of_returns": np.asarray(chunk.number_of_returns, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }


def classify_tile(task: PointTask) -> dict:
    """Classify one tile's points (core plus buffer) in a worker process; write the classes of its core points.

    Reads the tile's columns (:func:`lidar.tile_points.split_cloud`),
    writes ``idx`` and ``classification`` of the core points to
    ``task.result`` and returns counts.
    """
    from lidar.tile_points import read_tile, write_result

    cols = read_tile(Path(task.source))
    params = ClassifyGroundParams.model_validate(task.params)
    cls = classify(
        cols["xyz"], cols["classification"], cols["return_number"], cols["number_of_returns"], cols["withheld"], params
    )
    core = cols["core"]
    write_result(Path(task.result), idx=cols["idx"][core], classification=cls[core])
    kept = cls[core]
    last = cols["return_number"][core] >= cols["number_of_returns"][core]
    return {
        "tile": task.tile,
        "points": int(core.sum()),
        "last_returns": int(last.sum()),
        "ground": int((kept == glossary.GROUND).sum()),
        "non_ground": int((kept == glossary.UNCLASSIFIED).sum()),
    }
