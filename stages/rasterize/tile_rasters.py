"""The rasters made tile by tile: what the split counts, the tile tasks, and the mosaics of their windows.

Each tile's task (:func:`rasterize_tile`, in a worker) reads its points
(core plus buffer, :func:`lidar.tile_points.split_cloud`), makes the
rasters of its core cells on the survey's grid and writes them as ``.npy``
windows; :func:`mosaic_raster` assembles each raster of the survey from
them as a COG.  A tile's cells are bit for bit those of an untiled run
(:class:`lidar.grid.Grid`'s windows, and a buffer of :func:`reach`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import laspy
import numpy as np
import rasterio

from lidar import glossary
from lidar.arrays import sorted_union
from lidar.grid import Grid, cell_max_count, cell_of
from lidar.memory import free_memory, gigabytes
from lidar.mosaic import RasterMosaic, core_window
from lidar.rasters import HEIGHT, NODATA
from lidar.tile_points import tile_parts
from lidar.units import Units
from lidar.water_bodies import breakline_points, burn_levels, read_breaklines, read_water_bodies
from pipeline.errors import ConfigError, InputDataError
from pipeline.tiling import Layout
from stages.rasterize.interpolators import INTERPOLATORS
from stages.rasterize.outline import Outline, occupied_cells
from stages.rasterize.params import RasterizeParams
from stages.rasterize.products import TileCloud, tile_figures, tile_rasters

if TYPE_CHECKING:
    import laspy
    import pyproj
    from affine import Affine

#: The rasters a run can make, in the order they are made and written.
RASTERS = ("dtm", "dsm", "ndsm", "density", "dtm_uncertainty")
#: Each raster's band description and unit (None: the unit of the CRS's heights).
BANDS = {
    "dtm": ("bare-earth elevation (DTM)", None),
    "dsm": ("highest-surface elevation (DSM)", None),
    "ndsm": ("height above the bare earth (nDSM)", None),
    "density": ("points per cell, all classes but noise and withheld", "points per cell"),
    "dtm_uncertainty": ("vertical uncertainty of the DTM, 1 sigma", None),
}
#: The rasters whose values are heights above a vertical datum (they carry its VERTICAL_DATUM tag).
ELEVATIONS = ("dtm", "dsm")


def reach(params: RasterizeParams, decks: bool = True) -> float:
    """The buffer (metres) a tile needs for its cells to equal the untiled ones.

    The method's reach (its declaration, :mod:`stages.rasterize.interpolators`:
    IDW and nearest use points within ``nodata_distance`` of a cell centre; a
    TIN triangle covering a cell may reach across a gap up to
    ``nodata_distance`` from both sides, twice that), which covers the DSM's
    gap filling (``nodata_distance``), plus two cells.  With bridge decks
    (*decks*: the points hold class 17) and ``bridge_decks``, the cells
    either side of a deck, ``max_deck_width`` more.
    """
    across = params.max_deck_width if params.bridge_decks and decks else 0.0
    return INTERPOLATORS[params.method].reach(params) + 2.0 * params.resolution + across


def has_decks(path: Path, chunk: int = 1_000_000) -> bool:
    """Whether any point of the LAS file *path* is a bridge deck's (class 17).

    Read from the classification byte of its records, mapped (point formats
    0-5 keep the class in its five low bits), when they lie uncompressed
    (the cache's intermediates); otherwise True: the tiles keep the margin
    for decks.
    """

    with laspy.open(str(path)) as reader:
        header = reader.header
        fields = header.point_format.dtype().fields
        offset, size, count = int(header.offset_to_point_data), int(header.point_format.size), int(header.point_count)
    name, mask = ("classification", 0xFF) if "classification" in fields else ("raw_classification", 0x1F)
    if header.are_points_compressed or name not in fields or Path(path).stat().st_size < offset + count * size:
        return True
    at = fields[name][1]
    deck = glossary.BRIDGE_DECK
    for i in range(0, count, chunk):
        # one chunk mapped at a time: a mapping of the whole file held every page it read (2.1 GB more of the
        # process's memory, for a moment, at 100 M points)
        n = min(chunk, count - i)
        records = np.memmap(path, dtype=np.uint8, mode="r", offset=offset + i * size, shape=(n, size))
        found = bool(np.any(records[:, at] & mask == deck))
        del records
        if found:
            return True
    return False


def raster_columns(chunk: laspy.ScaleAwarePointRecord, *, sigma: bool = False) -> dict[str, np.ndarray]:
    """The columns the tiles need besides x, y, z (:func:`lidar.tile_points.split_cloud`): classes, withheld, sigma."""
    cols = {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }
    if sigma:
        cols["sigma_vertical"] = np.asarray(chunk["sigma_vertical"], dtype=np.float64)
    return cols


@dataclass(frozen=True)
class Usable:
    """The class histogram of some points, and the box (metres) of the usable ones: all but noise (7, 18) and withheld.

    :meth:`of` is :func:`lidar.tile_points.split_cloud`'s ``count``; the sum of
    two is the histogram and box of both (the grid is sized by the box).
    """

    classes: np.ndarray  # points per class 0..255
    lo: np.ndarray  # xmin, ymin (inf: none usable)
    hi: np.ndarray  # xmax, ymax
    cells: np.ndarray  # the outline's cells holding a usable point (outline.occupied_cells)

    @classmethod
    def of(cls, cols: dict[str, np.ndarray]) -> Usable:
        usable = glossary.usable(cols["classification"], cols["withheld"])
        lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
        cells = np.zeros(0, dtype=np.int64)
        if usable.any():
            x, y = cols["x"][usable], cols["y"][usable]
            lo, hi = np.array([x.min(), y.min()]), np.array([x.max(), y.max()])
            cells = occupied_cells(x, y)
        return cls(np.bincount(cols["classification"], minlength=256), lo, hi, cells)

    def __add__(self, other: Usable) -> Usable:
        return Usable(
            self.classes + other.classes,
            np.minimum(self.lo, other.lo),
            np.maximum(self.hi, other.hi),
            sorted_union(self.cells, other.cells),
        )

    def box(self) -> tuple[float, float, float, float]:
        if not np.isfinite(self.lo).all():
            raise InputDataError("every point is noise or withheld: there is nothing to grid.")
        return (float(self.lo[0]), float(self.lo[1]), float(self.hi[0]), float(self.hi[1]))


@dataclass(frozen=True)
class RasterTask:
    """One tile's rasters (runs in a worker process or on Dask: :func:`rasterize_tile`).

    *window*: the core's rows and columns ``(r0, r1, c0, c1)`` of the
    survey's *grid*; *source*: the tile's columns; *result*: where its
    ``.npy`` windows go; *weight*: its points; *params*: the stage's
    ``model_dump``; *vertical*: metres per height unit of the CRS;
    *outputs*: the rasters to write; *outline*: the survey's outline
    (:class:`~stages.rasterize.outline.Outline` saved) and its corner;
    *water*: ``water.gpkg`` to flatten the DTM in, *breaklines*:
    ``breaklines.gpkg`` to enforce in its interpolation (*water_digest*:
    the SHA-256 of those over the tile; *water_units*: metres per
    horizontal and vertical unit of their coordinates).
    """

    tile: int
    window: tuple[int, int, int, int]
    weight: int
    source: str
    result: str
    grid: Grid
    params: dict
    buffer: float
    vertical: float
    outputs: tuple[str, ...]
    water: str | None = None
    breaklines: str | None = None
    water_digest: str | None = None
    water_units: tuple[float, float] = (1.0, 1.0)
    outline: tuple[str, int, int] | None = None  # None: no outline

    def inside(self, core: Grid) -> np.ndarray | None:
        """Which of the *core* cells lie inside the survey's outline (None: every one)."""
        if self.outline is None:
            return None
        path, ix0, iy1 = self.outline
        x, y = core.centres()
        return Outline.load(Path(path), ix0, iy1).contains(x, y)


def raster_tasks(
    layout: Layout,
    rows: dict[int, tuple[int, int]],
    grid: Grid,
    work: Path,
    params: dict,
    vertical: float,
    outputs: Sequence[str],
    outline: tuple[str, int, int],
) -> list[RasterTask]:
    """One task per tile holding points (*rows*: :func:`lidar.tile_points.split_cloud`'s), its columns in *work*."""
    return [
        RasterTask(
            tile=tile.index,
            window=core_window(grid, tile, layout),
            weight=rows[tile.index][0],
            source=str(work / "in" / str(tile.index)),
            result=str(work / "out" / str(tile.index)),
            grid=grid,
            params=params,
            buffer=layout.buffer,
            vertical=vertical,
            outputs=tuple(outputs),
            outline=outline,
        )
        for tile in layout.tiles
        if tile.index in rows
    ]


#: Bytes per cell of a tile's wide grid (core plus buffer) while its rasters are made (measured: 84).
TILE_BYTES_PER_CELL = 90
#: Bytes per cell of the TIN's nodata mask, the wide grid plus ``nodata_distance`` all round (measured: 20).
MASK_BYTES_PER_CELL = 24


def tile_memory(task: RasterTask, params: RasterizeParams) -> tuple[int, int, int, int]:
    """Bytes a tile's task holds at its peak for its grid (core and buffer) and the TIN's nodata mask; the mask's size.

    Returns
    -------
    grid_bytes, mask_bytes, rows, cols : int
        The mask's rows and columns are the grid's when there is no mask (not the TIN).
    """
    _, wide, _ = tile_windows(task.grid, task.window, task.buffer)
    rows, cols = wide.rows, wide.cols
    if not INTERPOLATORS[params.method].mask:
        return wide.rows * wide.cols * TILE_BYTES_PER_CELL, 0, rows, cols
    pad = 2 * (int(math.ceil(params.nodata_distance / params.resolution)) + 2)  # the margin of ``_far_from``
    rows, cols = rows + pad, cols + pad
    return wide.rows * wide.cols * TILE_BYTES_PER_CELL, rows * cols * MASK_BYTES_PER_CELL, rows, cols


def check_tile_memory(
    tasks: Sequence[RasterTask], params: RasterizeParams, workers: int, memory: int | None = None
) -> None:
    """Refuse, before any tile is made, tiles the workers could not hold side by side (one sentence, exit 2).

    The key named is ``nodata_distance`` when the TIN's nodata mask takes
    most of it, else ``resolution``.  *memory* (bytes) defaults to
    :func:`lidar.memory.free_memory`.
    """

    if not tasks:
        return
    at_once = max(1, min(workers, len(tasks)))
    grid, mask, rows, cols = max(tile_memory(t, params) for t in tasks)
    need = (grid + mask) * at_once
    memory = free_memory() if memory is None else memory
    if need <= memory:
        return
    tiles = f"about {gigabytes(need)} for {at_once} tile{'s' if at_once > 1 else ''} at a time"
    if mask > grid:
        raise ConfigError(
            f"stages.rasterize.nodata_distance: {params.nodata_distance:g} m around each tile at {params.resolution:g} m "
            f"cells make the TIN's nodata mask {cols:,} x {rows:,} cells, {tiles}, more than the {gigabytes(memory)} "
            "of free memory; use a smaller nodata_distance or a coarser resolution."
        )
    raise ConfigError(
        f"stages.rasterize.resolution: {params.resolution:g} m cells make grids of {cols:,} x {rows:,} cells per tile "
        f"(its buffer and nodata_distance included), {tiles}, more than the {gigabytes(memory)} of free memory; "
        "use a coarser resolution, a smaller tiling.size, or fewer executor.workers."
    )


def rasterize_tile(task: RasterTask) -> dict:
    """The rasters of one tile's core cells, from its points (core plus buffer); its figures.

    Runs in a worker process; writes one ``.npy`` per raster (in the CRS's
    height unit, nodata ``params.nodata``) to ``task.result`` and returns
    :func:`stages.rasterize.products.tile_figures`.
    """
    params = RasterizeParams.model_validate(task.params)
    core, wide, crop = tile_windows(task.grid, task.window, task.buffer)
    cloud = read_tile_cloud(Path(task.source), wide, sigma="dtm_uncertainty" in task.outputs)
    flat, breaklines = None, None
    if task.water is not None:
        units = Units(*task.water_units)
        bodies = read_water_bodies(Path(task.water), units)

        def flat(grid: Grid) -> np.ndarray:
            return burn_levels(bodies, (grid.rows, grid.cols), grid.transform)

        if task.breaklines is not None:
            lines = read_breaklines(Path(task.breaklines), units)
            breaklines = breakline_points(lines, params.resolution)
            breaklines = breaklines[cell_of(breaklines, wide)[0] >= 0]  # the tile's, core and buffer
    rasters = tile_rasters(cloud, core, wide, crop, params, task.inside(core), flat=flat, breaklines=breaklines)
    vertical = task.vertical
    folder = Path(task.result)
    folder.mkdir(parents=True, exist_ok=True)
    for name in task.outputs:
        values = rasters[name] if name == "density" else rasters[name] / vertical
        nodata = NODATA if params.nodata is None else params.nodata
        np.save(folder / f"{name}.npy", np.where(np.isnan(values), nodata, values).astype(np.float32))
    return {"tile": task.tile, **tile_figures(rasters, vertical)}


def tile_windows(
    grid: Grid, window: tuple[int, int, int, int], buffer: float
) -> tuple[Grid, Grid, tuple[slice, slice]]:
    """The tile's core cells (*window* of *grid*), its wide grid (the core plus *buffer*), and the core's slice of it."""
    r0, r1, c0, c1 = window
    core = grid.window(r0, r1, c0, c1)
    pad = int(math.ceil(buffer / grid.resolution))
    br0, br1 = max(r0 - pad, 0), min(r1 + pad, grid.rows)
    bc0, bc1 = max(c0 - pad, 0), min(c1 + pad, grid.cols)
    wide = grid.window(br0, br1, bc0, bc1)
    crop = (slice(r0 - br0, r1 - br0), slice(c0 - bc0, c1 - bc0))
    return core, wide, crop


def read_tile_cloud(folder: Path, wide: Grid, *, sigma: bool) -> TileCloud:
    """What a tile's rasters need of its points (:class:`TileCloud`), read part by part, in file order.

    The coordinates are mapped, not read: only the rows each raster needs
    are in memory.
    """

    parts = tile_parts(folder)  # the tile's points in file order, a range of records each
    masks = []
    for part in parts:
        cls = np.load(part / "classification.npy")
        usable = glossary.usable(cls, np.load(part / "withheld.npy"))
        masks.append((np.isin(cls, glossary.BARE_EARTH), usable, usable & (cls == glossary.BRIDGE_DECK)))
    del cls
    ground = np.empty((sum(int(is_ground.sum()) for is_ground, _, _ in masks), 3))
    highest = count = decks = None
    sigma_parts = []
    at = 0
    for part, (is_ground, usable, deck) in zip(parts, masks, strict=True):
        xyz = [np.load(part / f"{a}.npy", mmap_mode="r") for a in "xyz"]
        # core cells are wide cells; every point usable (the usual case): the mapped columns as they are
        high, n = cell_max_count(xyz if usable.all() else [a[usable] for a in xyz], wide)
        highest, count = (high, n) if highest is None else (np.fmax(highest, high), count + n)
        if deck.any():  # bridge-deck points per cell, for the ground under the decks
            n = cell_max_count([a[deck] for a in xyz], wide)[1]
            decks = n if decks is None else decks + n
        k = int(is_ground.sum())
        for i, a in enumerate(xyz):
            ground[at : at + k, i] = a[is_ground]
        at += k
        if sigma:
            sigma_parts.append(np.load(part / "sigma_vertical.npy", mmap_mode="r")[is_ground])
        del xyz, high, n
    del masks
    if sigma:
        sigmas = sigma_parts[0] if len(sigma_parts) == 1 else np.concatenate(sigma_parts)
        return TileCloud(ground, highest, count, sigmas, decks)
    return TileCloud(ground, highest, count, decks=decks)


@dataclass(frozen=True)
class MosaicJob:
    """One raster of the survey to assemble from its tiles' windows (runs in a worker: :func:`mosaic_raster`).

    *path*, *rows*, *cols*, *transform*, *crs*, *nodata*, *fill*, *unit*, *description*, *tags*: those of
    :class:`lidar.mosaic.RasterMosaic`; *windows*: ``((r0, r1, c0,
    c1), npy file)`` of each tile; *empty*: the windows no tile wrote;
    *cache_mb*: GDAL's block cache.
    """

    path: str
    rows: int
    cols: int
    transform: Any
    crs: Any
    nodata: float
    fill: float
    unit: str | None
    description: str
    tags: dict[str, str]
    windows: tuple[tuple[tuple[int, int, int, int], str], ...]
    empty: tuple[tuple[int, int, int, int], ...]
    cache_mb: int


def mosaic_jobs(
    paths: dict[str, Path],
    grid: Grid,
    transform: Affine,
    crs: pyproj.CRS | None,
    layout: Layout,
    tasks: list[RasterTask],
    cache_mb: int,
    nodata: float,
    tags: dict[str, str],
) -> list[MosaicJob]:
    """One job per raster of *paths* (name -> file): the windows of *tasks*, and fill for the tiles without one.

    The elevation rasters (:data:`ELEVATIONS`) carry the metadata *tags* (their vertical datum).
    """
    done = {t.tile for t in tasks}
    empty = tuple(core_window(grid, tile, layout) for tile in layout.tiles if tile.index not in done)
    return [
        MosaicJob(
            path=str(path),
            rows=grid.rows,
            cols=grid.cols,
            transform=transform,
            crs=crs,
            nodata=nodata,
            fill=0.0 if name == "density" else nodata,
            unit=BANDS[name][1] or HEIGHT,
            description=BANDS[name][0],
            tags=tags if name in ELEVATIONS else {},
            windows=tuple((t.window, str(Path(t.result) / f"{name}.npy")) for t in tasks),
            empty=empty,
            cache_mb=cache_mb,
        )
        for name, path in paths.items()
    ]


def mosaic_raster(job: MosaicJob) -> None:
    """Assemble one raster of the survey from its tiles' windows and write it as a COG (runs in a worker)."""

    # GDAL's block cache, 64 MB for all the workers at once: its default, 5 % of the RAM, would grow with the grid
    with rasterio.Env(GDAL_CACHEMAX=job.cache_mb):
        mosaic = RasterMosaic(
            Path(job.path),
            rows=job.rows,
            cols=job.cols,
            transform=job.transform,
            crs=job.crs,
            nodata=job.nodata,
            fill=job.fill,
            unit=job.unit,
            description=job.description,
            tags=job.tags,
        )
        try:
            for (r0, _, c0, _), values in job.windows:
                mosaic.write(r0, c0, np.load(values))
            for window in job.empty:
                mosaic.write_fill(*window)
            mosaic.finish()
        except BaseException:
            mosaic.abort()
            raise
