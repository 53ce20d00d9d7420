"""Tiles with buffers: cutting a plane extent into square tasks.

The engine knows nothing about what lies on the plane.  A stage that works
tile by tile gives :func:`run_tiled` its extent, the buffer its algorithm
needs, and three functions: ``split`` (make each tile's task from the input:
the items inside the tile plus its buffer), ``task`` (a module-level
function run by the executor on one task: small arguments, paths, and a
small result) and ``merge`` (assemble the results, keeping each tile's core
only).  Tiles are squares aligned on multiples of their size, so the tiles
of neighbouring jobs line up; each point of the plane belongs to the core
of exactly one tile (cores are closed at their low edges, open at their high
edges).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import ConfigError
from pipeline.executor import LocalExecutor, thread_map

#: Most tiles one layout may have: the tile list and the tasks are made in memory.
MAX_TILES = 100_000
#: Most tiles a point may fall in (core plus buffers): ``((size + 2 buffer) / size)**2``.
MAX_COPIES = 100.0


@dataclass(frozen=True)
class Tile:
    """One tile: its index in the layout and its core rectangle."""

    index: int
    col: int
    row: int
    xmin: float
    ymin: float
    xmax: float
    ymax: float


@dataclass(frozen=True)
class Layout:
    """Square tiles of side ``size`` over an extent; ``size`` None = a single tile.

    Tile ``(col, row)`` covers ``[(c0 + col) size, (c0 + col + 1) size)`` in x
    and likewise in y (rows grow northwards here).
    """

    extent: tuple[float, float, float, float]
    size: float | None
    buffer: float
    c0: int = 0
    r0: int = 0
    cols: int = 1
    rows: int = 1

    @classmethod
    def of(cls, extent: Sequence[float], size: float | None, buffer: float) -> Layout:
        """The layout covering *extent* (xmin, ymin, xmax, ymax).

        Raises
        ------
        ConfigError
            Before any tile is made, when the layout would have more than
            :data:`MAX_TILES` tiles or put a point in more than
            :data:`MAX_COPIES` tiles (a buffer wide for its tile size), or
            when the size or buffer is not a finite positive length.
        """
        xmin, ymin, xmax, ymax = (float(v) for v in extent)
        if not math.isfinite(buffer) or buffer < 0:
            raise ConfigError(f"tiling.buffer: {buffer:g} is not a finite length >= 0.")
        if size is None:
            return cls((xmin, ymin, xmax, ymax), None, float(buffer))
        if not (math.isfinite(size) and size > 0):
            raise ConfigError(f"tiling.size: {size:g} is not a finite length > 0.")
        copies = ((size + 2 * buffer) / size) ** 2
        if copies > MAX_COPIES:
            least = 2 * buffer / (math.sqrt(MAX_COPIES) - 1)
            raise ConfigError(
                f"tiling.size: tiles of {size:g} m with a buffer of {buffer:g} m put every point in {copies:.0f} "
                f"tiles, more than {MAX_COPIES:g}; use tiles of at least {math.ceil(least):g} m (or a smaller "
                "tiling.buffer)."
            )
        c0, r0, cols, rows = _grid(xmin, ymin, xmax, ymax, size)
        if cols * rows > MAX_TILES:
            least = max(size, math.sqrt((xmax - xmin) * (ymax - ymin) / MAX_TILES))
            while math.prod(_grid(xmin, ymin, xmax, ymax, least)[2:]) > MAX_TILES:
                least *= 1.002
            raise ConfigError(
                f"tiling.size: tiles of {size:g} m cut the extent of {xmax - xmin:.0f} m x {ymax - ymin:.0f} m "
                f"into {cols * rows:,} tiles, more than {MAX_TILES:,}; use tiles of at least {math.ceil(least):g} m."
            )
        return cls((xmin, ymin, xmax, ymax), float(size), float(buffer), c0, r0, cols, rows)

    def __len__(self) -> int:
        return self.cols * self.rows

    @property
    def tiles(self) -> list[Tile]:
        if self.size is None:
            return [Tile(0, 0, 0, *self.extent)]
        s = self.size
        return [
            Tile(
                r * self.cols + c,
                c,
                r,
                (self.c0 + c) * s,
                (self.r0 + r) * s,
                (self.c0 + c + 1) * s,
                (self.r0 + r + 1) * s,
            )
            for r in range(self.rows)
            for c in range(self.cols)
        ]

    def _cells(self, v: np.ndarray, origin: int, count: int, shift: float) -> np.ndarray:
        return np.clip(
            np.floor((np.asarray(v, dtype=np.float64) + shift) / self.size).astype(np.int64) - origin, -1, count
        )

    def locate(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Index of the tile whose core holds each point (-1 outside the layout)."""
        if self.size is None:
            return np.zeros(len(x), dtype=np.int64)
        c = self._cells(x, self.c0, self.cols, 0.0)
        r = self._cells(y, self.r0, self.rows, 0.0)
        inside = (c >= 0) & (c < self.cols) & (r >= 0) & (r < self.rows)
        return np.where(inside, r * self.cols + c, -1)

    def memberships(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every (point, tile) pair with the point inside the tile's core plus buffer.

        Returns
        -------
        point, tile : ndarray of int64
            Pairs sorted by tile, then by point.
        """
        n = len(x)
        if self.size is None:
            return np.arange(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
        b = self.buffer
        # Tile i holds x in [lo_i - b, hi_i + b): i from floor((x - b) / s) to floor((x + b) / s).
        c_lo, c_hi = self._cells(x, self.c0, self.cols, -b), self._cells(x, self.c0, self.cols, b)
        r_lo, r_hi = self._cells(y, self.r0, self.rows, -b), self._cells(y, self.r0, self.rows, b)
        points, tiles = [], []
        c_first, c_last = max(int(c_lo.min(initial=0)), 0), min(int(c_hi.max(initial=-1)), self.cols - 1)
        r_first, r_last = max(int(r_lo.min(initial=0)), 0), min(int(r_hi.max(initial=-1)), self.rows - 1)
        if (c_last - c_first + 1) * (r_last - r_first + 1) <= 16:
            # Few tiles around these points (a chunk of a file in flight order): one
            # mask per tile gives its points already in order, without a sort.
            for r in range(r_first, r_last + 1):
                rok = (r_lo <= r) & (r <= r_hi)
                for c in range(c_first, c_last + 1):
                    sel = np.flatnonzero(rok & (c_lo <= c) & (c <= c_hi))
                    points.append(sel)
                    tiles.append(np.full(len(sel), r * self.cols + c, dtype=np.int64))
            if not points:
                return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
            return np.concatenate(points), np.concatenate(tiles)
        for dc in range(int((c_hi - c_lo).max(initial=0)) + 1):
            c = c_lo + dc
            cok = (c <= c_hi) & (c >= 0) & (c < self.cols)
            for dr in range(int((r_hi - r_lo).max(initial=0)) + 1):
                r = r_lo + dr
                ok = cok & (r <= r_hi) & (r >= 0) & (r < self.rows)
                sel = np.flatnonzero(ok)
                points.append(sel)
                tiles.append(r[sel] * self.cols + c[sel])
        point = np.concatenate(points) if points else np.zeros(0, dtype=np.int64)
        tile = np.concatenate(tiles) if tiles else np.zeros(0, dtype=np.int64)
        key = np.sort(tile * max(n, 1) + point)  # one integer sort: by tile, then by point
        return key % max(n, 1), key // max(n, 1)


def _grid(xmin: float, ymin: float, xmax: float, ymax: float, size: float) -> tuple[int, int, int, int]:
    """First column and row, and how many, of the tiles of side *size* that cover the extent."""
    c0, r0 = math.floor(xmin / size), math.floor(ymin / size)
    return c0, r0, math.floor(xmax / size) - c0 + 1, math.floor(ymax / size) - r0 + 1


def layout_for(config: Any, extent: Sequence[float], buffer: float) -> Layout:
    """The layout the configuration's ``tiling`` block asks for (a single tile when disabled)."""
    tiling = getattr(config, "tiling", None)
    if tiling is None or not tiling.enabled:
        return Layout.of(extent, None, buffer)
    if tiling.buffer is not None:
        buffer = float(tiling.buffer)
    return Layout.of(extent, tiling.size, buffer)


@dataclass(frozen=True)
class TileMemo:
    """How a stage keeps the results of its tiles for later runs (:class:`pipeline.cache.TileCache`).

    ``key(task)``: JSON-ready material of everything the task's result
    depends on besides the stage's settings (the files it reads as their
    SHA-256; nothing that depends on other tiles, such as positions in the
    whole survey).  ``save(task, result, folder)``: copy the task's outputs
    into *folder* and return the JSON-ready result to keep.  ``load(task,
    folder, kept)``: write the task's outputs from *folder* as the task would
    have, and return its result.
    """

    key: Callable[[Any], Any]
    save: Callable[[Any, Any, Path], Any]
    load: Callable[[Any, Path, Any], Any]


def run_tiled(
    ctx: Any,
    *,
    extent: Sequence[float],
    buffer: float,
    split: Callable[[Layout], list[Any]],
    task: Callable[[Any], Any],
    merge: Callable[[Layout, list[Any], list[Any]], Any],
    what: str = "tiles",
    weight: float | None = None,
    memo: TileMemo | None = None,
) -> Any:
    """Run a stage's work tile by tile on the run's executor; the value of *merge*.

    *ctx* gives the configuration, the executor and the log; *extent*
    ``(xmin, ymin, xmax, ymax)`` is what the tiles cover; *buffer* is the
    margin each task needs around its tile (its algorithm's reach) unless
    ``tiling.buffer`` is set.  ``split(layout)`` returns one small task per
    tile that holds something (a small dataclass of paths and parameters,
    never arrays, whose optional ``weight`` runs the largest first); *task*, a
    module-level function, runs each one (in another process or on a Dask
    worker); ``merge(layout, tasks, results)`` gets the results in the tasks'
    order.  *weight*, the whole work's in the tasks' unit, lets a light stage
    run in this process (:func:`_runs_here`); the results are the same.
    With a *memo* and the run's tile cache (``ctx.tile_cache``), a tile whose
    task reads what a tile of an earlier run read is not run again
    (:func:`_reusing`).
    """
    executor, here = ctx.executor, _runs_here(ctx.config, weight)
    if here:
        ctx.executor = LocalExecutor(1)  # the split, the tasks: all here, no worker started
    where = f"this process (work {weight:,.0f}, below executor.in_process_below)" if here else executor.describe()
    try:
        layout = layout_for(ctx.config, extent, buffer)
        ctx.metrics["tiling"] = {
            "extent": [round(v, 3) for v in layout.extent],
            "tiles": len(layout),
            "size": layout.size,
            "buffer": layout.buffer,
            "executor": where,
        }
        if len(layout) > 1:
            ctx.executor.prepare(task, len(layout))  # workers start while the tasks are being made
        tasks = split(layout)
        ctx.metrics["tiling"]["tasks"] = len(tasks)
        if len(layout) > 1:
            ctx.log.info(
                "%d tiles of %g m with a buffer of %g m (%d hold data) on %s",
                len(layout),
                layout.size,
                layout.buffer,
                len(tasks),
                where,
            )
        cache = getattr(ctx, "tile_cache", None) if memo is not None else None
        if cache is None:
            results = map_largest_first(ctx, task, tasks, what)
        else:
            results = _reusing(ctx, cache, memo, task, tasks, what)
        return merge(layout, tasks, results)
    finally:
        ctx.executor = executor


def _reusing(ctx: Any, cache: Any, memo: TileMemo, task: Callable[[Any], Any], tasks: list[Any], what: str) -> list:
    """Run the *tasks* whose results the tile *cache* does not hold, keep theirs, load the others'."""

    keys = thread_map(lambda t: cache.key(memo.key(t)), tasks, max(int(getattr(ctx, "workers", 1)), 1))
    kept = [cache.get(k) for k in keys]
    results: list[Any] = [None if k is None else memo.load(t, *k) for t, k in zip(tasks, kept, strict=True)]
    todo = [i for i, k in enumerate(kept) if k is None]
    for i, result in zip(todo, map_largest_first(ctx, task, [tasks[i] for i in todo], what), strict=True):
        results[i] = result
        cache.put(keys[i], partial(memo.save, tasks[i], result))
    ctx.metrics["tiling"].update(reused=len(tasks) - len(todo), ran=len(todo))
    if len(todo) < len(tasks):
        ctx.log.info("%d of %d tiles unchanged since an earlier run: reused", len(tasks) - len(todo), len(tasks))
    return results


def _runs_here(config: Any, weight: float | None) -> bool:
    """Whether work of *weight* runs in this process: the local executor's ``in_process_below``."""
    ex = getattr(config, "executor", None)
    below = getattr(ex, "in_process_below", 0) if ex is not None else 0
    return weight is not None and ex is not None and ex.kind == "local" and weight < below


def map_largest_first(ctx: Any, task: Callable[[dict[str, Any]], Any], tasks: list[dict[str, Any]], what: str) -> list:
    """Run *tasks* on the run's executor, the largest (``weight``) first; results in the tasks' order.

    Largest first, the workers finish together instead of one waiting on
    the last big tile.
    """
    order = sorted(range(len(tasks)), key=lambda i: -float(getattr(tasks[i], "weight", 0)))
    done = ctx.executor.map(task, [tasks[i] for i in order], log=ctx.log, what=what)
    results: list[Any] = [None] * len(tasks)
    for i, r in zip(order, done, strict=True):
        results[i] = r
    return results
