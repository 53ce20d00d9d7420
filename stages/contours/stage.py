"""Stage ``contours``: contour lines of the DTM.

``contours.gpkg``: a GeoPackage layer ``contours`` of line strings with an
``elevation`` attribute, every ``interval`` metres
(:func:`stages.contours.lines.contour_lines`); lines and elevations in
the CRS's units (:mod:`lidar.units`).  A stage of its own, apart from
``rasterize``, so that restyling it never re-grids the DTM
(docs/stages/contours.md).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from lidar.grid import round_up
from lidar.rasters import read_raster
from lidar.units import raster_units
from lidar.vectors import write_lines_gpkg
from pipeline.errors import ConfigError
from pipeline.stage import Stage, StageContext, StageParams
from stages.contours.lines import contour_lines, levels_between

#: Most contour levels one run draws, whatever the memory: each level is a pass over the DTM.
MAX_LEVELS = 10_000


class ContoursParams(StageParams):
    interval: float = Field(
        1.0,
        gt=0,
        description=f"height between contour lines, metres (at most {MAX_LEVELS:,} levels over the DTM's heights: "
        "a finer interval is refused before drawing)",
    )


class Contours(Stage, name="contours", version="2", params=ContoursParams):
    """contour lines of the DTM (GeoPackage)."""

    inputs = ("dtm",)
    outputs: ClassVar = {"contours": "contours.gpkg"}
    products: ClassVar = {"contours": "contours.gpkg"}

    def run(self, ctx: StageContext[ContoursParams]) -> None:
        dem, transform, crs, _ = read_raster(ctx.inputs["dtm"])
        units = raster_units(crs)  # levels every interval metres; written in the CRS's units
        dem = dem * units.vertical
        levels = _check_levels(dem, ctx.params.interval)
        with ctx.progress(levels, "contour levels drawn", unit="levels") as bar:
            lines = contour_lines(
                dem, units.transform_to_metres(transform), interval=ctx.params.interval, advance=bar.update
            )
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


def _check_levels(dem: np.ndarray, interval: float) -> int:
    """The levels over *dem* (metres); refused, before drawing, when more than :data:`MAX_LEVELS`."""
    finite = dem[np.isfinite(dem)]
    if not len(finite):
        return 0
    lo, hi = float(finite.min()), float(finite.max())
    levels = levels_between(lo, hi, interval)
    if levels <= MAX_LEVELS:
        return levels
    least = (hi - lo) / (MAX_LEVELS - 1)
    raise ConfigError(
        f"stages.contours.interval: {interval:g} m between lines over the DTM's heights of {lo:.3f} to {hi:.3f} m "
        f"make {levels:,} levels, more than the {MAX_LEVELS:,} a run draws; use an interval of at least "
        f"{round_up(least):g} m."
    )
