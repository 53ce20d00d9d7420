"""Stage ``contours``: contour lines of the DTM.

``contours.gpkg``: a GeoPackage layer ``contours`` of line strings with an
``elevation`` attribute, every ``interval`` metres
(:func:`dtm.stages.contours.lines.contour_lines`); lines and elevations in
the CRS's units (:mod:`dtm.common.units`).  A stage of its own, apart from
``rasterize``, so that restyling it never re-grids the DTM
(docs/stages/contours.md).
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import Field

from dtm.common.rasters import read_raster
from dtm.common.units import raster_units
from dtm.common.vectors import write_lines_gpkg
from pipeline.stage import Stage, StageContext, StageParams


class ContoursParams(StageParams):
    interval: float = Field(1.0, gt=0, description="height between contour lines, metres")


class Contours(Stage, name="contours", version="2", params=ContoursParams):
    """contour lines of the DTM (GeoPackage)."""

    inputs = ("dtm",)
    outputs: ClassVar = {"contours": "contours.gpkg"}
    products: ClassVar = {"contours": "contours.gpkg"}

    def run(self, ctx: StageContext[ContoursParams]) -> None:
        from dtm.stages.contours.lines import contour_lines

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
