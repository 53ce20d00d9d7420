"""Stages ``hillshade`` and ``contours``: map products derived from the DTM.

- ``hillshade``: ``hillshade.tif`` (COG, Byte: shades 1-255, nodata 0, as
  ``gdaldem hillshade`` writes it) and ``hillshade.png`` (the same bytes,
  nodata black), Horn's method.
- ``contours``: ``contours.gpkg``, a GeoPackage layer ``contours`` of line
  strings with an ``elevation`` attribute, every ``interval`` metres; lines
  and elevations in the CRS's units (:mod:`stages.units`).

Separate stages so that restyling them never re-grids the DTM.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from pipeline.stage import Stage, StageParams
from stages.io import png_bytes, read_raster, write_cog, write_lines_gpkg
from stages.units import raster_units

#: Nodata of the Byte hillshade (shades are 1-255, as gdaldem writes them).
HILLSHADE_NODATA = 0


class HillshadeParams(StageParams):
    azimuth: float = Field(
        315.0, ge=0, lt=360, description="direction the light comes from, degrees clockwise from north"
    )
    altitude: float = Field(45.0, gt=0, le=90, description="light elevation above the horizon, degrees")
    z_factor: float = Field(1.0, gt=0, description="vertical exaggeration")


class Hillshade(Stage):
    name = "hillshade"
    version = "2"  # 2: Byte, shades 1-255, nodata 0
    Params = HillshadeParams
    description = "shaded relief of the DTM (GeoTIFF and PNG)"
    inputs = ("dtm",)
    outputs: ClassVar = {"hillshade": "hillshade.tif", "hillshade_png": "hillshade.png"}
    products: ClassVar = {"hillshade": "hillshade.tif", "hillshade_png": "hillshade.png"}

    def run(self, ctx) -> None:
        from stages.grid.terrain import hillshade

        dem, transform, crs, res = read_raster(ctx.inputs["dtm"])
        p = ctx.params
        units = raster_units(crs)  # slopes from metres on both axes, whatever the CRS's units
        shade = hillshade(
            dem * units.vertical, res * units.horizontal, azimuth=p.azimuth, altitude=p.altitude, z_factor=p.z_factor
        )
        image = np.where(np.isnan(shade), HILLSHADE_NODATA, np.clip(np.nan_to_num(shade).round(), 1, 255))
        image = image.astype(np.uint8)
        write_cog(
            ctx.outputs["hillshade"],
            image,
            transform=transform,
            crs=crs,
            nodata=HILLSHADE_NODATA,
            dtype="uint8",
            unit=None,
        )
        ctx.outputs["hillshade_png"].write_bytes(png_bytes(image))
        ctx.metrics.update(azimuth=p.azimuth, altitude=p.altitude)


class ContoursParams(StageParams):
    interval: float = Field(1.0, gt=0, description="height between contour lines, metres")


class Contours(Stage):
    name = "contours"
    version = "2"  # 2: reproducible GeoPackage bytes
    Params = ContoursParams
    description = "contour lines of the DTM (GeoPackage)"
    inputs = ("dtm",)
    outputs: ClassVar = {"contours": "contours.gpkg"}
    products: ClassVar = {"contours": "contours.gpkg"}

    def run(self, ctx) -> None:
        from stages.grid.terrain import contour_lines

        dem, transform, crs, _ = read_raster(ctx.inputs["dtm"])
        units = raster_units(crs)  # levels every interval metres; written in the CRS's units
        lines = contour_lines(dem * units.vertical, units.transform_to_metres(transform), interval=ctx.params.interval)
        if not units.is_metre:
            lines = [(level / units.vertical, xy / units.horizontal) for level, xy in lines]
        write_lines_gpkg(ctx.outputs["contours"], lines, crs=crs)
        levels = sorted({level for level, _ in lines})
        ctx.metrics.update(
            interval=ctx.params.interval,
            lines=len(lines),
            levels=len(levels),
            lowest=levels[0] if levels else None,
            highest=levels[-1] if levels else None,
        )
        ctx.log.info("%d contour lines on %d levels", len(lines), len(levels))
