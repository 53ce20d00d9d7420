"""Stages that reclassify points on one grid of the whole survey: passes over the records, no tile.

Such a stage reads the points a chunk at a time to build its grid
(:func:`las_chunks`), works on the grid whole, then writes each chunk's
classes: in this process (:func:`classes_here`) or, with several workers,
a range of records each, written at its place in the output
(:func:`classes_on_workers`, :func:`rewrite_range`).  Only the
classification changes, so the output's header (bounds, returns, counts)
is the input's: the one laspy's writer gives the same points.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pipeline.errors import InputDataError

if TYPE_CHECKING:
    import laspy

    from pipeline.executor import DaskExecutor, LocalExecutor
    from pipeline.log import Progress

#: A header's grid over a one-grid stage's cap, but within this many times it, is taken for the survey's own:
#: the stage tiles without first reading every point for the box of those it uses.  Beyond it, stray points
#: (noise far out, a header whose bounds are wrong) may have made the header's grid large: the box is read.
#: Only the speed depends on it; the tiles give the one grid's classes.  At 100 M points (12.8 M cells
#: against 8 M and 4 M), the read cost each of classify_ground and classify_objects 8-10 s (2026-12-04).
STRAYS_BEYOND = 4.0


def box_worth_reading(cells: int, cap: int) -> bool:
    """Whether a header's grid of *cells*, over a one-grid stage's *cap*, may be stray points' (:data:`STRAYS_BEYOND`)."""
    return cells > STRAYS_BEYOND * cap


#: ``classes(chunk, xyz)``: a chunk's new classification and the numbers to sum over the chunks.
Classes = Callable[[Any, np.ndarray], tuple[np.ndarray, tuple[int, ...]]]


def las_chunks(path: Path, work: Callable[[laspy.ScaleAwarePointRecord, np.ndarray], Any], *, chunk_size: int):
    """``work(chunk, xyz)`` of each chunk of a LAS file, in file order; *xyz* in metres, as the tiles read them.

    (Two threads sharing the chunks were slower, 24 s against 16 s on 37.5 M
    points with the other core busy, and held 1.6 times the memory.)
    """
    import laspy

    from lidar.clouds import chunk_xyz_metres, cloud_crs
    from lidar.units import Units

    with laspy.open(str(path)) as reader:
        units = Units.of(cloud_crs(reader))
        for chunk in reader.chunk_iterator(chunk_size):
            yield work(chunk, chunk_xyz_metres(chunk, units))


def _summed(totals: list[int], numbers) -> list[int]:
    return [a + b for a, b in zip(totals, numbers, strict=True)]


def classes_here(
    src: Path, dst: Path, classes: Classes, width: int, *, chunk_size: int, progress: Progress | None = None
) -> list[int]:
    """*src* copied to *dst* a chunk at a time with ``classes(chunk, xyz)``'s classes; its *width* numbers summed."""
    import laspy

    from lidar.clouds import open_las_writer

    def write(chunk, xyz):
        chunk.classification, numbers = classes(chunk, xyz)
        return chunk, numbers

    totals = [0] * width
    with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
        for chunk, numbers in las_chunks(src, write, chunk_size=chunk_size):
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
    import laspy

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


def workers_layout(
    src: Path,
    count: int,
    executor: LocalExecutor | DaskExecutor | None,
    workdir: Path | None,
    chunk_size: int,
    run: Callable[[Any], list[int]],
) -> tuple[int, int, int] | None:
    """:func:`record_layout` of *src* when its classes are to be written on the workers, else None.

    On the workers when there are more than one, a *workdir* for the grids
    and *count* records fill two chunks or more; then the workers start
    (importing *run*'s module) while this process makes its grid.
    """
    if executor is None or executor.workers <= 1 or workdir is None or count < 2 * chunk_size:
        return None
    records = record_layout(src)
    if records is not None:
        executor.prepare(run)
    return records


@dataclass(frozen=True)
class RecordRange:
    """Records ``start:stop`` of the LAS *src*, written with their new classes at byte *offset* of *dst*."""

    src: str
    dst: str
    start: int
    stop: int
    offset: int
    chunk_size: int


