"""Buildings and vegetation on one grid of the whole survey, in two passes over its points: no tile, no buffer.

Pass 1 gathers each cell's statistics a chunk at a time (:class:`CellSums`,
on the grid :func:`stages.classify_objects.objects.surface` would make
of all the usable points); the cell grids are made once, whole
(:func:`object_cells`); pass 2 gives each chunk's points their classes
(:func:`point_classes`), in this process or on the workers, a range of
records each (:func:`classes_range`).  The classes are those of
:func:`object_classes` on all the points at once
(docs/stages/classify_objects.md).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar import glossary
from lidar.grid import Grid
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
from stages.classify_objects.object_tiles import COUNTS, class_counts
from stages.classify_objects.objects import SUMS, CellSums, ObjectCells, cell_index, object_cells, point_classes
from stages.classify_objects.params import ClassifyObjectsParams
from stages.classify_objects.windows import (
    WindowCells,
    Windows,
    object_windows,
    save_sums,
    window_tasks,
)

if TYPE_CHECKING:
    from pipeline.executor import DaskExecutor, LocalExecutor
    from pipeline.log import Progress


def _usable(chunk, xyz) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A chunk's classes and usable mask, and its usable points' coordinates and numbers of returns."""
    cls = np.asarray(chunk.classification, dtype=np.uint8)
    usable = glossary.usable(cls, np.asarray(chunk.withheld, dtype=bool))
    nret = np.asarray(chunk.number_of_returns, dtype=np.uint8)[usable]
    if usable.all():
        return cls, usable, xyz, nret
    pts = np.empty((int(usable.sum()), 3), order="F")  # column by column: 3 times faster than xyz[usable]
    for axis in range(3):
        np.compress(usable, xyz[:, axis], out=pts[:, axis])
    return cls, usable, pts, nret


def _box(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lowest and highest x, y of points (infinite without points).

    Column by column: ``min(axis=0)`` of a boolean selection's rows took
    25 ms a million points, this 2 ms.
    """
    if not len(pts):
        return np.full(2, np.inf), np.full(2, -np.inf)
    x, y = pts[:, 0], pts[:, 1]
    return np.array([x.min(), y.min()]), np.array([x.max(), y.max()])


def _usable_box(src: Path, chunk_size: int) -> tuple[float, float, float, float] | None:
    """``(xmin, ymin, xmax, ymax)`` of the usable points; None when there is none."""
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for low, high in las_chunks(src, lambda chunk, xyz: _box(_usable(chunk, xyz)[2]), chunk_size=chunk_size):
        lo, hi = np.minimum(lo, low), np.maximum(hi, high)
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])) if np.isfinite(lo).all() else None


def _gathered(src: Path, grid: Grid, chunk_size: int, progress: Progress | None) -> tuple[CellSums, tuple] | None:
    """Pass 1 on *grid*: the cell sums and the usable points' box; None when a usable point lies off the grid."""
    sums = CellSums(grid)
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)

    def gather(chunk, xyz):
        cls, usable, pts, nret = _usable(chunk, xyz)
        if len(pts):
            k = cell_index(pts, grid)
            if (k < 0).any():
                return None
            sums.add(k, pts[:, 2], nret <= 1, cls[usable] == glossary.GROUND)
        return (*_box(pts), len(chunk))

    for got in las_chunks(src, gather, chunk_size=chunk_size):
        if got is None:
            return None
        lo, hi = np.minimum(lo, got[0]), np.maximum(hi, got[1])
        if progress is not None:
            progress.update(got[2])
    return sums, (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1]))


