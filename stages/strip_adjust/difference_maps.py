"""What both models publish of the overlaps: the strip-difference rasters and picture, the combined RMS.

``strip_difference_before.tif`` / ``_after.tif`` hold the mean signed
distance between overlapping strips at planar patches, per cell (like
LAStools' lasoverlap); ``strip_difference.png`` shows them side by side.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar.grid import Grid, cell_mean
from lidar.rasters import NODATA, colour_ramp, png_bytes, write_cog

if TYPE_CHECKING:
    import pyproj

    from lidar.units import Units

#: the outputs of the difference maps, unpublished when no overlap was measured
DIFFERENCE_MAPS = ("strip_difference_before", "strip_difference_after", "strip_difference_png")


def combined_rms(values: list[float], weights: list[int]) -> float | None:
    """The RMS of several groups from their RMS values and sizes (None without a group)."""
    if not values:
        return None
    v, w = np.asarray(values, dtype=np.float64), np.asarray(weights, dtype=np.float64)
    return float(np.sqrt(np.sum(w * v**2) / np.sum(w)))


def write_difference_maps(
    paths: dict[str, Path],
    extent: tuple[float, float, float, float],
    before: list | None,
    after: list | None,
    resolution: float,
    crs: pyproj.CRS,
    units: Units,
    nodata: float = NODATA,
) -> None:
    """Mean signed strip-to-strip distance per cell (*nodata* where no planar overlap), before and after.

    *before* and *after* hold (patch centres, mean distances) per pair, in
    metres; *paths* maps the names of :data:`DIFFERENCE_MAPS` to files.  The
    grid covers the overlap patches (one cell when there is none), so a
    sparse survey over a large area costs nothing.  The rasters are written
    in the CRS's units (cells and values).
    """
    # the grid covers the overlaps measured, not the survey: its cost follows the patches, not the area
    centres_all = [c for parts in (before or [], after or []) for c, _ in parts if len(c)]
    if centres_all:
        xy = np.concatenate(centres_all)[:, :2]
        box = (*xy.min(axis=0), *xy.max(axis=0))
    else:
        box = (extent[0], extent[1], extent[0], extent[1])
    grid = Grid.covering(*box, resolution)
    images = []
    for name, parts in (("strip_difference_before", before), ("strip_difference_after", after)):
        centres = np.concatenate([c for c, _ in parts]) if parts else np.zeros((0, 3))
        values = np.concatenate([v for _, v in parts]) if parts else np.zeros(0)
        grid_values = cell_mean(centres, values, grid)
        values_crs = grid_values / units.vertical
        write_cog(
            paths[name],
            np.where(np.isfinite(values_crs), values_crs, nodata).astype(np.float32),
            transform=units.transform_from_metres(grid.transform),
            crs=crs,
            nodata=nodata,
            description=f"mean height difference of overlapping strips, {name.rsplit('_', 1)[1]} adjustment",
        )
        images.append(grid_values)
    paths["strip_difference_png"].write_bytes(_picture(images, grid.rows))


def _picture(images: list[np.ndarray], rows: int) -> bytes:
    """PNG: before | after, blue (-0.3 m) - white (0) - red (+0.3 m), grey where no overlap."""
    ramp = [(0.0, (59, 76, 192)), (0.5, (245, 245, 245)), (1.0, (180, 4, 38))]
    panels = []
    for image in images:
        rgb = colour_ramp(np.nan_to_num(image), ramp, -0.3, 0.3)
        rgb[~np.isfinite(image)] = 200.0
        panels.append(rgb)
    gap = np.full((rows, 4, 3), 255.0)
    return png_bytes(np.concatenate((panels[0], gap, panels[1]), axis=1).round())
