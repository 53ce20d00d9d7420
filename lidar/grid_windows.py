"""A survey's grid cut into the engine's tiles as windows: the tiles' cells, and each point's tile.

A stage that works on one grid of the whole survey can filter a grid too
large to work on whole in the windows of the run's tiles (each tile plus
its buffer, in cells) and give each point the result of its own tile's
window: what the stage would do on tiles of points, without writing any
point twice (:mod:`stages.classify_ground.windows`,
:mod:`stages.classify_objects.windows`).  The tiles are those of
:class:`pipeline.tiling.Layout`: squares of ``size`` counted from 0 m.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

#: A grid worked in windows may have this many times a stage's ``one_grid_cells``; beyond, tiles of points.
WINDOWED_BEYOND = 4


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


def run_tile_cells(config, reach: float, cell: float) -> tuple[int, int] | None:
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


def largest_first(fn, tasks: list, executor) -> list:
    """``fn`` of every window task, the largest (``weight``) first, on the workers when there are any."""
    order = sorted(tasks, key=lambda t: -t.weight)
    if executor is None or executor.workers <= 1:
        return [fn(t) for t in order]
    return executor.map(fn, order, what="windows")


def note_windows(ctx, what: str, whole: dict, tiles: tuple[int, int], cell: float) -> None:
    r"""The stage's ``tiling`` metrics and log line for a grid worked in *whole*\ ``["windows"]`` windows."""
    ctx.metrics["tiling"] = {  # the grid in the tiles' windows, no tile of points
        "tiles": whole["windows"],
        "size": tiles[0] * cell,
        "buffer": tiles[1] * cell,
        "executor": f"one grid in windows, {ctx.executor.describe()}",
        "grid": list(whole["grid"]),
    }
    ctx.log.info(
        "%s on one grid of %d x %d cells of %g m, in %d windows of %g with a buffer of %g",
        what,
        *whole["grid"],
        cell,
        whole["windows"],
        tiles[0] * cell,
        tiles[1] * cell,
    )


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
