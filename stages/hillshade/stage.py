"""Stage ``hillshade``: the shaded relief of the DTM.

``hillshade.tif`` (COG, Byte: shades 1-255, nodata 0, as ``gdaldem
hillshade`` writes it) and ``hillshade.png`` (the same bytes, nodata black),
by Horn's method (:func:`lidar.shading.hillshade`) on the DTM in metres.
A stage of its own, apart from ``rasterize``, so that restyling it never
re-grids the DTM (docs/stages/hillshade.md).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from lidar.rasters import png_bytes, read_raster, write_cog
from lidar.shading import ALTITUDE, AZIMUTH, Z_FACTOR, hillshade
from lidar.units import raster_units
from pipeline.stage import Stage, StageContext, StageParams

#: Nodata of the Byte hillshade (shades are 1-255, as gdaldem writes them).
HILLSHADE_NODATA = 0


class HillshadeParams(StageParams):
    azimuth: float = Field(
        AZIMUTH, ge=0, lt=360, description="direction the light comes from, degrees clockwise from north"
    )
    altitude: float = Field(ALTITUDE, gt=0, le=90, description="light elevation above the horizon, degrees")
    z_factor: float = Field(Z_FACTOR, gt=0, description="vertical exaggeration")


class Hillshade(Stage, name="hillshade", version="3", params=HillshadeParams):
    """shaded relief of the DTM (GeoTIFF and PNG)."""

    inputs = ("dtm",)
    outputs: ClassVar = {"hillshade": "hillshade.tif", "hillshade_png": "hillshade.png"}
    products: ClassVar = {"hillshade": "hillshade.tif", "hillshade_png": "hillshade.png"}

    def run(self, ctx: StageContext[HillshadeParams]) -> None:
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
            unit="grey level, 1 (shadow) to 255 (lit); 0 is nodata",
            description=f"hillshade of the DTM, sun at azimuth {p.azimuth:g} degrees, altitude {p.altitude:g} degrees",
        )
        ctx.outputs["hillshade_png"].write_bytes(png_bytes(image))
        ctx.metrics.update(azimuth=p.azimuth, altitude=p.altitude)
