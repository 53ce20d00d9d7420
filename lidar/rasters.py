"""Rasters: Cloud Optimized GeoTIFF writing and reading, PNG images, colour ramps.

COG: float32, internal 256-pixel tiles, DEFLATE with the floating-point
predictor, overviews, explicit nodata; an elevation raster names its unit
(the band's unit type: the unit of the CRS's vertical axis, else of its
horizontal axes, :mod:`lidar.units`), and a compound CRS is written
whole (GDAL writes its vertical part as the GeoTIFF's vertical CRS).
Images meant for the eye (the hillshade) are Byte with nodata 0.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import rasterio
import rasterio.shutil
from rasterio.errors import NotGeoreferencedWarning
from rasterio.io import MemoryFile

from lidar.units import raster_units

#: Nodata value of the float rasters (documented in docs/PRODUCTS.md) but the DEMs of a USGS LBS deliverable.
NODATA = -9999.0
#: Nodata value of the DEM the USGS Lidar Base Specification asks for (GeoTIFF, 32-bit float, GDAL_NODATA tag):
#: ``rasterize``'s rasters when ``stages.report.specification`` is an LBS quality level.
LBS_NODATA = -999999.0


def dem_nodata(specification: str | None, configured: float | None = None) -> float:
    """The nodata value of the elevation rasters: *configured* (``stages.rasterize.nodata``) when given, else
    the one for acceptance against *specification* (a report specification name).

    >>> dem_nodata("usgs-lbs-ql2"), dem_nodata("asprs-2023-10cm"), dem_nodata("usgs-lbs-ql2", -32767)
    (-999999.0, -9999.0, -32767.0)
    """
    if configured is not None:
        return float(configured)
    return LBS_NODATA if (specification or "").startswith("usgs-lbs") else NODATA


#: Internal tile size of the Cloud Optimized GeoTIFFs.
COG_BLOCKSIZE = 256


#: ``unit`` value meaning "heights in the CRS's vertical unit" (an elevation raster).
HEIGHT = "height"


def read_raster(path: Path):
    """Band 1 as float64 with NaN for nodata, and the raster's transform, CRS and cell size."""
    with rasterio.open(path) as ds:
        band = ds.read(1).astype(np.float64)
        if ds.nodata is not None:
            band[band == ds.nodata] = np.nan
        return band, ds.transform, ds.crs, ds.res[0]


def write_cog(
    path: Path,
    array: np.ndarray,
    *,
    transform,
    crs,
    nodata: float = NODATA,
    dtype: str = "float32",
    unit: str | None = HEIGHT,
    description: str | None = None,
    tags: dict[str, str] | None = None,
) -> None:
    """Write a single-band Cloud Optimized GeoTIFF (float32 unless *dtype* says ``uint8``).

    *array* (rows, cols) holds *nodata* (not NaN) in empty cells; *transform*
    is north-up; *crs* (pyproj or a string) is written as WKT.  *unit* is the
    band's unit type: :data:`HEIGHT` for the unit of the CRS's heights
    (:func:`height_unit`), a name, or None.  *description* is the band's
    description, *tags* the dataset's metadata (:func:`describe_band`).
    """
    data = np.asarray(array, dtype=dtype)
    rows, cols = data.shape
    profile = float_raster_profile(rows, cols, transform=transform, crs=crs, nodata=nodata, dtype=dtype)
    with MemoryFile() as mem:
        with mem.open(**profile) as ds:
            ds.write(data, 1)
            describe_band(ds, crs, unit, description, tags)
        with mem.open() as src:
            copy_to_cog(src, path)


def height_unit(crs) -> str:
    """The name of the unit heights are in, in *crs* (a pyproj, rasterio or WKT CRS): 'metre', 'foot', ..."""
    return raster_units(crs).vertical_name


#: The metadata item of an elevation raster that names its heights' vertical datum (:class:`lidar.crs.Heights`).
VERTICAL_DATUM = "VERTICAL_DATUM"


def describe_band(
    ds, crs, unit: str | None, description: str | None = None, tags: dict[str, str] | None = None
) -> None:
    """Set band 1's unit type and description, and the dataset's metadata *tags*, of the writable *ds*.

    GDAL's COG driver copies all three; ``gdalinfo`` shows them and QGIS
    labels the band with the description.  See :func:`write_cog`.
    """
    if unit is not None:
        ds.units = (height_unit(crs) if unit == HEIGHT else unit,)
    if description:
        ds.set_band_description(1, description)
    if tags:
        ds.update_tags(**tags)


def float_raster_profile(
    rows: int, cols: int, *, transform, crs, nodata: float = NODATA, dtype: str = "float32"
) -> dict:
    """The rasterio profile of a single-band GeoTIFF, float32 by default (CRS written as WKT)."""
    wkt = crs.to_wkt() if hasattr(crs, "to_wkt") else str(crs)
    return {
        "driver": "GTiff",
        "width": cols,
        "height": rows,
        "count": 1,
        "dtype": dtype,
        "crs": rasterio.crs.CRS.from_wkt(wkt),
        "transform": transform,
        "nodata": nodata,
    }


def copy_to_cog(src, path: Path) -> None:
    """Write the open dataset *src* to *path* as a Cloud Optimized GeoTIFF (GDAL's COG driver, streaming).

    GDAL's block cache is held to 64 MB here: its default, 5 % of the
    machine's memory, took 65 MB more for a 12.8-million-cell grid.
    """
    with rasterio.Env(GDAL_CACHEMAX=64):
        rasterio.shutil.copy(
            src,
            str(path),
            driver="COG",
            COMPRESS="DEFLATE",
            PREDICTOR="YES",
            BLOCKSIZE=str(COG_BLOCKSIZE),
            OVERVIEW_RESAMPLING="AVERAGE",
            BIGTIFF="IF_SAFER",
            NUM_THREADS="ALL_CPUS",
        )


def png_bytes(image: np.ndarray) -> bytes:
    """Encode a (rows, cols) or (rows, cols, 3) uint8 image as PNG (GDAL's PNG driver)."""
    warnings.filterwarnings("ignore", category=NotGeoreferencedWarning)
    img = np.asarray(image, dtype=np.uint8)
    bands = img[np.newaxis] if img.ndim == 2 else np.moveaxis(img, -1, 0)
    with MemoryFile() as mem:
        with mem.open(
            driver="PNG", width=bands.shape[2], height=bands.shape[1], count=bands.shape[0], dtype="uint8"
        ) as ds:
            ds.write(bands)
        return mem.read()


def colour_ramp(values: np.ndarray, ramp, lo: float, hi: float) -> np.ndarray:
    """Map values to RGB along a ramp; NaN -> white."""
    t = np.clip((values - lo) / (hi - lo if hi > lo else 1.0), 0.0, 1.0)
    pos = np.array([p for p, _ in ramp])
    out = np.empty(values.shape + (3,))
    for channel in range(3):
        out[..., channel] = np.interp(t, pos, [c[channel] for _, c in ramp])
    out[~np.isfinite(values)] = 255.0
    return out
