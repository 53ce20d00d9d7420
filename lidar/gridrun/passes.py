"""Passes over a LAS file's records: the statistics of a grid (pass 1), and each point's new class (pass 2).

Pass 1 (:func:`survey_statistics`) gathers a kernel's statistics a chunk at
a time on the frame of the header's extent, or of the box of the points it
gathers where the header misses some or is far too wide (stray points).
Pass 2 (:func:`write_classes`) copies the file with the classes a
:class:`Lookup` gives: in this process, or with several workers a range of
records each, written at its place in the output (:func:`rewrite_range`).
Only the classification changes, so the output's header is the input's:
the one laspy's writer gives the same points.
"""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import laspy
import numpy as np

from lidar.clouds import chunk_xyz_metres, cloud_crs, open_las_writer, progress_chunk
from lidar.gridrun.kernel import Frame, GridKernel
from lidar.tile_points import record_chunks
from lidar.units import Units
from pipeline.errors import InputDataError

if TYPE_CHECKING:
    from pipeline.executor import DaskExecutor, LocalExecutor
    from pipeline.log import Progress

#: A header's grid over a stage's cap, but within this many times it, is taken for the survey's own: the
#: stage tiles without first reading every point for the box of those it uses.  Beyond it, stray points
#: (noise far out, a header whose bounds are wrong) may have made the header's grid large: the box is read.
#: Only the speed depends on it.  At 100 M points (12.8 M cells against 8 M and 4 M), the read cost each of
#: classify_ground and classify_objects 8-10 s.
STRAYS_BEYOND = 4.0


def las_chunks(path: Path, chunk_size: int) -> Iterator[tuple[laspy.ScaleAwarePointRecord, np.ndarray]]:
    """``(chunk, xyz)`` of each chunk of a LAS file, in file order; *xyz* in metres, as the tiles read them.

    (Two threads sharing the chunks were slower, 24 s against 16 s on 37.5 M
    points with the other core busy, and held 1.6 times the memory.)
    """
    with laspy.open(str(path)) as reader:
        units = Units.of(cloud_crs(reader))
        for chunk in reader.chunk_iterator(chunk_size):
            yield chunk, chunk_xyz_metres(chunk, units)


def take(xyz: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The rows of (n, 3) *xyz* where *mask*, column by column (3 times faster than ``xyz[mask]``); *xyz* itself when all."""
    if mask.all():
        return xyz
    out = np.empty((int(mask.sum()), 3), order="F")
    for axis in range(3):
        np.compress(mask, xyz[:, axis], out=out[:, axis])
    return out


def subset(cols: dict[str, np.ndarray], mask: np.ndarray) -> dict[str, np.ndarray]:
    """Every column where *mask*."""
    return {name: c[mask] for name, c in cols.items()}


def _gathered(
    src: Path, kernel: GridKernel, frame: Frame, chunk_size: int, progress: Progress | None
) -> dict[str, np.ndarray] | None:
    """Pass 1 on *frame*: the kernel's statistics; None when a point it gathers lies off the frame."""
    stats = kernel.stats(frame.size)
    for step in range(kernel.passes):
        for chunk, xyz in las_chunks(src, chunk_size):
            cols = kernel.columns(chunk)
            sel = kernel.selected(cols)
            if sel.any():
                pts = take(xyz, sel)
                k = frame.flat(pts)
                if (k < 0).any():
                    return None
                kernel.gather(stats, step, k, pts, subset(cols, sel))
            if progress is not None:
                progress.update(len(chunk))
    return stats


def selected_box(src: Path, kernel: GridKernel, chunk_size: int) -> tuple[float, float, float, float] | None:
    """``(xmin, ymin, xmax, ymax)`` of the points the kernel gathers; None when there is none."""
    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for chunk, xyz in las_chunks(src, chunk_size):
        sel = kernel.selected(kernel.columns(chunk))
        if sel.any():
            for axis in range(2):
                v = xyz[sel, axis]
                lo[axis], hi[axis] = min(lo[axis], v.min()), max(hi[axis], v.max())
    return (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])) if np.isfinite(lo).all() else None


def survey_statistics(
    src: Path,
    kernel: GridKernel,
    extent: tuple[float, float, float, float],
    cap: int,
    chunk_size: int = 1_000_000,
    progress: Progress | None = None,
) -> tuple[dict[str, np.ndarray] | None, Frame | None] | None:
    """Pass 1: the kernel's statistics over the survey and their frame; None when the grid has over *cap* cells.

    Tried on the header's *extent* first; read again on the box of the
    gathered points when one lies off it (a header whose bounds miss
    points); that box is read first when the header's grid is far over
    *cap* (:data:`STRAYS_BEYOND`: stray points), and None returned at once
    when it is over *cap* but not far.  ``(None, None)`` when no point is
    gathered.
    """
    frame = Frame.covering(kernel.axes, extent, kernel.cell)
    if frame.size > cap and frame.size <= STRAYS_BEYOND * cap:
        return None  # a survey larger than one grid: tiled
    with laspy.open(str(src)) as reader:  # read in chunks the progress figure moves by, in a small file too
        chunk_size = progress_chunk(reader.header.point_count, chunk_size)
    tried = frame.size <= cap
    stats = _gathered(src, kernel, frame, chunk_size, progress) if tried else None
    if stats is None:  # the header's grid is far too big (stray points) or misses points: the gathered points' own
        box = selected_box(src, kernel, chunk_size)
        if box is None:
            return None, None
        frame = Frame.covering(kernel.axes, box, kernel.cell)
        if frame.size > cap:
            return None
        stats = _gathered(src, kernel, frame, chunk_size, None if tried else progress)  # pass 1 counted once
    return stats, frame


