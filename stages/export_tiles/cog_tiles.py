"""A north-up raster cut into square COG tiles on a grid of whole tile sides, plus a GDAL VRT mosaic.

Tiles are named by their lower-left corner and read window by window from the
untiled raster (memory holds one tile); the VRT is plain XML written by hand.
The format and the reasons: docs/stages/export_tiles.md.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING
from xml.sax.saxutils import escape

import numpy as np
import rasterio
from rasterio.windows import Window

from lidar.rasters import NODATA, write_cog
from pipeline.errors import ConfigError

if TYPE_CHECKING:
    from collections.abc import Callable

    from affine import Affine


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


def tile_corners(transform: Affine, width: int, height: int, side: float) -> list[tuple[float, float]]:
    """Lower-left corners of the tiles of *side* that touch the raster, north to south, west to east.

    Tiles lie on the grid of whole multiples of *side* (cells of ``dtm.tif``
    lie on multiples of the cell, so tile edges are cell edges).
    """
    cell = transform.a
    left, top = transform.c, transform.f
    right, bottom = left + width * cell, top + transform.e * height
    # the small tolerance absorbs the rounding of the corners
    eps = 1e-9 * max(1.0, abs(left), abs(top))
    i0, i1 = math.floor((left + eps) / side), math.ceil((right - eps) / side)
    j0, j1 = math.floor((bottom + eps) / side), math.ceil((top - eps) / side)
    return [(i * side, j * side) for j in range(j1 - 1, j0 - 1, -1) for i in range(i0, i1)]


def tile_count(src: Path, cells: int) -> int:
    """How many tiles of *cells* × *cells* touch the GeoTIFF *src* (:func:`write_tiles` tries each)."""
    with rasterio.open(src) as ds:
        return len(tile_corners(ds.transform, ds.width, ds.height, cells * ds.transform.a))


def write_tiles(
    src: Path,
    folder: Path,
    vrt: Path,
    name: str,
    cells: int,
    folder_in_vrt: str,
    advance: Callable[[int], object] | None = None,
) -> list[dict]:
    """Cut the north-up single-band GeoTIFF *src* into tiles of *cells* × *cells*, and write the VRT *vrt*.

    The tiles go to *folder* (created), named ``<name>_<E>_<N>.tif``; the VRT
    names that folder *folder_in_vrt* (relative to the VRT's folder).
    *advance* is told each tile done (written, or left out: no valid cell).

    Returns
    -------
    list of dict
        One per tile written: ``file``, ``lower_left`` (E, N), ``valid_cells``.
    """
    folder.mkdir(parents=True, exist_ok=True)
    tiles = []
    sources = []
    with rasterio.open(src) as ds:
        t = ds.transform
        if t.b != 0 or t.d != 0 or t.e >= 0:
            raise ValueError(f"{src}: not a north-up raster")
        nodata = NODATA if ds.nodata is None else ds.nodata
        unit = ds.units[0] if ds.units and ds.units[0] else None
        for corner in tile_corners(t, ds.width, ds.height, cells * t.a):
            written = _write_tile(ds, corner, cells, folder / name, nodata, unit)
            if advance is not None:
                advance(1)
            if written is None:
                continue
            tile, src_rect, dst_rect = written
            tiles.append(tile)
            sources.append(_source(f"{folder_in_vrt}/{tile['file']}", cells, src_rect, dst_rect))
        vrt.write_text(_vrt(ds, nodata, unit, sources), encoding="utf-8")
    return tiles


def _write_tile(ds, corner: tuple[float, float], cells: int, prefix: Path, nodata: float, unit: str | None):
    """Write the tile of lower-left *corner* (``<prefix>_<E>_<N>.tif``) from the open raster *ds*.

    Returns its record and its source and destination rectangles in the VRT
    (x, y, width, height in cells), or None when it holds no valid cell (not written).
    """
    t = ds.transform
    cell = t.a
    side = cells * cell
    x0, y0 = corner
    col0 = int(round((x0 - t.c) / cell))  # tile's first column in the raster (may be < 0)
    row0 = int(round((t.f - (y0 + side)) / cell))
    c_lo, c_hi = max(col0, 0), min(col0 + cells, ds.width)
    r_lo, r_hi = max(row0, 0), min(row0 + cells, ds.height)
    if c_lo >= c_hi or r_lo >= r_hi:
        return None
    part = ds.read(1, window=Window(c_lo, r_lo, c_hi - c_lo, r_hi - r_lo))
    valid = int(np.count_nonzero(part != nodata))
    if valid == 0:
        return None
    block = np.full((cells, cells), nodata, dtype=np.float32)
    block[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0] = part
    fname = f"{prefix.name}_{corner_name(x0)}_{corner_name(y0)}.tif"
    transform = rasterio.Affine(cell, 0.0, x0, 0.0, -cell, y0 + side)
    write_cog(
        prefix.parent / fname,
        block,
        transform=transform,
        crs=ds.crs.to_wkt(),
        nodata=nodata,
        unit=unit,
        description=ds.descriptions[0],
        tags={k: v for k, v in ds.tags().items() if k != "AREA_OR_POINT"},
    )
    tile = {"file": fname, "lower_left": [x0, y0], "valid_cells": valid}
    return tile, (c_lo - col0, r_lo - row0, c_hi - c_lo, r_hi - r_lo), (c_lo, r_lo, c_hi - c_lo, r_hi - r_lo)


def _source(path: str, cells: int, src_rect: tuple[int, ...], dst_rect: tuple[int, ...]) -> str:
    """One tile of the VRT: a ``SimpleSource`` with its rectangles."""
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
    """The VRT document: the untiled raster's size, GeoTransform, CRS, metadata, nodata, unit and description,
    and the tiles."""
    t = ds.transform
    geotransform = ", ".join(repr(float(v)) for v in (t.c, t.a, t.b, t.f, t.d, t.e))
    unit_xml = f"    <UnitType>{escape(unit)}</UnitType>\n" if unit else ""
    description = ds.descriptions[0]
    described = f"    <Description>{escape(description)}</Description>\n" if description else ""
    items = "".join(
        f'    <MDI key="{escape(k)}">{escape(v)}</MDI>\n' for k, v in ds.tags().items() if k != "AREA_OR_POINT"
    )
    metadata = f"  <Metadata>\n{items}  </Metadata>\n" if items else ""
    return (
        f'<VRTDataset rasterXSize="{ds.width}" rasterYSize="{ds.height}">\n'
        f'  <SRS dataAxisToSRSAxisMapping="1,2">{escape(ds.crs.to_wkt())}</SRS>\n'
        f"  <GeoTransform>{geotransform}</GeoTransform>\n"
        f"{metadata}"
        '  <VRTRasterBand dataType="Float32" band="1">\n'
        f"{described}"
        f"    <NoDataValue>{float(nodata)!r}</NoDataValue>\n"
        f"{unit_xml}"
        f"{''.join(sources)}"
        "  </VRTRasterBand>\n"
        "</VRTDataset>\n"
    )