def cell_sums(
    src: Path,
    extent: tuple[float, float, float, float],
    cell: float,
    cap: int,
    chunk_size: int = 1_000_000,
    progress: Progress | None = None,
) -> CellSums | None:
    """Pass 1: the statistics of every cell on the grid of the usable points; None when it has over *cap* cells.

    The grid is :meth:`Grid.covering` the usable points' box, as
    :func:`~stages.classify_objects.objects.surface` makes it (so the
    cells, and every tie broken on them, are the same).  Tried first on the
    header's *extent*, which the usable points' box mostly gives too; read
    again on the box when it does not (noise or withheld points at the
    edge, a header whose bounds miss points); the box is read first when
    the header's grid is far over *cap* (stray points:
    :func:`~lidar.grid_classes.box_worth_reading`), and None returned
    at once when it is over *cap* but not far.  None also without usable
    points.
    """
    grid = Grid.covering(*extent, cell)
    if grid.rows * grid.cols <= cap:
        got = _gathered(src, grid, chunk_size, progress)
        if got is not None and np.isfinite(got[1]).all() and Grid.covering(*got[1], cell) == grid:
            return got[0]
        box = got[1] if got is not None else _usable_box(src, chunk_size)
    elif box_worth_reading(grid.rows * grid.cols, cap):
        box = _usable_box(src, chunk_size)
    else:  # a survey larger than one grid: tiled
        return None
    if box is None or not np.isfinite(box).all():
        return None
    grid = Grid.covering(*box, cell)
    if grid.rows * grid.cols > cap:
        return None
    got = _gathered(src, grid, chunk_size, None)
    return got[0] if got is not None else None


def _chunk_classes(chunk, xyz, rule) -> tuple[np.ndarray, tuple]:
    """Pass 2 on one chunk: its new classes and :data:`COUNTS`; ``rule(pts, classes, returns)``: the usable points'."""
    cls, usable, pts, nret = _usable(chunk, xyz)
    out = cls.copy()
    if len(pts):
        out[usable] = rule(pts, cls[usable], nret)
    return out, class_counts(out, cls)


def _grid_rule(cells: ObjectCells, params: ClassifyObjectsParams):
    """The point rule on one grid's cells (:func:`point_classes`), for :func:`_chunk_classes`."""
    return lambda pts, cls, nret: point_classes(cells, cell_index(pts, cells.grid), cls, pts[:, 2], nret, params)[0]


def objects_one_grid(
    src: Path,
    dst: Path,
    params: ClassifyObjectsParams,
    cell: float,
    multi_echo: bool,
    *,
    chunk_size: int = 1_000_000,
    progress: Progress | None = None,
    executor: LocalExecutor | DaskExecutor | None = None,
    workdir: Path | None = None,
    tiles: tuple[int, int] | None = None,
) -> dict | None:
    """Buildings and vegetation on one grid of the survey: *src* copied to *dst* with the new classes.

    1. the cells' statistics (:func:`cell_sums`);
    2. the cell grids (:func:`object_cells`), once;
    3. each chunk's classes (:func:`point_classes`), written as it is read;
       with an *executor* of more than one worker (and a *workdir* for the
       grids), on the workers, a range of records each.

    With *tiles* ``(tile, buffer)`` in cells (:func:`~lidar.grid_windows.tile_cells`),
    a grid of more than ``params.one_grid_cells`` cells, up to
    :data:`~lidar.grid_windows.WINDOWED_BEYOND` times that, makes its
    cell grids in the tiles' windows instead, and each point takes its
    tile's (:mod:`stages.classify_objects.windows`).

    Returns :data:`COUNTS`, ``grid`` (its rows and columns) and
    ``windows`` (0: the grid whole), or None (nothing written) when the
    grid is larger or there is no usable point: the caller tiles.
    """
    from lidar.clouds import cloud_info

    info = cloud_info(src)
    records = workers_layout(src, info.count, executor, workdir, chunk_size, classes_range)
    cap = params.one_grid_cells * (WINDOWED_BEYOND if tiles is not None else 1)
    sums = cell_sums(src, info.extent, cell, cap, chunk_size, progress)
    if sums is None:
        return None
    grid, dump = sums.grid, params.model_dump(mode="json")

    write = partial(_pass2, src, dst, records, executor, workdir, chunk_size, progress)
    if tiles is not None and grid.rows * grid.cols > params.one_grid_cells:
        with scratch(workdir, dst, ".objects-windows") as folder:
            corner = save_sums(sums, folder)
            del sums
            windows = _windows(folder, corner, grid, tiles, params, multi_echo, executor)
            rule = partial(WindowCells(windows).classes, params=params)
            numbers = write(rule, {}, lambda r, _: WindowsTask(records=r, params=dump, windows=windows), windows_range)
        made = len(windows.grids)
    else:
        cells = object_cells(sums.surface(), params, multi_echo)
        del sums
        numbers = write(
            _grid_rule(cells, params),
            {f.name: getattr(cells, f.name) for f in fields(cells) if f.name != "grid"},
            lambda r, paths: RangeTask(records=r, params=dump, grid=_dump(cells.grid), grids=paths),
            classes_range,
        )
        made = 0
    return {**dict(zip(COUNTS, numbers, strict=True)), "grid": (grid.rows, grid.cols), "windows": made}


