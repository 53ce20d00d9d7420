"""SMRF on one grid too large to filter whole: the grid filtered in windows, the points tested in passes.

A survey whose grid has more than ``one_grid_cells`` cells was cut into
tiles of points, each written out with its buffer (2.5 copies of every point
at 500 m tiles and SMRF's 146 m reach) and read back.  But SMRF's grid steps
need no point: :func:`filter_windows` cuts the grid of the lowest candidates
(:func:`stages.classify_ground.streaming.lowest_grid`, one pass over the
points) into the tiles' windows, each with the tile's buffer in cells, and
filters each window on the workers; :class:`WindowSurfaces` then tests every
point against the provisional DEM of the window of its own tile, a chunk at
a time.  Each window is the grid a tile of points would make (the box of its
candidates, anchored on whole cells), so the classes are those of the tiles
when the tile size and the buffer are whole numbers of cells (a test checks
it); otherwise the buffer is rounded up to whole cells.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar.grid_windows import Recent, home_tiles, largest_first, span
from stages.classify_ground.params import SmrfParams
from stages.classify_ground.surface import CellIndex

if TYPE_CHECKING:
    from pipeline.executor import DaskExecutor, LocalExecutor


@dataclass(frozen=True)
class WindowTask:
    """One window of the grid of lowest candidates, filtered in a worker (:func:`filter_window`).

    *zmin*: the grid's ``.npy`` file, whose cell ``[0, 0]`` is the cell
    *origin* ``(row, col)`` counted from 0, 0 in whole cells; *core*: the
    tile's rows and columns ``(r0, r1, c0, c1)``, ends excluded, in the same
    count; *buffer*: cells around the core; *out*: the ``.npy`` file of its
    DEM and slope; *weight*: its cells with a candidate.
    """

    key: tuple[int, int]
    zmin: str
    origin: tuple[int, int]
    core: tuple[int, int, int, int]
    buffer: int
    algorithm: dict
    out: str
    weight: int


def window_tasks(
    zmin: np.ndarray, origin: tuple[int, int], tile: int, buffer: int, algorithm: SmrfParams, folder: Path
) -> list[WindowTask]:
    """A task for each tile of *tile* x *tile* cells that holds a candidate (a value in *zmin*) of its own.

    Tiles are counted from cell 0, 0, as the engine's tiles are counted from
    0 m: tile ``(i, j)`` holds rows ``i tile`` to ``(i + 1) tile``.
    """
    rows, cols = zmin.shape
    r_first, c_first = origin[0] // tile, origin[1] // tile
    tasks = []
    for i in range(r_first, (origin[0] + rows - 1) // tile + 1):
        for j in range(c_first, (origin[1] + cols - 1) // tile + 1):
            r0, c0 = i * tile, j * tile
            mine = zmin[max(r0 - origin[0], 0) : r0 + tile - origin[0], max(c0 - origin[1], 0) : c0 + tile - origin[1]]
            weight = int(np.count_nonzero(~np.isnan(mine)))
            if weight:
                tasks.append(
                    WindowTask(
                        key=(i, j),
                        zmin=str(folder / "zmin.npy"),
                        origin=origin,
                        core=(r0, r0 + tile, c0, c0 + tile),
                        buffer=buffer,
                        algorithm=algorithm.model_dump(mode="json"),
                        out=str(folder / f"{i}_{j}.npy"),
                        weight=weight,
                    )
                )
    return tasks


def filter_window(task: WindowTask) -> tuple[tuple[int, int], tuple[int, int]] | None:
    """SMRF's grid steps on one window (runs in a worker): its DEM and slope around the core, saved.

    The window is the tile's core plus its buffer, cut to the box of its
    candidates (the grid :func:`~stages.classify_ground.surface.index_points`
    makes of a tile's candidates).  Saved: DEM and slope, stacked, over the
    core and one cell around it (all the point test of the core's points
    reads), cut to that box.  Returns the key and the saved grid's first
    ``(row, col)`` in whole cells; None when the filter leaves no cell.
    """
    from stages.classify_ground.smrf import provisional_dem

    algo = SmrfParams.model_validate(task.algorithm)
    zmin = np.load(task.zmin, mmap_mode="r")
    (o_r, o_c), (r0, r1, c0, c1), b = task.origin, task.core, task.buffer
    rows = slice(max(r0 - b - o_r, 0), max(min(r1 + b - o_r, zmin.shape[0]), 0))
    cols = slice(max(c0 - b - o_c, 0), max(min(c1 + b - o_c, zmin.shape[1]), 0))
    window = np.array(zmin[rows, cols])
    del zmin
    has = ~np.isnan(window)
    ra, rb = span(has.any(axis=1))
    ca, cb = span(has.any(axis=0))
    window = window[ra:rb, ca:cb]
    top, left = o_r + rows.start + ra, o_c + cols.start + ca  # the window's first cell, in whole cells
    surfaces = provisional_dem(window, **algo.model_dump(exclude={"name"}))
    if surfaces is None:
        return None
    keep_r = slice(max(r0 - 1 - top, 0), max(min(r1 + 1 - top, window.shape[0]), 0))
    keep_c = slice(max(c0 - 1 - left, 0), max(min(c1 + 1 - left, window.shape[1]), 0))
    np.save(task.out, np.stack([s[keep_r, keep_c] for s in surfaces]))
    return task.key, (top + keep_r.start, left + keep_c.start)


def filter_windows(
    tasks: list[WindowTask], executor: LocalExecutor | DaskExecutor | None
) -> dict[tuple[int, int], tuple[int, int]]:
    """Run :func:`filter_window` on every task (the largest first, on the workers when there are any).

    Returns each filtered window's key and first cell; a window the filter
    left without a DEM is absent (its points are not ground).
    """
    done = largest_first(filter_window, tasks, executor)
    return {key: first for key, first in (d for d in done if d is not None)}


@dataclass(frozen=True)
class Windows:
    """The filtered windows of a grid, for the point test (:class:`WindowSurfaces`); small, sent to workers.

    *cell*: the cell (m); *tile*: cells on a tile's side; *folder*: where
    :func:`filter_window` saved them; *first*: each window's key and first
    ``(row, col)`` in whole cells.
    """

    cell: float
    tile: int
    folder: str
    first: tuple[tuple[int, int, int, int], ...]


class WindowSurfaces:
    """The point test against the DEM of each point's own tile (:func:`~stages.classify_ground.smrf.point_test`)."""

    def __init__(self, windows: Windows):
        self.windows = windows
        self.first = {(i, j): (r, c) for i, j, r, c in windows.first}
        self.recent = Recent()

    def window(self, key: tuple[int, int]) -> tuple[CellIndex, np.ndarray] | None:
        """The grid and the stacked DEM and slope of the tile *key*'s window; None when it has none."""
        return self.recent.get(key, self._read) if key in self.first else None

    def _read(self, key: tuple[int, int]) -> tuple[CellIndex, np.ndarray]:
        r, c = self.first[key]
        grids = np.load(Path(self.windows.folder) / f"{key[0]}_{key[1]}.npy", mmap_mode="r")
        cell = self.windows.cell
        empty = np.zeros(0, np.int64)
        # the corner as grid_corner makes it: a whole number of cells times the cell
        return CellIndex(float(c * cell), float(r * cell), cell, grids.shape[1], grids.shape[2], empty, empty), grids

    def ground(self, xyz: np.ndarray, algo: SmrfParams) -> np.ndarray:
        """True where a point is ground by its tile's DEM; False where its tile has none."""
        from stages.classify_ground.smrf import point_test

        out = np.zeros(len(xyz), dtype=bool)
        for key, where in home_tiles(xyz[:, 0], xyz[:, 1], self.windows.tile * self.windows.cell):
            window = self.window(key)
            if window is not None:
                index, grids = window
                out[where] = point_test(
                    xyz[where],
                    index,
                    grids[0],
                    grids[1],
                    elevation_threshold=algo.elevation_threshold,
                    elevation_scalar=algo.elevation_scalar,
                )
        return out