class Lookup:
    """Where pass 2 finds the results for a point: one grid (:class:`OneGrid`) or the tiles' windows."""

    def values(self, kernel: GridKernel, xyz: np.ndarray, cols: dict[str, np.ndarray]) -> np.ndarray:
        raise NotImplementedError


class OneGrid(Lookup):
    """The results of one grid of the survey (*results* None: it has none)."""

    def __init__(self, results: dict[str, np.ndarray] | None, frame: Frame | None):
        self.results, self.frame = results, frame

    def values(self, kernel: GridKernel, xyz: np.ndarray, cols: dict[str, np.ndarray]) -> np.ndarray:
        return kernel.values(xyz, cols, self.results, self.frame)


@dataclass(frozen=True)
class SavedGrid:
    """:class:`OneGrid` for the workers: its results as ``.npy`` files by name, and its frame."""

    paths: dict[str, str]
    frame: Frame

    def lookup(self) -> OneGrid:
        return OneGrid({name: np.load(p, mmap_mode="r") for name, p in self.paths.items()}, self.frame)


def chunk_classes(
    kernel: GridKernel, lookup: Lookup, chunk: laspy.ScaleAwarePointRecord, xyz: np.ndarray
) -> tuple[np.ndarray, tuple[int, ...]]:
    """Pass 2 on one chunk: its new classes, and the kernel's counts with the points whose class changed last."""
    cols = kernel.columns(chunk)
    tested = kernel.tested(cols)
    values = lookup.values(kernel, take(xyz, tested), subset(cols, tested))
    new, counts = kernel.classes(cols, tested, values)
    return new, (*counts, int(np.count_nonzero(new != np.asarray(chunk.classification))))


def _summed(totals: list[int], numbers) -> list[int]:
    return [a + b for a, b in zip(totals, numbers, strict=True)]


def classes_here(
    src: Path,
    dst: Path,
    kernel: GridKernel,
    lookup: Lookup,
    *,
    chunk_size: int,
    progress: Progress | None = None,
) -> list[int]:
    """*src* copied to *dst* a chunk at a time with the classes of :func:`chunk_classes`; the numbers summed."""
    totals = [0] * (len(kernel.counts) + 1)
    with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
        for chunk, xyz in las_chunks(src, progress_chunk(reader.header.point_count, chunk_size)):
            chunk.classification, numbers = chunk_classes(kernel, lookup, chunk, xyz)
            writer.write_points(chunk)
            totals = _summed(totals, numbers)
            if progress is not None:
                progress.update(len(chunk))
    return totals


def record_layout(path: Path) -> tuple[int, int, int] | None:
    """``(offset to the first record, record length, record count)`` of a LAS file the workers may rewrite in place.

    None when the classification is not a byte of its own (point formats
    0-5 keep it in five bits of a byte shared with three flags), the file
    is compressed, or anything follows the records (EVLRs, which laspy's
    writer does not copy): such a file is written by laspy's writer.
    """
    with laspy.open(str(path)) as reader:
        header = reader.header
        if header.are_points_compressed:
            return None
        fields = header.point_format.dtype().fields
        if "classification" not in fields or fields["classification"][0] != np.uint8:
            return None
        offset, size, count = int(header.offset_to_point_data), int(header.point_format.size), int(header.point_count)
        if Path(path).stat().st_size != offset + count * size:
            return None
        return offset, size, count


@dataclass(frozen=True)
class Records:
    """Pass 2 on the workers: the file's :func:`record_layout`, the executor, and where the grids go."""

    layout: tuple[int, int, int]
    executor: Any
    folder: Path


def workers_layout(
    src: Path, count: int, executor: LocalExecutor | DaskExecutor | None, folder: Path | None, chunk_size: int
) -> Records | None:
    """How pass 2 runs on the workers, or None for this process.

    On the workers when there are more than one, a *folder* for the grids
    and *count* records fill two chunks or more; then the workers start
    (importing this module) while this process makes the grid.
    """
    if executor is None or executor.workers <= 1 or folder is None or count < 2 * chunk_size:
        return None
    layout = record_layout(src)
    if layout is None:
        return None
    executor.prepare(rewrite_range)
    return Records(layout, executor, Path(folder))


