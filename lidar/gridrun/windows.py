"""A survey's grid worked in the windows of the engine's tiles: what the tiles of points would give, no point written twice.

The grid's statistics are saved once (:func:`save_statistics`); each tile
that holds gathered points of its own gets a window (:func:`window_tasks`):
its cells and its buffer in whole cells, cut to the box of the cells that
hold points, the grid a tile of points makes.  The workers compute each
window (:func:`run_window`) and save its results over the tile's own cells
and the kernel's margin; pass 2 gives every point the results of its own
tile's window (:class:`WindowResults`).  The tiles are those of
:class:`pipeline.tiling.Layout`: squares of ``size`` counted from 0 m; a
point's tile is where its core holds it.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lidar.gridrun.kernel import Frame, GridKernel
from lidar.gridrun.passes import Lookup
from pipeline.log import stage_progress


def tile_cells(size: float | None, buffer: float, cell: float) -> tuple[int, int] | None:
    """``(tile, buffer)`` in whole cells for tiles of *size* (m) with *buffer* (m); None when a tile is not whole cells.

    The buffer is rounded up to whole cells.  None too without tiles (*size* None).
    """
    if size is None:
        return None
    tile = size / cell
    if not math.isclose(tile, round(tile), rel_tol=0, abs_tol=1e-9) or round(tile) < 1:
        return None
    return round(tile), math.ceil(buffer / cell - 1e-9)


def run_tile_cells(config: Any, reach: float, cell: float) -> tuple[int, int] | None:
    """:func:`tile_cells` of a run's ``tiling`` block (its buffer, or the stage's *reach*, m); None without tiles."""
    tiling = getattr(config, "tiling", None)
    if tiling is None or not tiling.enabled:
        return None
    return tile_cells(tiling.size, float(tiling.buffer) if tiling.buffer is not None else reach, cell)


def home_tiles(x: np.ndarray, y: np.ndarray, size: float) -> Iterator[tuple[tuple[int, int], np.ndarray]]:
    """``((row, col), indices)`` of the tile holding each point, as :meth:`pipeline.tiling.Layout.locate` finds it.

    Tile ``(i, j)`` holds ``y`` in ``[i size, (i + 1) size)`` and ``x`` in
    ``[j size, (j + 1) size)``; the points of each tile, in their order.
    """
    if not len(x):
        return
    i = np.floor(np.asarray(y) / size).astype(np.int64)
    j = np.floor(np.asarray(x) / size).astype(np.int64)
    i0, j0 = int(i.min()), int(j.min())
    span = int(j.max()) - j0 + 1
    key = (i - i0) * span + (j - j0)
    for k in np.unique(key):
        yield (i0 + int(k) // span, j0 + int(k) % span), np.flatnonzero(key == k)


def span(has: np.ndarray) -> tuple[int, int]:
    """First and past-last index where *has* is True (it must be somewhere)."""
    where = np.flatnonzero(has)
    return int(where[0]), int(where[-1]) + 1


def occupied_box(occupied: np.ndarray) -> tuple[slice, slice] | None:
    """The rows and columns of the box of the True cells of *occupied*; None when there is none."""
    if not occupied.any():
        return None
    ra, rb = span(occupied.any(axis=1))
    ca, cb = span(occupied.any(axis=0))
    return slice(ra, rb), slice(ca, cb)


def save_statistics(stats: dict[str, np.ndarray], frame: Frame, folder: Path) -> None:
    """The grid's statistics saved in *folder* (``<name>.npy``, in the frame's shape) for the windows."""
    for name, values in stats.items():
        np.save(folder / f"{name}.npy", values.reshape(frame.shape))


@dataclass(frozen=True)
class WindowTask:
    """One tile's window of the grid (:func:`run_window`, in a worker).

    *key*: the tile ``(row, col)`` (rows along y); *folder*: the saved
    statistics (:func:`save_statistics`) on *frame*; *tile*, *buffer*:
    cells; *weight*: the tile's own cells holding points.
    """

    kernel: GridKernel
    key: tuple[int, int]
    folder: str
    frame: Frame
    tile: int
    buffer: int
    weight: int


def _tile_of(frame: Frame, key: tuple[int, int]) -> tuple[int, int]:
    """The tile's index along each of the frame's axes."""
    return tuple(key[0] if axis.coord == 1 else key[1] for axis in frame.axes)


def window_tasks(
    kernel: GridKernel, frame: Frame, occupied: np.ndarray, tiles: tuple[int, int], folder: Path
) -> list[WindowTask]:
    """A task for each tile of *tiles* ``(tile, buffer)`` cells whose own cells hold points (*occupied*)."""
    tile, buffer = tiles
    a, b = frame.axes
    tasks = []
    for ta in a.tiles(frame.first[0], frame.shape[0], tile):
        rows = a.span(frame.first[0], frame.shape[0], *a.own(ta, tile))
        for tb in b.tiles(frame.first[1], frame.shape[1], tile):
            cols = b.span(frame.first[1], frame.shape[1], *b.own(tb, tile))
            weight = int(np.count_nonzero(occupied[rows, cols]))
            if weight:
                key = (ta, tb) if a.coord == 1 else (tb, ta)
                tasks.append(WindowTask(kernel, key, str(folder), frame, tile, buffer, weight))
    return tasks


def run_window(task: WindowTask) -> tuple[tuple[int, int], Frame] | None:
    """One window's results (runs in a worker), saved over the tile's own cells and the kernel's margin.

    Returns the key and the frame of what was saved; None when the window
    has no results, or none that changes a class (its points then get
    what the kernel gives without results).
    """
    kernel, frame, t, b = task.kernel, task.frame, task.tile, task.buffer
    stats = {p.stem: np.load(p, mmap_mode="r") for p in sorted(Path(task.folder).glob("*.npy"))}
    (ta, tb), (a, c) = _tile_of(frame, task.key), frame.axes
    rows = a.span(frame.first[0], frame.shape[0], *a.window(ta, t, b))
    cols = c.span(frame.first[1], frame.shape[1], *c.window(tb, t, b))
    inner = occupied_box(kernel.occupied({name: s[rows, cols] for name, s in stats.items()}))
    rows = slice(rows.start + inner[0].start, rows.start + inner[0].stop)
    cols = slice(cols.start + inner[1].start, cols.start + inner[1].stop)
    window = frame.cut(rows, cols)
    results = kernel.window({name: np.array(s[rows, cols]) for name, s in stats.items()}, window)
    del stats
    if results is None or kernel.unchanged(results):
        return None
    m = kernel.margin
    (lo_a, hi_a), (lo_c, hi_c) = a.own(ta, t), c.own(tb, t)
    keep = (
        a.span(window.first[0], window.shape[0], lo_a - m, hi_a + m),
        c.span(window.first[1], window.shape[1], lo_c - m, hi_c + m),
    )
    np.savez(Path(task.folder) / f"{task.key[0]}_{task.key[1]}.npz", **{n: r[keep] for n, r in results.items()})
    return task.key, window.cut(*keep)


def largest_first(fn, tasks: list, executor) -> list:
    """``fn`` of every window task, the largest (``weight``) first, on the workers when there are any."""
    order = sorted(tasks, key=lambda t: -t.weight)
    with stage_progress(sum(t.weight for t in order), "grid in windows", unit="cells") as bar:
        if executor is None or executor.workers <= 1:
            out = []
            for t in order:
                out.append(fn(t))
                bar.update(t.weight)
            return out
        return executor.map(fn, order, what="windows", done=lambda t: bar.update(t.weight))


@dataclass(frozen=True)
class Windows:
    """The saved windows of a grid, for pass 2 (:class:`WindowResults`); small, sent to the workers.

    *size*: the tiles' side (m); *folder*: where :func:`run_window` saved
    them; *frames*: each window's key and the frame of its saved results
    (a window without results, or none that changes a class, has none);
    *worked*: how many windows were worked.
    """

    size: float
    folder: str
    frames: tuple[tuple[tuple[int, int], Frame], ...]
    worked: int = 0

    def lookup(self) -> WindowResults:
        return WindowResults(self)


def run_windows(
    kernel: GridKernel, frame: Frame, stats: dict[str, np.ndarray], tiles: tuple[int, int], folder: Path, executor
) -> Windows:
    """The grid's windows computed (on the workers when there are any) and saved in *folder*.

    The statistics are saved there for the workers (:func:`save_statistics`)
    and removed once the windows are made.
    """
    save_statistics(stats, frame, folder)
    occupied = kernel.occupied({name: s.reshape(frame.shape) for name, s in stats.items()})
    tasks = window_tasks(kernel, frame, occupied, tiles, folder)
    del occupied
    done = [d for d in largest_first(run_window, tasks, executor) if d is not None]
    for name in stats:
        (folder / f"{name}.npy").unlink()
    return Windows(tiles[0] * frame.cell, str(folder), tuple(sorted(done)), len(tasks))


class Recent:
    """The last few windows read (a chunk of points in flight order crosses a few tiles): ``get(key, read)``."""

    def __init__(self, keep: int = 8):
        self.keep = keep
        self.items: dict = {}

    def get(self, key, read):
        if key not in self.items:
            if len(self.items) >= self.keep:
                del self.items[next(iter(self.items))]
            self.items[key] = read(key)
        return self.items[key]


class WindowResults(Lookup):
    """The values of points by the results of each one's own tile's window (:meth:`GridKernel.values`)."""

    def __init__(self, windows: Windows):
        self.windows = windows
        self.frames = dict(windows.frames)
        self.recent = Recent()

    def _read(self, key: tuple[int, int]) -> dict[str, np.ndarray]:
        with np.load(Path(self.windows.folder) / f"{key[0]}_{key[1]}.npz") as saved:
            return {name: saved[name] for name in saved.files}

    def values(self, kernel: GridKernel, xyz: np.ndarray, cols: dict[str, np.ndarray]) -> np.ndarray:
        out = None
        for key, sel in home_tiles(xyz[:, 0], xyz[:, 1], self.windows.size):
            frame = self.frames.get(key)
            results = self.recent.get(key, self._read) if frame is not None else None
            got = kernel.values(xyz[sel], {n: c[sel] for n, c in cols.items()}, results, frame)
            if out is None:
                out = np.empty(len(xyz), dtype=got.dtype)
            out[sel] = got
        return out if out is not None else kernel.values(xyz, cols, None, None)


@contextmanager
def scratch(workdir: Path | None, beside: Path, name: str) -> Iterator[Path]:
    """A fresh folder for a grid's windows: ``workdir/name``, or a temporary one beside the file *beside*; removed after."""
    folder = Path(workdir) / name if workdir is not None else Path(tempfile.mkdtemp(dir=Path(beside).parent))
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    try:
        yield folder
    finally:
        shutil.rmtree(folder, ignore_errors=True)
