"""Tiles of points: a kernel's classes computed tile by tile, merged back into one file in the input's order.

:func:`classes_by_tile` is the whole flow: the survey cut into the run's
tiles with the kernel's reach as buffer (:func:`lidar.tile_points.split_cloud`),
one :class:`PointTask` per tile holding points of its own
(:func:`tile_classes`: the kernel's :meth:`~lidar.gridrun.kernel.GridKernel.tile`
on its points, the classes of its core points kept), then
:func:`merge_classes`.  A tile whose points did not change since an earlier
run is read back from the tile cache (:data:`MEMO`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np

from lidar.clouds import cloud_info, open_las_writer, progress_chunk
from lidar.gridrun.kernel import GridKernel
from lidar.gridrun.passes import subset
from lidar.tile_points import (
    cleanup,
    column_digests,
    keep_file,
    read_column,
    read_tile,
    split_cloud,
    task_folder,
    write_result,
)
from pipeline.stage import StageContext
from pipeline.tiling import Layout, TileMemo, run_tiled

if TYPE_CHECKING:
    from pipeline.log import Progress

#: Values read at a time from each tile's result files while merging.
MERGE_BLOCK = 65_536


def classes_by_tile(ctx: StageContext, src: Path, dst: Path, kernel: GridKernel) -> list[int]:
    """*src* copied to *dst* with the classes the tiles give; the kernel's counts summed, the changed points last.

    When no tile changed a class, *dst* is *src* itself (:func:`keep_file`:
    a link, not a rewrite of every record).  The split runs on the run's
    workers.
    """
    info = cloud_info(src)
    work = task_folder(ctx.workdir, ctx.name)

    def split(layout: Layout) -> list[PointTask]:
        with ctx.progress(info.count, "tiling", unit="pt") as bar:
            executor = ctx.executor if len(layout) > 1 else None
            rows, _ = split_cloud(src, layout, work / "in", kernel.columns, progress=bar, executor=executor)
        return point_tasks(rows, work, kernel)

    def merge(layout: Layout, tasks: list[PointTask], results: list[list[int]]) -> list[int]:
        totals = [sum(r[k] for r in results) for k in range(len(kernel.counts) + 1)]
        if totals[-1] == 0:  # no class changed: the input is the output
            keep_file(src, dst)
            return totals
        with ctx.progress(info.count, "writing", unit="pt") as bar:
            merge_classes(src, dst, [Path(t.result) for t in tasks], progress=bar)
        return totals

    try:
        return run_tiled(
            ctx,
            extent=info.extent,
            buffer=kernel.reach,
            split=split,
            task=tile_classes,
            merge=merge,
            weight=info.count,
            memo=MEMO,
        )
    finally:
        cleanup(work)


@dataclass(frozen=True)
class PointTask:
    """One tile's task (runs in a worker process or on Dask): the kernel on its points.

    ``source``: the tile's columns (:func:`split_cloud`); ``result``: where
    the task writes ``idx`` and ``classification`` of its core points;
    ``weight``: the tile's points (the largest run first).
    """

    tile: int
    weight: int
    source: str
    result: str
    kernel: GridKernel


def point_tasks(rows: dict[int, tuple[int, int]], work: Path, kernel: GridKernel) -> list[PointTask]:
    """One task per tile holding points of its own (results per point)."""
    return [
        PointTask(
            tile=t,
            weight=rows[t][0],
            source=str(Path(work) / "in" / str(t)),
            result=str(Path(work) / "out" / str(t)),
            kernel=kernel,
        )
        for t in sorted(rows)
        if rows[t][1]  # a tile with no point of its own has nothing to classify
    ]


def tile_classes(task: PointTask) -> list[int]:
    """The kernel on one tile's points (core plus buffer), in a worker: the classes of its core points written.

    Returns the kernel's counts over the core points and, last, how many
    of them changed class.
    """
    kernel = task.kernel
    cols = read_tile(Path(task.source))
    xyz = cols.pop("xyz")
    tested = kernel.tested(cols)
    values = kernel.tile(xyz, cols, tested)
    core = cols["core"]
    new, counts = kernel.classes(subset(cols, core), tested[core], values[core[tested]])
    write_result(Path(task.result), idx=cols["idx"][core], classification=new)
    return [*counts, int(np.count_nonzero(new != cols["classification"][core]))]


def _memo_key(task: PointTask) -> dict:
    """What a tile's classes depend on: its points (not their positions in the survey's file) and the kernel."""
    kernel = {"kind": type(task.kernel).__qualname__, **dataclasses.asdict(task.kernel)}
    return {"kind": "classes", "kernel": kernel, "columns": column_digests(Path(task.source), skip=("idx",))}


def _memo_save(task: PointTask, result: list[int], folder: Path) -> list[int]:
    keep_file(Path(task.result) / "classification.npy", folder / "classification.npy")
    return result


def _memo_load(task: PointTask, folder: Path, kept: list[int]) -> list[int]:
    """The result of a kept tile, its core points' indices those of this run's file."""
    core = read_column(Path(task.source), "core")
    idx = read_column(Path(task.source), "idx")[core]
    classification = np.load(folder / "classification.npy")
    if len(classification) != len(idx):  # pragma: no cover - the key holds the core column
        raise RuntimeError(f"a kept tile holds {len(classification)} classes for {len(idx)} core points")
    write_result(Path(task.result), idx=idx, classification=classification)
    return list(kept)


#: A tile's classes kept for later runs: a tile whose points did not change is not classified again.
MEMO = TileMemo(_memo_key, _memo_save, _memo_load)


class _Run:
    """One tile's results (``idx`` ascending, values), read in blocks from disk."""

    def __init__(self, folder: Path, names: list[str]):
        self.names = ["idx", *names]
        self.files = {}
        self.dtypes = {}
        self.left = None
        for name in self.names:
            fh = open(Path(folder) / f"{name}.npy", "rb")  # noqa: SIM115 - closed in close()
            major, minor = np.lib.format.read_magic(fh)
            read = np.lib.format.read_array_header_1_0 if major == 1 else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(fh)
            self.files[name], self.dtypes[name] = fh, dtype
            self.left = int(shape[0])
        self.buf = {n: np.zeros(0, self.dtypes[n]) for n in self.names}

    def take_below(self, stop: int) -> dict[str, np.ndarray]:
        parts = []
        while True:
            if len(self.buf["idx"]) == 0:
                if self.left == 0:
                    break
                k = min(MERGE_BLOCK, self.left)
                self.buf = {n: np.fromfile(self.files[n], dtype=self.dtypes[n], count=k) for n in self.names}
                self.left -= k
            cut = int(np.searchsorted(self.buf["idx"], stop))
            parts.append({n: a[:cut] for n, a in self.buf.items()})
            self.buf = {n: a[cut:] for n, a in self.buf.items()}
            if len(self.buf["idx"]):
                break
        if not parts:
            return {n: np.zeros(0, self.dtypes[n]) for n in self.names}
        return {n: np.concatenate([p[n] for p in parts]) for n in self.names}

    def close(self) -> None:
        for fh in self.files.values():
            fh.close()


def merge_classes(
    src: Path,
    dst: Path,
    results: list[Path],
    *,
    chunk_size: int = 1_000_000,
    progress: Progress | None = None,
) -> None:
    """Copy the LAS *src* to *dst* with the classes of the tiles' results.

    Each result folder holds ``idx`` (ascending) and ``classification`` for
    the core points of one tile; together they cover every point once.
    """
    runs = [_Run(folder, ["classification"]) for folder in results]
    try:
        with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
            start = 0
            for chunk in reader.chunk_iterator(progress_chunk(reader.header.point_count, chunk_size)):
                n = len(chunk)
                cls = np.asarray(chunk.classification).copy()
                filled = np.zeros(n, dtype=bool)
                for run in runs:
                    got = run.take_below(start + n)
                    where = got["idx"] - start
                    cls[where] = got["classification"]
                    filled[where] = True
                if not filled.all():  # pragma: no cover - a broken layout, never a user error
                    raise RuntimeError(f"tiling left {int((~filled).sum())} points without a result")
                chunk.classification = cls
                writer.write_points(chunk)
                start += n
                if progress is not None:
                    progress.update(n)
    finally:
        for run in runs:
            run.close()
