"""SMRF on one grid of the whole survey, in passes over its points: no tile, no buffer.

SMRF's grid steps (:func:`stages.classify_ground.smrf.provisional_dem`)
need no point, and a survey's grid is small next to its points (8 bytes a
cell against 30 or more a point): :func:`smrf_one_grid` makes the grid of the
lowest candidates a chunk of points at a time, filters it whole, then tests
and writes each chunk's points, in this process or on the workers
(:func:`classes_range`).  The classes are those of SMRF on all the points at
once (docs/stages/classify_ground.md).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar import glossary
from lidar.grid_classes import (
    RecordRange,
    box_worth_reading,
    grids_of,
    las_chunks,
    rewrite_range,
    workers_layout,
    write_classes,
)
from lidar.grid_windows import WINDOWED_BEYOND, scratch
from stages.classify_ground.ground_classes import candidates_of, classify_columns, new_classes
from stages.classify_ground.params import ClassifyGroundParams, SmrfParams
from stages.classify_ground.surface import CellIndex, grid_corner
from stages.classify_ground.windows import Windows, WindowSurfaces, filter_windows, window_tasks

if TYPE_CHECKING:
    from pipeline.executor import DaskExecutor, LocalExecutor
    from pipeline.log import Progress


def _chunks(path: Path, work, *, chunk_size: int = 1_000_000):
    """``work(chunk, xyz, columns)`` of each chunk of a LAS file, in file order (:func:`las_chunks`).

    ``columns`` are what :func:`classify` needs, as :func:`lidar.tile_points.split_cloud` reads them.
    """
    return las_chunks(path, lambda chunk, xyz: work(chunk, xyz, classify_columns(chunk)), chunk_size=chunk_size)


def _anchored(lo, hi, cell: float) -> tuple[float, float, int, int]:
    """``(x0, y0, rows, cols)`` of the grid of cells of *cell* over a box, anchored as :func:`stages.classify_ground.surface.index_points`."""
    x0, y0 = grid_corner(lo, cell)
    return x0, y0, int(np.floor((hi[1] - y0) / cell)) + 1, int(np.floor((hi[0] - x0) / cell)) + 1


def _candidate_bounds(src: Path, params: ClassifyGroundParams, chunk_size: int = 1_000_000):
    """Lowest and highest x, y of the points the algorithm may call ground; None when there is none."""

    def bounds(_, xyz, cols):
        _, cand = candidates_of(**cols, params=params)
        if not cand.any():
            return np.full(2, np.inf), np.full(2, -np.inf)
        return xyz[cand, :2].min(axis=0), xyz[cand, :2].max(axis=0)

    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for low, high in _chunks(src, bounds, chunk_size=chunk_size):
        lo, hi = np.minimum(lo, low), np.maximum(hi, high)
    return (lo, hi) if np.isfinite(lo).all() else None


def _lowest(src: Path, params: ClassifyGroundParams, anchor, progress=None, chunk_size: int = 1_000_000):
    """The lowest candidate per cell of the grid *anchor*, and the rows and columns the candidates occupy.

    Returns ``(zmin, (r0, r1, c0, c1))`` (NaN where a cell holds no
    candidate; ``r1``, ``c1`` inclusive; None without candidates), or None
    when a candidate lies off the grid (a header whose bounds miss points).
    """
    x0, y0, rows, cols = anchor
    cell = params.algorithm.cell_size

    def cells(_, xyz, columns):
        _, cand = candidates_of(**columns, params=params)
        col = np.floor((xyz[cand, 0] - x0) / cell).astype(np.int64)
        row = np.floor((xyz[cand, 1] - y0) / cell).astype(np.int64)
        if not len(col):
            return len(xyz), None, None, None
        box = (row.min(), row.max(), col.min(), col.max())
        return len(xyz), box, row * cols + col, xyz[cand, 2]

    zmin = np.full(rows * cols, np.inf)
    box = [rows, -1, cols, -1]
    for n, part, flat, z in _chunks(src, cells, chunk_size=chunk_size):
        if part is not None:
            r0, r1, c0, c1 = part
            if r0 < 0 or c0 < 0 or r1 >= rows or c1 >= cols:
                return None
            box = [min(box[0], r0), max(box[1], r1), min(box[2], c0), max(box[3], c1)]
            np.minimum.at(zmin, flat, z)
        if progress is not None:
            progress.update(n)
    zmin[~np.isfinite(zmin)] = np.nan
    return zmin.reshape(rows, cols), (tuple(int(b) for b in box) if box[1] >= 0 else None)


#: What step 3 counts, in this order: points, ground, non-ground, last (or single) returns.
COUNTS = ("points", "ground", "non_ground", "last_returns")


def smrf_one_grid(
    src: Path,
    dst: Path,
    params: ClassifyGroundParams,
    *,
    threads: int = 1,
    chunk_size: int = 1_000_000,
    progress: Progress | None = None,
    executor: LocalExecutor | DaskExecutor | None = None,
    workdir: Path | None = None,
    tiles: tuple[int, int] | None = None,
) -> dict | None:
    """SMRF on one grid of the whole survey: *src* copied to *dst* with the new classes; None when too big.

    1. the lowest candidate per cell (:func:`lowest_grid`);
    2. the grid cut to the cells the candidates occupy, filtered whole on
       *threads* bands of rows (:func:`survey_surfaces`);
    3. each chunk's point test and classes, written as it is read; with an
       *executor* of more than one worker (and a *workdir* for the grids),
       on the workers, a range of records each (:func:`classes_range`).

    With *tiles* ``(tile, buffer)`` in cells (:func:`~lidar.grid_windows.tile_cells`),
    a grid of more than ``one_grid_cells`` cells, up to
    :data:`~lidar.grid_windows.WINDOWED_BEYOND` times that,
    is filtered in the tiles' windows instead, and each point tested in its
    tile's (:func:`_windows`).

    Returns the counts (:data:`COUNTS`, ``grid``: its rows and columns,
    ``windows``: how many were filtered, 0 for the grid filtered whole), or
    None (nothing written) when the candidates' grid is larger: the caller tiles.
    """
    from lidar.clouds import cloud_info

    info = cloud_info(src)
    windowed = tiles is not None and params.one_grid_cells > 0
    records = workers_layout(src, info.count, executor, workdir, chunk_size, classes_range)
    cap = params.one_grid_cells * (WINDOWED_BEYOND if windowed else 1)
    lowest = lowest_grid(src, params, info.extent, progress, chunk_size, cap=cap)
    if lowest is None:
        return None
    zmin, box, anchor = lowest
    del lowest
    shape = (box[1] - box[0] + 1, box[3] - box[2] + 1) if box is not None else (0, 0)
    dump = params.model_dump(mode="json")

    write = partial(_step3, src, dst, executor, workdir, params, chunk_size, progress)
    if windowed and shape[0] * shape[1] > params.one_grid_cells:
        with scratch(workdir, dst, ".smrf-windows") as folder:
            windows, filtered = _windows(folder, zmin, anchor, tiles, params.algorithm, executor)
            del zmin
            test = partial(WindowSurfaces(windows).ground, algo=params.algorithm)
            numbers = write(
                records, test, {}, lambda r, _: WindowsTask(records=r, params=dump, windows=windows), windows_range
            )
    else:
        grid, surfaces = survey_surfaces(zmin, box, anchor, params.algorithm, threads=threads)
        del zmin  # the grid of the lowest points, before the points are read again
        filtered = 0
        numbers = write(
            records if surfaces is not None else None,  # no cell left: no point is ground, nothing to read
            _grid_test(params.algorithm, grid, surfaces),
            {"dem": surfaces[0], "slope": surfaces[1]} if surfaces is not None else {},
            lambda r, paths: RangeTask(
                records=r, params=dump, grid=(grid.x0, grid.y0, grid.cell_size, grid.rows, grid.cols), surfaces=paths
            ),
            classes_range,
        )
    return {**dict(zip(COUNTS, numbers, strict=True)), "grid": shape, "windows": filtered}


def _step3(src, dst, executor, workdir, params, chunk_size, progress, records, test, grids, task, run) -> list[int]:
    """Step 3 of :func:`smrf_one_grid` by ``test(xyz)``: :func:`~lidar.grid_classes.write_classes` of its
    classes, on the workers when *records* allows (*grids*, *task*, *run*: theirs), else here."""
    return write_classes(
        src,
        dst,
        records,
        executor,
        classes=lambda chunk, xyz: _chunk_classes(xyz, classify_columns(chunk), params, test),
        width=len(COUNTS),
        folder=Path(workdir) / ".smrf-one-grid" if workdir is not None else None,
        grids=grids,
        task=task,
        run=run,
        chunk_size=chunk_size,
        what="point test",
        progress=progress,
    )


def _windows(folder, zmin, anchor, tiles, algo: SmrfParams, executor) -> tuple[Windows, int]:
    """Step 2 of :func:`smrf_one_grid` in the tiles' windows, filtered on the workers: the windows, and how many.

    The grid *zmin* (on *anchor*, :func:`lowest_grid`'s) is saved in
    *folder* for the workers (removed after) and cut into windows
    (:func:`~stages.classify_ground.windows.window_tasks`).
    """
    cell = algo.cell_size
    np.save(folder / "zmin.npy", zmin)
    origin = (round(anchor[1] / cell), round(anchor[0] / cell))
    tasks = window_tasks(zmin, origin, *tiles, algo, folder)
    first = filter_windows(tasks, executor)
    (folder / "zmin.npy").unlink()
    return Windows(cell, tiles[0], str(folder), tuple((*key, *at) for key, at in sorted(first.items()))), len(tasks)


def lowest_grid(
    src: Path,
    params: ClassifyGroundParams,
    extent: tuple[float, float, float, float],
    progress: Progress | None = None,
    chunk_size: int = 1_000_000,
    cap: int | None = None,
) -> tuple[np.ndarray, tuple[int, int, int, int] | None, tuple[float, float, int, int]] | None:
    """Step 1 of :func:`smrf_one_grid`: the lowest candidate per cell; None when its grid is too big.

    On the grid of the header's *extent*, or of the candidates' own bounds
    when a candidate lies off it (a header whose bounds miss points) or it
    has far more than ``one_grid_cells`` cells (stray points; the bounds are
    then read first: :func:`~lidar.grid_classes.box_worth_reading`);
    None at once when it has more, but not far more.  Returns ``(zmin, box, anchor)``: :func:`_lowest`'s
    grid and box, and :func:`_anchored`'s grid; None when the candidates'
    grid too has more than ``one_grid_cells`` cells (or *cap*, when given).
    """
    cell, cap = params.algorithm.cell_size, params.one_grid_cells if cap is None else cap
    anchor = _anchored(extent[:2], extent[2:], cell)
    cells = anchor[2] * anchor[3]
    if cap < cells and not box_worth_reading(cells, cap):
        return None  # a survey larger than one grid: tiled
    got = _lowest(src, params, anchor, progress, chunk_size) if cells <= cap else None
    if got is None:  # the header's grid is too big (stray points) or misses points: the candidates' own
        bounds = _candidate_bounds(src, params, chunk_size)
        anchor = _anchored(*bounds, cell) if bounds is not None else (0.0, 0.0, 1, 1)
        if anchor[2] * anchor[3] > cap:
            return None
        got = _lowest(src, params, anchor, chunk_size=chunk_size)
    zmin, box = got
    return zmin, box, anchor


def survey_surfaces(
    zmin: np.ndarray,
    box: tuple[int, int, int, int] | None,
    anchor: tuple[float, float, int, int],
    algo: SmrfParams,
    *,
    threads: int = 1,
) -> tuple[CellIndex | None, tuple[np.ndarray, np.ndarray] | None]:
    """Step 2 of :func:`smrf_one_grid`: the grid cut to the candidates' *box*, and its provisional DEM and slope.

    *zmin*, *box*, *anchor*: :func:`lowest_grid`'s.  ``(None, None)``
    without candidates; the surfaces are None when the filter leaves no
    cell (:func:`stages.classify_ground.smrf.provisional_dem`).
    """
    from stages.classify_ground.smrf import provisional_dem

    if box is None:
        return None, None
    cell = algo.cell_size
    r0, r1, c0, c1 = box
    x0, y0 = anchor[0] + c0 * cell, anchor[1] + r0 * cell
    grid = CellIndex(x0, y0, cell, r1 - r0 + 1, c1 - c0 + 1, np.zeros(0, np.int64), np.zeros(0, np.int64))
    surfaces = provisional_dem(zmin[r0 : r1 + 1, c0 : c1 + 1], **algo.model_dump(exclude={"name"}), threads=threads)
    return grid, surfaces


def _grid_test(algo: SmrfParams, grid: CellIndex | None, surfaces) -> Callable[[np.ndarray], np.ndarray] | None:
    """The point test against the DEM and slope of one grid; None without them (no point is ground)."""
    from stages.classify_ground.smrf import point_test

    if surfaces is None:
        return None
    return partial(
        point_test,
        idx=grid,
        dem=surfaces[0],
        slope_dem=surfaces[1],
        elevation_threshold=algo.elevation_threshold,
        elevation_scalar=algo.elevation_scalar,
    )


def _chunk_classes(xyz, cols, params, test) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Step 3 of :func:`smrf_one_grid` on one chunk: its new classes and :data:`COUNTS`; ``test(xyz)``: ground or not."""
    keep, cand = candidates_of(**cols, params=params)
    ground = np.zeros(len(keep), dtype=bool)
    if test is not None and cand.any():
        ground[cand] = test(xyz[cand])
    cls = new_classes(cols["classification"], keep, ground)
    last = int((cols["return_number"] >= cols["number_of_returns"]).sum())
    return cls, (len(cls), int((cls == glossary.GROUND).sum()), int((cls == glossary.UNCLASSIFIED).sum()), last)


@dataclass(frozen=True)
class RangeTask:
    """Step 3 of :func:`smrf_one_grid` on one range of records, in a worker (:func:`classes_range`).

    *grid*: ``(x0, y0, cell, rows, cols)`` of the filtered grid;
    *surfaces*: its DEM and slope as ``.npy`` files (``dem``, ``slope``);
    *params*: the stage's ``model_dump``.
    """

    records: RecordRange
    params: dict
    grid: tuple[float, float, float, int, int]
    surfaces: dict[str, str]


def classes_range(task: RangeTask) -> list[int]:
    """Step 3 of :func:`smrf_one_grid` on one range of records (runs in a worker); the DEM and slope read from ``.npy`` files."""
    params = ClassifyGroundParams.model_validate(task.params)
    x0, y0, cell, rows, cols = task.grid
    empty = np.zeros(0, np.int64)
    grid = CellIndex(x0, y0, cell, int(rows), int(cols), empty, empty)
    grids = grids_of(task.surfaces)
    test = _grid_test(params.algorithm, grid, (grids["dem"], grids["slope"]))

    def classes(chunk, xyz):
        return _chunk_classes(xyz, classify_columns(chunk), params, test)

    return rewrite_range(task.records, classes, len(COUNTS))


@dataclass(frozen=True)
class WindowsTask:
    """Step 3 of :func:`smrf_one_grid` in windows on one range of records, in a worker (:func:`windows_range`)."""

    records: RecordRange
    params: dict
    windows: Windows


def windows_range(task: WindowsTask) -> list[int]:
    """Step 3 of :func:`smrf_one_grid` in windows on one range of records (runs in a worker)."""
    params = ClassifyGroundParams.model_validate(task.params)
    test = partial(WindowSurfaces(task.windows).ground, algo=params.algorithm)

    def classes(chunk, xyz):
        return _chunk_classes(xyz, classify_columns(chunk), params, test)

    return rewrite_range(task.records, classes, len(COUNTS))
