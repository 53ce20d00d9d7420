"""Point clouds and rasters cut into the engine's tiles, and put back together.

The engine (:mod:`pipeline.tiling`) cuts a plane into tiles; this module
does the LiDAR side, streaming, so that memory depends on the tile size and
not on the survey:

- :func:`split_cloud` reads a LAS file chunk by chunk and writes, for every
  tile, the columns its task needs (coordinates in metres, classes, ...) of
  the points inside the tile plus its buffer, in file order, with each
  point's index in the file (``idx``) and whether it lies in the tile's core
  (``core``); given the run's executor, its workers split ranges of the
  file's records side by side, each into parts of the tiles
  (:func:`tile_parts`).
- :func:`merge_classes` writes the input file again, chunk by chunk, with
  the classes the tiles computed for their core points: every point is in
  exactly one core, so the output has the input's points in the input's
  order, byte for byte what an untiled run writes.
- :class:`RasterMosaic` assembles rasters from windows (a tiled GeoTIFF on
  disk) and converts them to Cloud Optimized GeoTIFF.

Why tiled and untiled results are identical: every algorithm the tiles run
computes on grids anchored at whole multiples of their cell size (not at the
data's corner), sees the points in the file's order, and gets a buffer at
least as wide as its reach; the same code runs untiled as a single tile.
"""

from __future__ import annotations

import shutil
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from stages.io import HEIGHT, NpyColumns, chunk_xyz_metres, npy_header, open_las_writer

#: Bytes of tile columns held in memory before they are appended to disk.
SPILL_BYTES = 64 * 2**20
#: Values read at a time from each tile's result files while merging.
MERGE_BLOCK = 65_536


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
class CloudInfo:
    """What a LAS file's header says, for cutting it into tiles."""

    extent: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax in metres
    units: Any  # stages.units.Units of its CRS
    crs: Any  # pyproj CRS, or None
    count: int
    dimensions: frozenset[str]


def cloud_info(path: Path) -> CloudInfo:
    """The extent (metres), units, CRS, point count and dimensions a LAS file's header gives."""
    import laspy

    from stages.io import cloud_crs
    from stages.units import Units

    with laspy.open(str(path)) as reader:
        header = reader.header
        crs = cloud_crs(reader)
        units = Units.of(crs)
        lo = units.to_metres(np.array([[header.mins[0], header.mins[1], header.mins[2]]]))[0]
        hi = units.to_metres(np.array([[header.maxs[0], header.maxs[1], header.maxs[2]]]))[0]
        return CloudInfo(
            (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])),
            units,
            crs,
            int(header.point_count),
            frozenset(header.point_format.dimension_names),
        )


