"""Buildings and vegetation on one grid too large to work on whole: the grid's cells in the tiles' windows.

A survey whose grid has more than ``one_grid_cells`` cells was cut into
tiles of points, each written out with its buffer (2.2 copies of every point
at 500 m tiles and a 123 m reach) and read back.  The cell grids need no
point: pass 1 gathers the cells' statistics of the whole survey
(:func:`stages.classify_objects.one_grid.cell_sums`), :func:`window_tasks`
cuts them into the tiles' windows, each with the tile's buffer in cells and
cut to the box of its points (the grid a tile of points makes), the workers
make each window's cell grids (:func:`object_window`), and pass 2 gives every
point the classes of its own tile's window (:class:`WindowCells`).  The
classes are those of the tiles of points when the tile size and the buffer
are whole numbers of cells (a test checks it).

Cells here are the stage's north-up :class:`~lidar.grid.Grid`: a cell
holds ``x`` in ``[c, c + 1)`` cells and ``y`` in ``(r - 1, r]`` cells, so a
cell is counted by its column ``floor(x / cell)`` and its top
``ceil(y / cell)``.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar.grid import Grid
from lidar.grid_windows import Recent, home_tiles, largest_first, span
from stages.classify_objects.objects import SUMS, ObjectCells, cell_index, object_cells, point_classes, surface_of
from stages.classify_objects.params import ClassifyObjectsParams

if TYPE_CHECKING:
    from pipeline.executor import DaskExecutor, LocalExecutor
    from stages.classify_objects.objects import CellSums


def save_sums(sums: CellSums, folder: Path) -> tuple[int, int]:
    """Save the grid's statistics (:data:`~stages.classify_objects.objects.SUMS`) in *folder* for the windows.

    Returns ``(top, column)`` of the grid's first cell, counted as the
    module says.
    """
    grid = sums.grid
    for name in SUMS:
        np.save(folder / f"{name}.npy", getattr(sums, name).reshape(grid.rows, grid.cols))
    return round(grid.ymax / grid.resolution), round(grid.xmin / grid.resolution)


@dataclass(frozen=True)
class WindowTask:
    """One tile's window of the grid's statistics, in a worker (:func:`object_window`).

    *folder*: the statistics' ``.npy`` files (:func:`save_sums`), whose first
    cell is *corner* ``(top, column)``; *key*: the tile ``(row, col)``;
    *tile*, *buffer*: cells; *cell*: metres; *params*: the stage's dump;
    *weight*: its cells holding points.
    """

    key: tuple[int, int]
    folder: str
    corner: tuple[int, int]
    tile: int
    buffer: int
    cell: float
    params: dict
    multi_echo: bool
    weight: int


def window_tasks(
    count: np.ndarray,
    corner: tuple[int, int],
    tiles: tuple[int, int],
    cell: float,
    params: dict,
    multi_echo: bool,
    folder: Path,
) -> list[WindowTask]:
    """A task for each tile holding points (*count*: the points per cell of the grid whose first cell is *corner*)."""
    tile, buffer = tiles
    rows, cols = count.shape
    top, left = corner
    tasks = []
    for i in range((top - rows) // tile - 1, top // tile + 1):
        for j in range(left // tile, (left + cols - 1) // tile + 1):
            # the tile's points lie in the cells of tops i tile ... (i + 1) tile (one on its lower edge in the
            # first) and of columns j tile ... (j + 1) tile - 1
            own = count[_rows(top, i * tile, (i + 1) * tile, rows), _cols(left, j * tile, (j + 1) * tile - 1, cols)]
            weight = int(np.count_nonzero(own))
            if weight:
                tasks.append(WindowTask((i, j), str(folder), corner, tile, buffer, cell, params, multi_echo, weight))
    return tasks


def _rows(top: int, lo: int, hi: int, rows: int) -> slice:
    """Rows of a grid whose first cell's top is *top*: the cells of tops *lo* to *hi* (ends included), cut to *rows*."""
    return slice(min(max(top - hi, 0), rows), min(max(top - lo + 1, 0), rows))


def _cols(left: int, lo: int, hi: int, cols: int) -> slice:
    """Columns of a grid whose first cell is column *left*: columns *lo* to *hi* (ends included), cut to *cols*."""
    return slice(min(max(lo - left, 0), cols), min(max(hi - left + 1, 0), cols))


