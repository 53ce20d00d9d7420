"""Rasters of the survey assembled from its tiles' windows.

:func:`core_window` gives the cells of a tile's core on the survey's grid
(the windows of a layout's tiles partition it); :class:`RasterMosaic` writes
the windows into one raster and converts it to a Cloud Optimized GeoTIFF.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import rasterio
from rasterio.windows import Window

from lidar.rasters import COG_BLOCKSIZE, HEIGHT, copy_to_cog, describe_band, float_raster_profile

if TYPE_CHECKING:
    import pyproj
    from affine import Affine

    from lidar.grid import Grid
    from pipeline.tiling import Layout, Tile


def core_window(grid: Grid, tile: Tile, layout: Layout) -> tuple[int, int, int, int]:
    """Rows and columns ``(r0, r1, c0, c1)`` of *grid* whose cell centres lie in *tile*'s core.

    Cell centres on a core's low edge belong to it, on its high edge to the
    next tile, so the windows of a layout's tiles partition the grid; the
    layout's outer tiles also take the grid's cells beyond it (a grid may
    reach a cell past the points).
    """
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
    unit type, *description* its description and *tags* the dataset's metadata
    (:func:`lidar.rasters.write_cog`).
    """

    def __init__(
        self,
        path: Path,
        *,
        rows: int,
        cols: int,
        transform: Affine,
        crs: pyproj.CRS | None,
        nodata: float,
        fill: float,
        unit: str | None = HEIGHT,
        description: str | None = None,
        tags: dict[str, str] | None = None,
    ):
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
        describe_band(self.ds, crs, unit, description, tags)
        self.covered = 0

    def write(self, r0: int, c0: int, array: np.ndarray) -> None:
        data = np.asarray(array, dtype=np.float32)
        if data.size:
            self.ds.write(data, 1, window=Window(c0, r0, data.shape[1], data.shape[0]))
            self.covered += data.size

    def write_fill(self, r0: int, r1: int, c0: int, c1: int) -> None:
        """Fill a window no task wrote (a tile without any point near it)."""
        if r1 > r0 and c1 > c0:
            self.write(r0, c0, np.full((r1 - r0, c1 - c0), self.fill, dtype=np.float32))

    def finish(self) -> None:
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