def split_cloud(
    path: Path,
    layout,
    folder: Path,
    columns: Callable[[Any], dict[str, np.ndarray]],
    *,
    chunk_size: int = 1_000_000,
    progress=None,
    count: Callable[[dict[str, np.ndarray]], Any] | None = None,
    index: bool = True,
    executor=None,
) -> tuple[dict[int, tuple[int, int]], Any]:
    """Write each tile's points (core plus buffer) as ``.npy`` columns under ``folder/<tile>/``.

    Every tile gets ``x``, ``y``, ``z`` in metres and ``core``; the rest is
    the caller's.  Read a tile back with :func:`tile_parts` (or
    :func:`read_tile`): in one process the columns are in the tile's
    folder; split on an executor's workers they are in one sub-folder per
    range of records (``0``, ``1``, ...), which read in turn give the same
    points in the same order.

    Parameters
    ----------
    path : Path
        The LAS file.
    layout : pipeline.tiling.Layout
        Tiles and buffer, in metres.
    folder : Path
        Where the tiles' folders go.
    columns : callable
        ``columns(chunk) -> {name: array}``: what else the tasks need of a
        chunk of points (laspy record), one value per point.
    chunk_size : int
        Points read at a time.
    progress : Progress, optional
        Advanced by the points read.
    count : callable, optional
        ``count(cols) -> value``, summed (``+``) over the chunks (totals the
        caller checks before running the tasks).
    index : bool
        Write ``idx``, each point's index in the file (for results per
        point; not needed for results per cell).
    executor : LocalExecutor or DaskExecutor, optional
        With more than one worker, the file's records are cut into ranges
        (two per worker, at least *chunk_size* each) that the workers split
        at once, each reading chunks and buffering columns of its share of
        what one process would (memory); *columns* and *count* then travel
        to them, so they must be module-level functions (or
        ``functools.partial`` of one).

    Returns
    -------
    rows : dict
        Tile index -> (points written, of which in the core); tiles with
        none are absent.
    counted : object or None
        The sum of *count* over the chunks.
    """
    from stages.io import cloud_crs

    workers = int(getattr(executor, "workers", 1)) if executor is not None else 1
    with _open_las(path) as reader:
        total = int(reader.header.point_count)
        pieces = min(2 * workers, total // chunk_size) if workers > 1 else 1  # ranges of a chunk at least
        if pieces < 2:
            return _split_records(
                reader, cloud_crs(reader), 0, total, layout, folder, columns, chunk_size, count, index, None, progress
            )
    bounds = [total * k // pieces for k in range(pieces + 1)]
    tasks = [
        {
            "path": str(path),
            "start": bounds[k],
            "stop": bounds[k + 1],
            "layout": layout,
            "folder": str(folder),
            "columns": columns,
            "count": count,
            "index": index,
            "chunk_size": max(chunk_size // workers, 1),  # the workers' chunks and buffers together: one process's
            "spill": SPILL_BYTES // workers,
            "part": str(k),
        }
        for k in range(pieces)
    ]
    rows: dict[int, tuple[int, int]] = {}
    counted = None
    for k, (part_rows, part_counted) in enumerate(executor.map(split_range, tasks, what="tiling")):
        for t, (n, core) in part_rows.items():
            had = rows.get(t, (0, 0))
            rows[t] = (had[0] + n, had[1] + core)
        if part_counted is not None:
            counted = part_counted if counted is None else counted + part_counted
        if progress is not None:
            progress.update(bounds[k + 1] - bounds[k])
    return dict(sorted(rows.items())), counted


def split_range(task: dict) -> tuple[dict[int, tuple[int, int]], Any]:
    """Split records ``start:stop`` of a LAS file into the tiles' part ``task["part"]`` (runs in a worker).

    The task is :func:`split_cloud`'s; returns its rows and count for these records.
    """
    from stages.io import cloud_crs

    with _open_las(Path(task["path"])) as reader:
        return _split_records(
            reader,
            cloud_crs(reader),
            task["start"],
            task["stop"],
            task["layout"],
            Path(task["folder"]),
            task["columns"],
            task["chunk_size"],
            task["count"],
            task["index"],
            task["part"],
            None,
            spill=task["spill"],
        )


def _open_las(path: Path):
    import laspy

    return laspy.open(str(path))


def _split_records(
    reader, crs, start, stop, layout, folder, columns, chunk_size, count, index, part, progress, spill=SPILL_BYTES
):
    """Split records ``start:stop`` of an open LAS *reader* into the tiles (the work of :func:`split_cloud`)."""
    from stages.units import Units

    units = Units.of(crs)
    spill = _Spill(folder, spill, part=part)
    core_rows: dict[int, int] = {}
    counted = None
    for chunk in record_chunks(reader, start, stop, chunk_size):
        n = len(chunk)
        xyz = chunk_xyz_metres(chunk, units)
        x, y, z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
        cols = {"x": x, "y": y, "z": z, **columns(chunk)}
        if index:
            cols["idx"] = np.arange(start, start + n, dtype=np.int64)
        if count is not None:
            counted = count(cols) if counted is None else counted + count(cols)
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


def record_chunks(reader, start: int, stop: int, chunk_size: int):
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


def classes_by_tile(
    ctx,
    src: Path,
    dst: Path,
    *,
    buffer: float,
    columns: Callable[[Any], dict[str, np.ndarray]],
    task: Callable[[dict], dict],
    extra: dict,
    between: Callable[[list[dict], list[dict]], list[dict]] | None = None,
    on_workers: bool = False,
) -> list[dict]:
    """A stage that reclassifies points, tile by tile: *src* copied to *dst* with the tiles' classes.

    Cuts *src* into the run's tiles (:func:`split_cloud`; *columns* adds
    what the task needs), runs *task* on every tile holding points of its
    own (it writes ``idx`` and ``classification`` of its core points with
    :func:`write_result`), optionally *between* (a second round of tasks,
    given the first round's), then :func:`merge_classes`.  Returns the
    tasks' results.  *on_workers*: the split runs on the run's workers
    (*columns* then a module-level function; the task reads the tile's
    parts, :func:`tile_parts`).
    """
    from pipeline.tiling import run_tiled

    info = cloud_info(src)
    work = task_folder(ctx.workdir, ctx.name)

    def split(layout):
        with ctx.progress(info.count, "tiling", unit="pt") as bar:
            executor = ctx.executor if on_workers and len(layout) > 1 else None
            rows, _ = split_cloud(src, layout, work / "in", columns, progress=bar, executor=executor)
        return point_tasks(rows, work, **extra)

    def merge(layout, tasks, results):
        if between is not None:
            results = between(tasks, results)
        with ctx.progress(info.count, "writing", unit="pt") as bar:
            merge_classes(src, dst, [Path(t["result"]) for t in tasks], progress=bar)
        return results

    try:
        return run_tiled(ctx, extent=info.extent, buffer=buffer, split=split, task=task, merge=merge)
    finally:
        cleanup(work)


def point_tasks(rows: dict[int, tuple[int, int]], work: Path, **extra) -> list[dict]:
    """One task per tile holding points of its own (results per point): paths, weight, *extra*."""
    return [
        {
            "tile": t,
            "weight": rows[t][0],
            "source": str(Path(work) / "in" / str(t)),
            "result": str(Path(work) / "out" / str(t)),
            **extra,
        }
        for t in sorted(rows)
        if rows[t][1]  # a tile with no point of its own has nothing to classify
    ]


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


def write_result(folder: Path, **columns: np.ndarray) -> None:
    """Write a task's per-point results (``idx`` ascending plus values) as ``.npy`` files."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for name, values in columns.items():
        np.save(folder / f"{name}.npy", np.ascontiguousarray(values))


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
    progress=None,
) -> None:
    """Copy the LAS *src* to *dst* with the classes of the tiles' results.

    Each result folder holds ``idx`` (ascending) and ``classification`` for
    the core points of one tile; together they cover every point once.
    """
    import laspy

    runs = [_Run(folder, ["classification"]) for folder in results]
    try:
        with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
            start = 0
            for chunk in reader.chunk_iterator(chunk_size):
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


def core_window(grid, tile, layout) -> tuple[int, int, int, int]:
    """Rows and columns ``(r0, r1, c0, c1)`` of *grid* whose cell centres lie in *tile*'s core.

    Cell centres on a core's low edge belong to it, on its high edge to the
    next tile, so the windows of a layout's tiles partition the grid; the
    layout's outer tiles also take the grid's cells beyond it (a grid may
    reach a cell past the points).
    """
    import math

    res = grid.resolution
    c0 = math.ceil((tile.xmin - grid.xmin) / res - 0.5)
    c1 = math.ceil((tile.xmax - grid.xmin) / res - 0.5)
    r0 = math.floor((grid.ymax - tile.ymax) / res - 0.5) + 1
    r1 = math.floor((grid.ymax - tile.ymin) / res - 0.5) + 1
    if tile.col == 0:
        c0 = 0
    if tile.col == layout.cols - 1:
        c1 = grid.cols
    if tile.row == layout.rows - 1:  # northernmost
        r0 = 0
    if tile.row == 0:  # southernmost
        r1 = grid.rows
    return (
        min(max(r0, 0), grid.rows),
        min(max(r1, 0), grid.rows),
        min(max(c0, 0), grid.cols),
        min(max(c1, 0), grid.cols),
    )


class RasterMosaic:
    """A float32 raster assembled from windows on disk, then written as a COG.

    Windows go into a tiled, uncompressed GeoTIFF beside the destination;
    :meth:`finish` converts it with GDAL's COG driver (which streams) and
    removes it.  Windows nobody writes hold *fill*.  *unit* is the band's
    unit type (:func:`stages.io.write_cog`; None for counts).
    """

    def __init__(
        self,
        path: Path,
        *,
        rows: int,
        cols: int,
        transform,
        crs,
        nodata: float,
        fill: float,
        unit: str | None = HEIGHT,
    ):
        import rasterio

        from stages.io import COG_BLOCKSIZE, float_raster_profile, set_unit

        self.path = Path(path)
        self.tmp = self.path.with_name(f".{self.path.name}.mosaic.tif")
        self.rows, self.cols, self.fill = rows, cols, fill
        profile = float_raster_profile(rows, cols, transform=transform, crs=crs, nodata=nodata)
        self.ds = rasterio.open(
            self.tmp,
            "w",
            **profile,
            tiled=True,
            blockxsize=COG_BLOCKSIZE,
            blockysize=COG_BLOCKSIZE,
            BIGTIFF="IF_SAFER",
        )
        set_unit(self.ds, crs, unit)
        self.covered = 0

    def write(self, r0: int, c0: int, array: np.ndarray) -> None:
        from rasterio.windows import Window

        data = np.asarray(array, dtype=np.float32)
        if data.size:
            self.ds.write(data, 1, window=Window(c0, r0, data.shape[1], data.shape[0]))
            self.covered += data.size

    def write_fill(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Fill a window no task wrote (a tile without any point near it)."""
        if r1 > r0 and c1 > c0:
            self.write(r0, c0, np.full((r1 - r0, c1 - c0), self.fill, dtype=np.float32))

    def finish(self) -> None:
        import rasterio

        from stages.io import copy_to_cog

        if self.covered != self.rows * self.cols:  # pragma: no cover - a broken layout, never a user error
            raise RuntimeError(f"mosaic {self.path.name}: {self.covered} of {self.rows * self.cols} cells written")
        self.ds.close()
        with rasterio.Env(GDAL_CACHEMAX=64), rasterio.open(self.tmp) as src:
            copy_to_cog(src, self.path)
        self.tmp.unlink()

    def abort(self) -> None:
        try:
            self.ds.close()
        finally:
            self.tmp.unlink(missing_ok=True)


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