#: Pass 2 on the workers cuts the records into at least this many ranges (its progress moves by a range).
PIECES = 10


@dataclass(frozen=True)
class RecordRange:
    """Records ``start:stop`` of the LAS *src*, written with their new classes at byte *offset* of *dst*.

    *kernel* and *lookup* (a :class:`SavedGrid`, or the windows' ``lookup()``)
    give the classes.
    """

    src: str
    dst: str
    start: int
    stop: int
    offset: int
    chunk_size: int
    kernel: GridKernel
    lookup: Any


def classes_on_workers(
    src: Path,
    dst: Path,
    records: Records,
    kernel: GridKernel,
    lookup: Any,
    *,
    chunk_size: int,
    what: str,
    progress: Progress | None = None,
) -> list[int]:
    """*dst*: *src* with the classes the workers give it, a range of records each; their numbers summed.

    This process writes *src*'s header and VLRs to *dst* and sizes it for
    the records; *lookup* is what the workers read the results by (small:
    paths and frames, its ``lookup()`` opens them).  *progress* advances by
    each range's records as it is written: in at least :data:`PIECES`
    ranges, so that it moves every tenth of the records.
    """
    offset, size, count = records.layout
    with open(src, "rb") as head, open(dst, "wb") as out:
        out.write(head.read(offset))  # header and VLRs
        out.truncate(offset + count * size)
    pieces = max(2 * records.executor.workers, PIECES)
    bounds = [count * k // pieces for k in range(pieces + 1)]
    ranges = [
        RecordRange(
            src=str(src),
            dst=str(dst),
            start=bounds[k],
            stop=bounds[k + 1],
            offset=offset + bounds[k] * size,
            chunk_size=max(chunk_size // records.executor.workers, 1),  # the workers' chunks together: one process's
            kernel=kernel,
            lookup=lookup,
        )
        for k in range(pieces)
    ]
    advance = (lambda r: progress.update(r.stop - r.start)) if progress is not None else None
    results = records.executor.map(rewrite_range, ranges, what=what, done=advance)
    return [sum(r[k] for r in results) for k in range(len(results[0]))]


def save_grid(results: dict[str, np.ndarray] | None, frame: Frame | None, folder: Path) -> SavedGrid | None:
    """The results of one grid saved in *folder* for the workers (None without results)."""
    if results is None:
        return None
    paths = {}
    for name, grid in results.items():
        paths[name] = str(folder / f"{name}.npy")
        np.save(paths[name], grid)
    return SavedGrid(paths, frame)


def write_classes(
    src: Path,
    dst: Path,
    kernel: GridKernel,
    lookup: Lookup,
    records: Records | None,
    saved: Any,
    *,
    chunk_size: int,
    what: str,
    progress: Progress | None = None,
) -> list[int]:
    """*dst*: *src* with new classes, on the workers when *records* (:func:`workers_layout`) says so, else here.

    *lookup*: the results here; *saved*: a callable giving what the workers
    read them by (saving them first).  The numbers summed; *progress*
    advanced by the records either way.
    """
    if records is None:
        return classes_here(src, dst, kernel, lookup, chunk_size=chunk_size, progress=progress)
    shutil.rmtree(records.folder, ignore_errors=True)
    records.folder.mkdir(parents=True)
    try:
        lookup = saved(records.folder)
        return classes_on_workers(
            src, dst, records, kernel, lookup, chunk_size=chunk_size, what=what, progress=progress
        )
    finally:
        shutil.rmtree(records.folder, ignore_errors=True)


class _NoResults:
    """What the workers read when the grid gave no results."""

    def lookup(self) -> OneGrid:
        return OneGrid(None, None)


NO_RESULTS = _NoResults()


def rewrite_range(task: RecordRange) -> list[int]:
    """Records of one range classified and written in place, in a worker; the numbers summed.

    The output exists at its full size (:func:`classes_on_workers`): each
    range writes its own bytes.
    """
    lookup = (task.lookup or NO_RESULTS).lookup()
    start, stop = task.start, task.stop
    totals, seen = [0] * (len(task.kernel.counts) + 1), 0
    with laspy.open(task.src) as reader, open(task.dst, "r+b") as out:  # r+: no truncation
        out.seek(task.offset)
        units = Units.of(cloud_crs(reader))
        for chunk in record_chunks(reader, start, stop, task.chunk_size):
            cls, numbers = chunk_classes(task.kernel, lookup, chunk, chunk_xyz_metres(chunk, units))
            chunk.array["classification"] = cls
            out.write(chunk.array)  # contiguous records: written as they are, no copy
            totals, seen = _summed(totals, numbers), seen + len(chunk)
    if seen != stop - start:  # pragma: no cover - fewer records than the header says; parse checks that first
        raise InputDataError(f"{task.src}: of records {start:,} to {stop:,}, {seen:,} could be read.")
    return totals
