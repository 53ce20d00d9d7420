"""Stage ``export_tiles``: large elevation rasters as square GeoTIFF tiles plus a GDAL VRT mosaic.

Runs when ``stages.export_tiles.tile_size`` is set.  For each raster of
``rasters`` (default ``[dtm]``; ``dsm`` and ``ndsm`` on request) it writes

- ``tiles/<raster>/<raster>_<E>_<N>.tif``: Cloud Optimized GeoTIFFs (the
  same format as ``dtm.tif``: float32, DEFLATE with the floating-point
  predictor, overviews, nodata −9999, the CRS as WKT, the band's unit) of
  ``tile_size`` × ``tile_size`` on a grid aligned to whole multiples of the
  tile side, named by their lower-left corner (E, N in the CRS's unit), so
  tiles of neighbouring surveys and of later runs have the same names and
  edges.  Every tile has the full size (cells outside the survey's raster
  are nodata); tiles without a valid cell are not written.
- ``<raster>.vrt``: a GDAL virtual mosaic of the tiles (one
  ``SimpleSource`` a tile, paths relative to the VRT) with the extent,
  GeoTransform, CRS, nodata value and unit of the untiled raster, so GDAL,
  QGIS and rasterio read it as that raster, cell for cell.

The VRT is written by hand (the format is plain XML:
https://gdal.org/en/stable/drivers/raster/vrt.html) rather than by
``gdalbuildvrt``, which is not a Python dependency here.  Tiles are read
window by window from the untiled raster, so memory holds one tile.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import ClassVar, Literal
from xml.sax.saxutils import escape

import numpy as np
from pydantic import Field

from dtm.common.rasters import NODATA
from pipeline.errors import ConfigError
from pipeline.stage import Stage, StageContext, StageIO, StageParams

#: rasters that can be tiled
TILED = ("dtm", "dsm", "ndsm")


class ExportTilesParams(StageParams):
    tile_size: float | None = Field(
        None,
        ge=1.0,
        description="side of the tiles, metres, a whole number of raster cells (e.g. 1000); none (default) = no "
        "tiles: the rasters stay single files",
    )
    rasters: list[Literal["dtm", "dsm", "ndsm"]] = Field(
        ["dtm"], min_length=1, description="rasters written as tiles, each with its VRT: dtm, dsm, ndsm"
    )


def tile_cells(tile_size_m: float, resolution_m: float) -> int:
    """Cells on a tile's side: *tile_size_m* must be a whole number of cells of *resolution_m*.

    >>> tile_cells(1000.0, 0.5)
    2000
    """
    k = round(tile_size_m / resolution_m)
    if k < 1 or abs(k * resolution_m - tile_size_m) > 1e-6 * tile_size_m:
        raise ConfigError(
            f"stages.export_tiles.tile_size {tile_size_m:g} m is not a whole number of cells of "
            f"stages.rasterize.resolution {resolution_m:g} m: choose a multiple of the resolution."
        )
    return k


def corner_name(value: float) -> str:
    """A tile corner coordinate as it appears in a file name: whole units plain, else 3 decimals.

    >>> corner_name(440000.0), corner_name(1640416.6666667)
    ('440000', '1640416.667')
    """
    if abs(value - round(value)) < 1e-6:
        return str(int(round(value)))
    return f"{value:.3f}"


def write_tiles(src: Path, folder: Path, vrt: Path, name: str, cells: int, folder_in_vrt: str) -> list[dict]:
    """Cut the raster *src* into tiles of *cells* × *cells* in *folder*, and write the VRT *vrt*.

    Parameters
    ----------
    src : Path
        A north-up single-band GeoTIFF.
    folder : Path
        Where the tiles go (created).
    vrt : Path
        The VRT mosaic to write.
    name : str
        Prefix of the tile names (``dtm``).
    cells : int
        Cells on a tile's side.
    folder_in_vrt : str
        *folder* as the VRT names it, relative to the VRT's folder.

    Returns
    -------
    list of dict
        One per tile written: ``file``, ``lower_left`` (E, N), ``valid_cells``.
    """
    import rasterio
    from rasterio.windows import Window

    from dtm.common.rasters import write_cog

    folder.mkdir(parents=True, exist_ok=True)
    tiles = []
    sources = []
    with rasterio.open(src) as ds:
        t = ds.transform
        if t.b != 0 or t.d != 0 or t.e >= 0:
            raise ValueError(f"{src}: not a north-up raster")
        cell = t.a
        side = cells * cell
        nodata = NODATA if ds.nodata is None else ds.nodata
        unit = ds.units[0] if ds.units and ds.units[0] else None
        left, top = t.c, t.f
        right, bottom = left + ds.width * cell, top + t.e * ds.height
        # tile columns / rows on the grid of multiples of the tile side (cells of dtm.tif lie on multiples of
        # the cell, so tile edges are cell edges); the small tolerance absorbs the rounding of the corners
        eps = 1e-9 * max(1.0, abs(left), abs(top))
        i0, i1 = math.floor((left + eps) / side), math.ceil((right - eps) / side)
        j0, j1 = math.floor((bottom + eps) / side), math.ceil((top - eps) / side)
        for j in range(j1 - 1, j0 - 1, -1):  # north to south
            for i in range(i0, i1):
                x0, y0 = i * side, j * side  # lower-left corner
                col0 = int(round((x0 - left) / cell))  # tile's first column in the raster (may be < 0)
                row0 = int(round((top - (y0 + side)) / cell))
                c_lo, c_hi = max(col0, 0), min(col0 + cells, ds.width)
                r_lo, r_hi = max(row0, 0), min(row0 + cells, ds.height)
                if c_lo >= c_hi or r_lo >= r_hi:
                    continue
                part = ds.read(1, window=Window(c_lo, r_lo, c_hi - c_lo, r_hi - r_lo))
                valid = int(np.count_nonzero(part != nodata))
                if valid == 0:
                    continue
                block = np.full((cells, cells), nodata, dtype=np.float32)
                block[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0] = part
                fname = f"{name}_{corner_name(x0)}_{corner_name(y0)}.tif"
                transform = rasterio.Affine(cell, 0.0, x0, 0.0, -cell, y0 + side)
                write_cog(folder / fname, block, transform=transform, crs=ds.crs.to_wkt(), nodata=nodata, unit=unit)
                tiles.append({"file": fname, "lower_left": [x0, y0], "valid_cells": valid})
                sources.append(
                    _source(
                        f"{folder_in_vrt}/{fname}",
                        cells,
                        (c_lo - col0, r_lo - row0, c_hi - c_lo, r_hi - r_lo),
                        (c_lo, r_lo, c_hi - c_lo, r_hi - r_lo),
                    )
                )
        vrt.write_text(_vrt(ds, nodata, unit, sources), encoding="utf-8")
    return tiles


def _source(path: str, cells: int, src_rect: tuple[int, ...], dst_rect: tuple[int, ...]) -> str:
    sx, sy, sw, sh = src_rect
    dx, dy, dw, dh = dst_rect
    return (
        "    <SimpleSource>\n"
        f'      <SourceFilename relativeToVRT="1">{escape(path)}</SourceFilename>\n'
        "      <SourceBand>1</SourceBand>\n"
        f'      <SourceProperties RasterXSize="{cells}" RasterYSize="{cells}" DataType="Float32" '
        'BlockXSize="256" BlockYSize="256"/>\n'
        f'      <SrcRect xOff="{sx}" yOff="{sy}" xSize="{sw}" ySize="{sh}"/>\n'
        f'      <DstRect xOff="{dx}" yOff="{dy}" xSize="{dw}" ySize="{dh}"/>\n'
        "    </SimpleSource>\n"
    )


def _vrt(ds, nodata: float, unit: str | None, sources: list[str]) -> str:
    t = ds.transform
    geotransform = ", ".join(repr(float(v)) for v in (t.c, t.a, t.b, t.f, t.d, t.e))
    unit_xml = f"    <UnitType>{escape(unit)}</UnitType>\n" if unit else ""
    return (
        f'<VRTDataset rasterXSize="{ds.width}" rasterYSize="{ds.height}">\n'
        f'  <SRS dataAxisToSRSAxisMapping="1,2">{escape(ds.crs.to_wkt())}</SRS>\n'
        f"  <GeoTransform>{geotransform}</GeoTransform>\n"
        '  <VRTRasterBand dataType="Float32" band="1">\n'
        f"    <NoDataValue>{nodata!r}</NoDataValue>\n"
        f"{unit_xml}"
        f"{''.join(sources)}"
        "  </VRTRasterBand>\n"
        "</VRTDataset>\n"
    )


class ExportTiles(Stage):
    name = "export_tiles"
    version = "1"
    Params = ExportTilesParams
    description = "DTM (and DSM, nDSM) as GeoTIFF tiles plus a VRT mosaic, when tile_size is set"
    inputs = ("dtm",)
    outputs: ClassVar = {"tiles": "tiles", "dtm_vrt": "dtm.vrt"}
    products: ClassVar = {"tiles": "tiles", "dtm_vrt": "dtm.vrt"}
    config_keys = ("stages.rasterize.resolution",)

    def is_enabled(self, params, config) -> bool:
        return bool(params.enabled) and params.tile_size is not None

    def declare(self, params, config) -> StageIO:
        if params.tile_size is not None:
            tile_cells(params.tile_size, config.stages.rasterize.resolution)  # a ConfigError before anything runs
        rasters = list(dict.fromkeys(params.rasters))
        outputs = {"tiles": "tiles", **{f"{r}_vrt": f"{r}.vrt" for r in rasters}}
        return StageIO(tuple(rasters), outputs, dict(outputs))

    def run(self, ctx: StageContext[ExportTilesParams]) -> None:
        p = ctx.params
        cells = tile_cells(p.tile_size, ctx.setting("stages.rasterize.resolution"))
        root = ctx.outputs["tiles"]
        root.mkdir(parents=True, exist_ok=True)
        counts = {}
        for raster in dict.fromkeys(p.rasters):
            tiles = write_tiles(
                ctx.inputs[raster], root / raster, ctx.outputs[f"{raster}_vrt"], raster, cells, f"tiles/{raster}"
            )
            counts[raster] = len(tiles)
            ctx.log.info("%s: %d tiles of %d x %d cells, %s.vrt", raster, len(tiles), cells, cells, raster)
        ctx.metrics.update(tile_cells=cells, tiles=counts)
