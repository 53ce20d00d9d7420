"""Stages ``hillshade`` and ``contours``: map products derived from the DTM.

- ``hillshade``: ``hillshade.tif`` (COG, float32 0-255, nodata -9999) and
  ``hillshade.png`` (8-bit grey, nodata black), Horn's method.
- ``contours``: ``contours.gpkg``, a GeoPackage layer ``contours`` of line
  strings with an ``elevation`` attribute (m), every ``interval`` metres.

Separate stages so that restyling them never re-grids the DTM.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from pipeline.stage import Stage, StageParams
from stages.io import NODATA, png_bytes, read_raster, write_cog, write_lines_gpkg


class HillshadeParams(StageParams):
    azimuth: float = Field(
        315.0, ge=0, lt=360, description="direction the light comes from, degrees clockwise from north"
    )
    altitude: float = Field(45.0, gt=0, le=90, description="light elevation above the horizon, degrees")
    z_factor: float = Field(1.0, gt=0, description="vertical exaggeration")


class Hillshade(Stage):
    name = "hillshade"
    version = "1"
    Params = HillshadeParams
    description = "shaded relief of the DTM (GeoTIFF and PNG)"
    inputs = ("dtm",)
    outputs: ClassVar = {"hillshade": "hillshade.tif", "hillshade_png": "hillshade.png"}
    products: ClassVar = {"hillshade": "hillshade.tif", "hillshade_png": "hillshade.png"}

    def run(self, ctx) -> None:
        from stages.grid.terrain import hillshade

        dem, transform, crs, res = read_raster(ctx.inputs["dtm"])
        p = ctx.params
        shade = hillshade(dem, res, azimuth=p.azimuth, altitude=p.altitude, z_factor=p.z_factor)
        write_cog(ctx.outputs["hillshade"], np.where(np.isnan(shade), NODATA, shade), transform=transform, crs=crs)
        ctx.outputs["hillshade_png"].write_bytes(png_bytes(np.nan_to_num(shade, nan=0.0).round()))
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
        lines = contour_lines(dem, transform, interval=ctx.params.interval)
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