def _pass2(src, dst, records, executor, workdir, chunk_size, progress, rule, grids, task, run) -> list[int]:
    """Pass 2 of :func:`objects_one_grid` by ``rule(pts, classes, returns)``: :func:`~lidar.grid_classes.write_classes`
    of its classes, on the workers when *records* allows (*grids*, *task*, *run*: theirs), else here."""
    return write_classes(
        src,
        dst,
        records,
        executor,
        classes=lambda chunk, xyz: _chunk_classes(chunk, xyz, rule),
        width=len(COUNTS),
        folder=Path(workdir) / ".objects-one-grid" if workdir is not None else None,
        grids=grids,
        task=task,
        run=run,
        chunk_size=chunk_size,
        what="classes",
        progress=progress,
    )


def _windows(folder, corner, grid, tiles, params, multi_echo, executor) -> Windows:
    """Step 2 of :func:`objects_one_grid` in the tiles' windows: each window's cell grids, made on the workers.

    From the statistics saved in *folder* (:func:`~stages.classify_objects.windows.save_sums`,
    first cell *corner*), which are removed after.
    """
    cell = grid.resolution
    count = np.load(folder / "count.npy", mmap_mode="r")
    tasks = window_tasks(count, corner, tiles, cell, params.model_dump(mode="json"), multi_echo, folder)
    del count
    saved = object_windows(tasks, executor)
    for name in SUMS:
        (folder / f"{name}.npy").unlink()
    return Windows(tiles[0] * cell, cell, str(folder), tuple((*key, *g) for key, g in sorted(saved.items())))


def _dump(grid: Grid) -> tuple[float, float, float, int, int]:
    return grid.xmin, grid.ymax, grid.resolution, grid.cols, grid.rows


@dataclass(frozen=True)
class RangeTask:
    """Pass 2 of :func:`objects_one_grid` on one range of records, in a worker (:func:`classes_range`).

    *grid*: ``(xmin, ymax, cell, cols, rows)``; *grids*: the
    :class:`ObjectCells` grids as ``.npy`` files by name; *params*: the
    stage's ``model_dump``.
    """

    records: RecordRange
    params: dict
    grid: tuple[float, float, float, int, int]
    grids: dict[str, str]


def classes_range(task: RangeTask) -> list[int]:
    """Pass 2 of :func:`objects_one_grid` on one range of records (runs in a worker)."""
    params = ClassifyObjectsParams.model_validate(task.params)
    xmin, ymax, cell, cols, rows = task.grid
    cells = ObjectCells(Grid(xmin, ymax, cell, int(cols), int(rows)), **grids_of(task.grids))
    rule = _grid_rule(cells, params)
    return rewrite_range(task.records, lambda chunk, xyz: _chunk_classes(chunk, xyz, rule), len(COUNTS))


@dataclass(frozen=True)
class WindowsTask:
    """Pass 2 of :func:`objects_one_grid` in windows on one range of records, in a worker (:func:`windows_range`)."""

    records: RecordRange
    params: dict
    windows: Windows


def windows_range(task: WindowsTask) -> list[int]:
    """Pass 2 of :func:`objects_one_grid` in windows on one range of records (runs in a worker)."""
    params = ClassifyObjectsParams.model_validate(task.params)
    rule = partial(WindowCells(task.windows).classes, params=params)
    return rewrite_range(task.records, lambda chunk, xyz: _chunk_classes(chunk, xyz, rule), len(COUNTS))