def classes_on_workers(
    src: Path,
    dst: Path,
    records: tuple[int, int, int],
    executor: LocalExecutor | DaskExecutor,
    *,
    folder: Path,
    grids: dict[str, np.ndarray],
    task: Callable[[RecordRange, dict[str, str]], Any],
    run: Callable[[Any], list[int]],
    chunk_size: int,
    what: str,
) -> list[int]:
    """*dst*: *src* with the classes the workers compute, a range of records each; their numbers summed.

    This process writes *src*'s header and VLRs to *dst* and sizes it for
    the records; *grids* are saved as ``.npy`` files in *folder* (removed
    after); ``task(records, paths)`` makes the worker task of a range given
    the grids' paths by name, and *run* (a module-level function calling
    :func:`rewrite_range`) runs it.  *records*: :func:`record_layout`.
    """
    offset, size, count = records
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    try:
        paths = {}
        for name, grid in grids.items():
            paths[name] = str(folder / f"{name}.npy")
            np.save(paths[name], grid)
        with open(src, "rb") as head, open(dst, "wb") as out:
            out.write(head.read(offset))  # header and VLRs
            out.truncate(offset + count * size)
        pieces = 2 * executor.workers
        bounds = [count * k // pieces for k in range(pieces + 1)]
        ranges = [
            RecordRange(
                src=str(src),
                dst=str(dst),
                start=bounds[k],
                stop=bounds[k + 1],
                offset=offset + bounds[k] * size,
                chunk_size=max(chunk_size // executor.workers, 1),  # the workers' chunks together: one process's
            )
            for k in range(pieces)
        ]
        results = executor.map(run, [task(r, paths) for r in ranges], what=what)
        return [sum(r[k] for r in results) for k in range(len(results[0]))]
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def write_classes(
    src: Path,
    dst: Path,
    records: tuple[int, int, int] | None,
    executor: LocalExecutor | DaskExecutor | None,
    *,
    classes: Classes,
    width: int,
    folder: Path | None,
    grids: dict[str, np.ndarray],
    task: Callable[[RecordRange, dict[str, str]], Any],
    run: Callable[[Any], list[int]],
    chunk_size: int,
    what: str,
    progress: Progress | None = None,
) -> list[int]:
    """*dst*: *src* with new classes, on the workers when *records* (:func:`workers_layout`) says so, else here.

    On the workers: :func:`classes_on_workers` (*folder*, *grids*, *task*,
    *run*); here: :func:`classes_here` with ``classes(chunk, xyz)``.  The
    *width* numbers summed; *progress* advanced by the records either way.
    """
    if records is None:
        return classes_here(src, dst, classes, width, chunk_size=chunk_size, progress=progress)
    numbers = classes_on_workers(
        src, dst, records, executor, folder=folder, grids=grids, task=task, run=run, chunk_size=chunk_size, what=what
    )
    if progress is not None:
        progress.update(records[2])
    return numbers


def rewrite_range(records: RecordRange, classes: Classes, width: int) -> list[int]:
    """Records of one range classified by ``classes(chunk, xyz)`` and written in place, in a worker; *width* sums.

    The output exists at its full size (:func:`classes_on_workers`): each
    range writes its own bytes.
    """
    import laspy

    from lidar.clouds import chunk_xyz_metres, cloud_crs
    from lidar.tile_points import record_chunks
    from lidar.units import Units

    start, stop = records.start, records.stop
    totals, seen = [0] * width, 0
    with laspy.open(records.src) as reader, open(records.dst, "r+b") as out:  # r+: no truncation
        out.seek(records.offset)
        units = Units.of(cloud_crs(reader))
        for chunk in record_chunks(reader, start, stop, records.chunk_size):
            cls, numbers = classes(chunk, chunk_xyz_metres(chunk, units))
            chunk.array["classification"] = cls
            out.write(chunk.array)  # contiguous records: written as they are, no copy
            totals, seen = _summed(totals, numbers), seen + len(chunk)
    if seen != stop - start:  # pragma: no cover - fewer records than the header says; parse checks that first
        raise InputDataError(f"{records.src}: of records {start:,} to {stop:,}, {seen:,} could be read.")
    return totals


def grids_of(paths: dict[str, str]) -> dict[str, np.ndarray]:
    """The grids :func:`classes_on_workers` saved, memory-mapped, by name."""
    return {name: np.load(p, mmap_mode="r") for name, p in paths.items()}
