"""Point clouds cut into the engine's tiles, streaming: memory follows the tile size, not the survey.

The engine (:mod:`pipeline.tiling`) cuts a plane into tiles; :func:`split_cloud`
reads a LAS file chunk by chunk and writes, for every tile, the columns its
task needs of the points inside the tile plus its buffer, in file order, with
each point's index in the file (``idx``) and whether it lies in its core
(``core``); :func:`read_tile` reads them back.  The tiles' classes go back into
one file with :func:`lidar.gridrun.point_tiles.merge_classes`, their rasters into
one with :class:`lidar.mosaic.RasterMosaic`.

Why tiled and untiled results are identical: every algorithm the tiles run
computes on grids anchored at whole multiples of their cell size (not at the
data's corner), sees the points in the file's order, and gets a buffer at
least as wide as its reach; the same code runs untiled as a single tile.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import laspy
import numpy as np

from lidar.clouds import chunk_xyz_metres, cloud_crs, progress_chunk
from lidar.columns import NpyColumns, npy_header
from lidar.units import Units
from pipeline.tiling import Layout

if TYPE_CHECKING:
    import laspy

    from pipeline.executor import DaskExecutor, LocalExecutor
    from pipeline.log import Progress

#: A split on the workers cuts a large file into at least this many ranges (its progress moves by a range).
PROGRESS_RANGES = 10

#: Bytes of tile columns held in memory before they are appended to disk.
SPILL_BYTES = 64 * 2**20


class _Spill:
    """Per-tile columns appended to ``<root>/<tile>[/<part>]/<name>.npy``, buffered in memory up to a budget."""

    def __init__(self, root: Path, budget: int = SPILL_BYTES, part: str | None = None):
        self.root = Path(root)
        self.budget = budget
        self.part = part
        self.pending: dict[int, list[dict[str, np.ndarray]]] = {}
        self.pending_bytes = 0
        self.rows: dict[int, int] = {}
        self.dtypes: dict[str, np.dtype] = {}

    def folder(self, tile: int) -> Path:
        folder = self.root / str(tile)
        return folder if self.part is None else folder / self.part

    def add(self, tile: int, columns: dict[str, np.ndarray]) -> None:
        self.pending.setdefault(tile, []).append(columns)
        self.pending_bytes += sum(a.nbytes for a in columns.values())
        if self.pending_bytes > self.budget:
            self.flush()

    def flush(self) -> None:
        for tile, parts in self.pending.items():
            folder = self.folder(tile)
            new = tile not in self.rows
            folder.mkdir(parents=True, exist_ok=True)
            for name in parts[0]:
                self.dtypes.setdefault(name, parts[0][name].dtype)
                with open(folder / f"{name}.npy", "wb" if new else "ab") as fh:
                    if new:
                        fh.write(b"\0" * NpyColumns.HEADER_BYTES)
                    for part in parts:
                        fh.write(np.ascontiguousarray(part[name]).data)
            self.rows[tile] = self.rows.get(tile, 0) + sum(len(p["core"]) for p in parts)
        self.pending.clear()
        self.pending_bytes = 0

    def close(self) -> dict[int, int]:
        self.flush()
        for tile, rows in self.rows.items():
            for name, dtype in self.dtypes.items():
                with open(self.folder(tile) / f"{name}.npy", "r+b") as fh:
                    fh.write(npy_header(dtype, rows))
        return dict(self.rows)


@dataclass(frozen=True)
class SplitTask:
    """Records ``start:stop`` of the LAS file *path*, to split into the tiles' part *part* (:func:`split_range`).

    The other fields are :func:`split_cloud`'s; *spill*: the bytes of
    columns held before they are appended to disk; *part* None: the tiles'
    own folders (the whole file in one process).
    """

    path: str
    start: int
    stop: int
    layout: Layout
    folder: str
    columns: Callable[[Any], dict[str, np.ndarray]]
    count: Callable[[dict[str, np.ndarray]], Any] | None
    index: bool
    chunk_size: int
    spill: int = SPILL_BYTES
    part: str | None = None


def split_cloud(
    path: Path,
    layout: Layout,
    folder: Path,
    columns: Callable[[Any], dict[str, np.ndarray]],
    *,
    chunk_size: int = 1_000_000,
    progress: Progress | None = None,
    count: Callable[[dict[str, np.ndarray]], Any] | None = None,
    index: bool = True,
    executor: LocalExecutor | DaskExecutor | None = None,
) -> tuple[dict[int, tuple[int, int]], Any]:
    """Write each tile's points (core plus buffer) of the LAS file *path* as ``.npy`` columns under ``folder/<tile>/``.

    Every tile gets ``x``, ``y``, ``z`` in metres, ``core`` and, with
    *index*, ``idx`` (each point's index in the file); ``columns(chunk) ->
    {name: array}`` adds what the tasks need.  ``count(cols)`` is summed
    (``+``) over the chunks; *progress* is advanced by the points read.
    With an *executor* of more than one worker, the records are cut into
    ranges (two per worker, a chunk at least) that the workers split at
    once (:func:`split_range`), each into a part of the tiles' folders;
    *columns* and *count* then travel to them (module-level functions, or
    ``functools.partial`` of one).  Read a tile back with :func:`read_tile`.

    Returns ``(rows, counted)``: tile index -> (points written, of which in
    the core), tiles with none absent; the sum of *count* (None without).
    """
    workers = int(getattr(executor, "workers", 1)) if executor is not None else 1
    with _open_las(path) as reader:
        total = int(reader.header.point_count)
        pieces = min(2 * workers, total // chunk_size) if workers > 1 else 1  # the workers split two chunks or more
        if pieces >= 2:  # then in ten ranges at least (the progress moves by a range), of a tenth of a chunk or more
            pieces = max(pieces, min(PROGRESS_RANGES, total // max(chunk_size // PROGRESS_RANGES, 1)))
        if pieces < 2:  # read here in chunks the progress figure moves by, in a small file too
            read = progress_chunk(total, chunk_size)
            whole = SplitTask(str(path), 0, total, layout, str(folder), columns, count, index, read)
            return _split_records(reader, whole, progress)
    bounds = [total * k // pieces for k in range(pieces + 1)]
    tasks = [
        SplitTask(
            path=str(path),
            start=bounds[k],
            stop=bounds[k + 1],
            layout=layout,
            folder=str(folder),
            columns=columns,
            count=count,
            index=index,
            chunk_size=max(chunk_size // workers, 1),  # the workers' chunks and buffers together: one process's
            spill=SPILL_BYTES // workers,
            part=str(k),
        )
        for k in range(pieces)
    ]
    rows: dict[int, tuple[int, int]] = {}
    counted = None
    advance = (lambda t: progress.update(t.stop - t.start)) if progress is not None else None
    for part_rows, part_counted in executor.map(split_range, tasks, what="tiling", done=advance):
        for t, (n, core) in part_rows.items():
            had = rows.get(t, (0, 0))
            rows[t] = (had[0] + n, had[1] + core)
        if part_counted is not None:
            counted = part_counted if counted is None else counted + part_counted
    return dict(sorted(rows.items())), counted


def split_range(task: SplitTask) -> tuple[dict[int, tuple[int, int]], Any]:
    """Split one range of records into the tiles' part (runs in a worker); its rows and count, as :func:`split_cloud`."""
    with _open_las(Path(task.path)) as reader:
        return _split_records(reader, task)


def _open_las(path: Path):

    return laspy.open(str(path))


def _split_records(
    reader: laspy.LasReader, task: SplitTask, progress: Progress | None = None
) -> tuple[dict[int, tuple[int, int]], Any]:
    """Split the records of *task* from an open LAS *reader* into the tiles (the work of :func:`split_cloud`)."""

    units = Units.of(cloud_crs(reader))
    spill = _Spill(Path(task.folder), task.spill, part=task.part)
    layout = task.layout
    core_rows: dict[int, int] = {}
    counted = None
    start = task.start
    for chunk in record_chunks(reader, task.start, task.stop, task.chunk_size):
        n = len(chunk)
        xyz = chunk_xyz_metres(chunk, units)
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        cols = {"x": x, "y": y, "z": z, **task.columns(chunk)}
        if task.index:
            cols["idx"] = np.arange(start, start + n, dtype=np.int64)
        if task.count is not None:
            counted = task.count(cols) if counted is None else counted + task.count(cols)
        home = layout.locate(x, y)
        point, tile = layout.memberships(x, y)
        cuts = np.flatnonzero(np.diff(tile)) + 1
        for lo, hi in zip(np.r_[0, cuts], np.r_[cuts, len(tile)], strict=True):
            if lo == hi:
                continue
            t = int(tile[lo])
            sel = point[lo:hi]
            piece = {k: np.asarray(v)[sel] for k, v in cols.items()}
            piece["core"] = home[sel] == t
            core_rows[t] = core_rows.get(t, 0) + int(piece["core"].sum())
            spill.add(t, piece)
        start += n
        if progress is not None:
            progress.update(n)
    rows = spill.close()
    return {t: (n, core_rows[t]) for t, n in rows.items()}, counted


def record_chunks(
    reader: laspy.LasReader, start: int, stop: int, chunk_size: int
) -> Iterator[laspy.ScaleAwarePointRecord]:
    """Records ``start:stop`` of an open LAS *reader*, a chunk of at most *chunk_size* at a time.

    Stops early when the file holds fewer records than that (the readers
    check the count first; the caller can compare what it got).
    """
    if start:
        reader.seek(start)
    while start < stop:
        chunk = reader.read_points(min(chunk_size, stop - start))
        if len(chunk) == 0:  # pragma: no cover - fewer records than the header says
            return
        start += len(chunk)
        yield chunk


def tile_parts(folder: Path) -> list[Path]:
    """The folders holding one tile's columns, in file order: the tile's own, or its parts ``0``, ``1``, ...

    :func:`split_cloud` in one process writes a tile's columns into its
    folder; on several workers each range of records goes to a part of its
    own, and the parts read in turn hold the points in the file's order.
    """
    folder = Path(folder)
    parts = sorted((p for p in folder.iterdir() if p.is_dir() and p.name.isdigit()), key=lambda p: int(p.name))
    return parts or [folder]


def read_column(folder: Path, name: str) -> np.ndarray:
    """One column of a tile (:func:`split_cloud`), its parts joined, read into memory."""
    parts = [np.load(p / f"{name}.npy") for p in tile_parts(folder)]
    return parts[0] if len(parts) == 1 else np.concatenate(parts)


def read_xyz(folder: Path) -> np.ndarray:
    """A tile's x, y, z as one (n, 3) array, filled from the mapped columns of its parts (no other copy)."""
    parts = tile_parts(folder)
    cols = [[np.load(p / f"{a}.npy", mmap_mode="r") for a in "xyz"] for p in parts]
    xyz = np.empty((sum(len(c[0]) for c in cols), 3))
    at = 0
    for c in cols:
        for i, a in enumerate(c):
            xyz[at : at + len(a), i] = a
        at += len(c[0])
    return xyz


def read_tile(folder: Path) -> dict[str, np.ndarray]:
    """The columns :func:`split_cloud` wrote for one tile, read into memory, ``x, y, z`` as one (n, 3) ``xyz``."""
    names = sorted(p.stem for p in tile_parts(folder)[0].glob("*.npy"))
    cols = {name: read_column(folder, name) for name in names if name not in ("x", "y", "z")}
    cols["xyz"] = read_xyz(folder)
    return cols


def column_digests(folder: Path, skip: tuple[str, ...] = ()) -> dict[str, str]:
    """SHA-256 of each column of a tile (:func:`split_cloud`), its parts joined; the columns in *skip* left out.

    The values are hashed with their dtype, not the files: the same points
    give the same digests however the split cut them into parts.
    """

    parts = tile_parts(folder)
    out = {}
    for name in sorted(p.stem for p in parts[0].glob("*.npy")):
        if name in skip:
            continue
        digest = hashlib.sha256()
        for i, part in enumerate(parts):
            values = np.load(part / f"{name}.npy")
            if i == 0:
                digest.update(values.dtype.str.encode("ascii"))
            digest.update(np.ascontiguousarray(values).data)
        out[name] = digest.hexdigest()
    return out


def keep_file(src: Path, dst: Path) -> None:
    """Put the file *src* at *dst* (a new name): a hard link where the file system allows, else a copy.

    The tile cache and a stage's workspace are on one file system, and
    neither side writes a kept file again (both write new files).
    """
    try:
        os.link(src, dst)
    except OSError:
        shutil.copyfile(src, dst)


def write_result(folder: Path, **columns: np.ndarray) -> None:
    """Write a task's per-point results (``idx`` ascending plus values) as ``.npy`` files."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, values in columns.items():
        np.save(folder / f"{name}.npy", np.ascontiguousarray(values))


def task_folder(workdir: Path, name: str) -> Path:
    """A fresh folder for tile work inside a stage's workspace (removed by :func:`cleanup`)."""
    folder = Path(workdir) / f".tiles-{name}"
    if folder.exists():
        shutil.rmtree(folder)
    folder.mkdir(parents=True)
    return folder


def cleanup(folder: Path) -> None:
    """Remove a tile work folder (it must not enter the cache entry)."""
    shutil.rmtree(folder, ignore_errors=True)
