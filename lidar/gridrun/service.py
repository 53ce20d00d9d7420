"""The run service of the grid stages: one entry, :func:`run_grid_stage`, that decides how a kernel runs.

A stage gives its kernel (:class:`~lidar.gridrun.kernel.GridKernel`: what
it computes on a window of the survey's grid, and its reach) and the most
cells it may hold as one grid.  The service turns the reach into cells and
into the tile buffer, and runs the kernel:

- on the whole grid, here: pass 1 gathers the statistics, the grid is
  computed whole, pass 2 writes each point's class (on the workers, a range
  of records each, when the survey fills two chunks or more);
- on the grid cut into the tiles' windows, on the workers: a grid of more
  cells than the stage's cap, up to :data:`WINDOWED_BEYOND` times it, when
  the tiles are whole cells;
- on tiles of points: a larger grid, tiles that are not whole cells, or a
  kernel without a grid form.

Every point gets the result of its own window: the classes are the same
whichever way runs (docs/ARCHITECTURE.md, "Tiled equals untiled").
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from lidar.clouds import cloud_info
from lidar.gridrun.kernel import Frame, GridKernel
from lidar.gridrun.passes import OneGrid, save_grid, survey_statistics, workers_layout, write_classes
from lidar.gridrun.point_tiles import classes_by_tile
from lidar.gridrun.windows import occupied_box, run_tile_cells, run_windows, scratch
from lidar.tile_points import keep_file
from pipeline.log import Progress
from pipeline.stage import StageContext

#: A grid worked in windows may have this many times a stage's cap; beyond, tiles of points.
WINDOWED_BEYOND = 4


@dataclass(frozen=True)
class Workers:
    """Where a grid runs: the *executor* (None: this process) and a *workdir* for its files; *threads* for a grid
    computed whole in this process; records read *chunk_size* at a time.  Only the speed depends on them."""

    executor: Any = None
    workdir: Path | None = None
    threads: int = 1
    chunk_size: int = 1_000_000


@dataclass(frozen=True)
class GridRun:
    """What :func:`on_one_grid` did: the kernel's counts (the changed points last), the grid it worked (None: no
    point gathered) and in how many windows (0: whole)."""

    counts: list[int]
    grid: Frame | None
    windows: int


def run_grid_stage(
    ctx: StageContext, kernel: GridKernel, src: Path, dst: Path, *, one_grid_cells: int, what: str
) -> dict[str, int]:
    """*src* copied to *dst* with the kernel's classes, run the way the survey allows; the kernel's counts.

    *one_grid_cells*: the most cells the stage's grid may have to be worked
    whole (0: always tiles of points); *what*: the stage's work, for the
    progress bar and the log.  Sets the stage's ``tiling`` metrics.
    """
    done = None
    if kernel.grid_form and one_grid_cells > 0:
        tiles = run_tile_cells(ctx.config, kernel.reach, kernel.cell)
        workers = Workers(ctx.executor, Path(ctx.workdir), ctx.workers)
        passes = f"{kernel.passes + 1} passes over the points"  # pass 1 (the grid's statistics), then the writing
        with ctx.progress((kernel.passes + 1) * cloud_info(src).count, f"{what}, {passes}", unit="pt") as bar:
            done = on_one_grid(src, dst, kernel, one_grid_cells, tiles, workers, bar)
        if done is not None:
            _note(ctx, what, done, tiles)
    numbers = done.counts if done is not None else classes_by_tile(ctx, src, dst, kernel)
    return dict(zip(kernel.counts, numbers[:-1], strict=True))


def on_one_grid(
    src: Path,
    dst: Path,
    kernel: GridKernel,
    cap: int,
    tiles: tuple[int, int] | None = None,
    workers: Workers = Workers(),
    progress: Progress | None = None,
) -> GridRun | None:
    """The kernel on one grid of the survey: whole when it has at most *cap* cells, else in the windows of
    *tiles* ``(tile, buffer)`` (cells) up to :data:`WINDOWED_BEYOND` times *cap*; None (nothing written) beyond."""
    count, chunk = cloud_info(src).count, workers.chunk_size
    folder = Path(workers.workdir) / f".{dst.stem}-records" if workers.workdir is not None else None
    records = workers_layout(src, count, workers.executor, folder, chunk)
    got = survey_statistics(
        src, kernel, cloud_info(src).extent, cap * (WINDOWED_BEYOND if tiles else 1), chunk, progress
    )
    if got is None:
        return None
    stats, frame = got
    box = occupied_box(kernel.occupied({n: s.reshape(frame.shape) for n, s in stats.items()})) if stats else None
    grid = frame.cut(*box) if box is not None else None
    write = partial(write_classes, src, dst, kernel, chunk_size=chunk, what="classes", progress=progress)
    if grid is not None and grid.size > cap:
        with scratch(workers.workdir, dst, f".{dst.stem}-windows") as where:
            windows = run_windows(kernel, frame, stats, tiles, where, workers.executor)
            del stats
            if not windows.frames and kernel.unchanged(None):
                return GridRun(_kept(src, dst, kernel, count), grid, windows.worked)
            return GridRun(write(windows.lookup(), records, lambda _: windows), grid, windows.worked)
    results = None
    if grid is not None:
        results = kernel.window({n: s.reshape(frame.shape)[box] for n, s in stats.items()}, grid, workers.threads)
    del stats
    if kernel.unchanged(results):
        return GridRun(_kept(src, dst, kernel, count), grid, 0)
    return GridRun(write(OneGrid(results, grid), records, partial(save_grid, results, grid)), grid, 0)


def _kept(src: Path, dst: Path, kernel: GridKernel, points: int) -> list[int]:
    """The input kept as the output (no class changes): a link; its *points* counted, nothing else."""
    keep_file(src, dst)
    return [points] + [0] * len(kernel.counts)


def _note(ctx: StageContext, what: str, done: GridRun, tiles: tuple[int, int] | None) -> None:
    """The stage's ``tiling`` metrics and log line for its one grid, whole or in windows."""
    shape = list(done.grid.shape) if done.grid is not None else [0, 0]
    cell = done.grid.cell if done.grid is not None else 0.0
    if done.windows:
        size, buffer = tiles[0] * cell, tiles[1] * cell
        ctx.metrics["tiling"] = {  # the grid in the tiles' windows, no tile of points
            "tiles": done.windows,
            "size": size,
            "buffer": buffer,
            "executor": f"one grid in windows, {ctx.executor.describe()}",
            "grid": shape,
        }
        ctx.log.info(
            "%s on one grid of %d x %d cells of %g m (x by y), in %d windows of %g m with a buffer of %g m",
            what,
            *_x_by_y(done.grid),
            cell,
            done.windows,
            size,
            buffer,
        )
        return
    ctx.metrics["tiling"] = {
        "tiles": 1,
        "size": None,
        "buffer": 0.0,
        "executor": "one grid, this process",
        "grid": shape,
    }
    ctx.log.info("%s on one grid of %d x %d cells of %g m (x by y)", what, *_x_by_y(done.grid), cell)


def _x_by_y(grid: Frame | None) -> tuple[int, int]:
    """The cells along x and along y of a frame (its arrays may be rows first or x first), as the DTM's are said."""
    if grid is None:
        return 0, 0
    along = {axis.coord: n for axis, n in zip(grid.axes, grid.shape, strict=True)}
    return along[0], along[1]