def object_window(task: WindowTask) -> tuple[tuple[int, int], tuple[float, float, int, int]]:
    """One window's cell grids (runs in a worker), saved over the tile's own cells; its key and saved grid.

    The window is the tile and its buffer, cut to the box of its cells
    holding points: the grid :func:`~stages.classify_objects.objects.surface`
    makes of a tile's points.  Saved, for the point rule: the
    :class:`~stages.classify_objects.objects.ObjectCells` grids over the
    tile's cells and the row of cells under it (a point on the tile's lower
    edge lies in the cell below it).  Returns the key and the saved grid's
    ``(xmin, ymax, cols, rows)``.
    """
    (i, j), t, b = task.key, task.tile, task.buffer
    sums = {name: np.load(Path(task.folder) / f"{name}.npy", mmap_mode="r") for name in SUMS}
    rows, cols = sums["count"].shape
    r = _rows(task.corner[0], i * t - b + 1, (i + 1) * t + b, rows)
    c = _cols(task.corner[1], j * t - b, (j + 1) * t + b - 1, cols)
    has = np.asarray(sums["count"][r, c]) > 0
    ra, rb = span(has.any(axis=1))
    ca, cb = span(has.any(axis=0))
    r, c = slice(r.start + ra, r.start + rb), slice(c.start + ca, c.start + cb)
    top, left = task.corner[0] - r.start, task.corner[1] + c.start  # the window's first cell
    cell = task.cell
    grid = Grid(float(left * cell), float(top * cell), cell, c.stop - c.start, r.stop - r.start)
    surface = surface_of(grid, **{name: np.array(a[r, c]) for name, a in sums.items()})
    del sums
    cells = object_cells(surface, ClassifyObjectsParams.model_validate(task.params), task.multi_echo)
    del surface
    # the tile's own cells and the row under it, in the window
    keep_r, keep_c = _rows(top, i * t, (i + 1) * t, grid.rows), _cols(left, j * t, (j + 1) * t - 1, grid.cols)
    kept = {f.name: getattr(cells, f.name)[keep_r, keep_c] for f in fields(cells) if f.name != "grid"}
    np.savez(Path(task.folder) / f"{i}_{j}.npz", **kept)
    saved = (
        (left + keep_c.start) * cell,
        (top - keep_r.start) * cell,
        keep_c.stop - keep_c.start,
        keep_r.stop - keep_r.start,
    )
    return task.key, (float(saved[0]), float(saved[1]), int(saved[2]), int(saved[3]))


def object_windows(
    tasks: list[WindowTask], executor: LocalExecutor | DaskExecutor | None
) -> dict[tuple[int, int], tuple[float, float, int, int]]:
    """Run :func:`object_window` on every task (the largest first, on the workers when there are any)."""
    done = largest_first(object_window, tasks, executor)
    return dict(done)


@dataclass(frozen=True)
class Windows:
    """The windows' cell grids, for the point rule (:class:`WindowCells`); small, sent to the workers.

    *size*: the tiles' side (m); *folder*: where :func:`object_window`
    saved them; *grids*: each window's key and saved grid
    ``(row, col, xmin, ymax, cols, rows)``; *cell*: m.
    """

    size: float
    cell: float
    folder: str
    grids: tuple[tuple[int, int, float, float, int, int], ...]


class WindowCells:
    """The classes of usable points by the cell grids of each one's own tile (:func:`point_classes`)."""

    def __init__(self, windows: Windows):
        self.windows = windows
        self.grids = {(i, j): Grid(x, y, windows.cell, c, r) for i, j, x, y, c, r in windows.grids}
        self.recent = Recent()

    def _read(self, key: tuple[int, int]) -> ObjectCells:
        with np.load(Path(self.windows.folder) / f"{key[0]}_{key[1]}.npz") as saved:
            return ObjectCells(self.grids[key], **{name: saved[name] for name in saved.files})

    def classes(self, pts: np.ndarray, cls: np.ndarray, nret: np.ndarray, params: ClassifyObjectsParams) -> np.ndarray:
        """New classes of usable points *pts* (metres) of classes *cls* and numbers of returns *nret*."""
        new = np.asarray(cls, dtype=np.uint8).copy()
        for key, sel in home_tiles(pts[:, 0], pts[:, 1], self.windows.size):
            cells = self.recent.get(key, self._read)
            k = cell_index(pts[sel], cells.grid)
            if (k < 0).any():  # pragma: no cover - each point's cell is in its tile's window by construction
                raise RuntimeError(f"a point of tile {key} lies outside its window's grid {cells.grid}")
            new[sel] = point_classes(cells, k, new[sel], pts[sel, 2], nret[sel], params)[0]
        return new
