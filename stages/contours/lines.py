"""Contour lines of an elevation grid: marching squares on its cell centres."""

from __future__ import annotations

from typing import TYPE_CHECKING

import contourpy
import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

    from affine import Affine


def levels_between(lo: float, hi: float, interval: float) -> int:
    """How many whole multiples of *interval* lie in [*lo*, *hi*]: the levels :func:`contour_lines` draws."""
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi < lo:
        return 0
    return max(0, int(np.floor(hi / interval + 1e-9) - np.ceil(lo / interval)) + 1)


def contour_lines(
    dem: np.ndarray,
    transform: Affine,
    *,
    interval: float,
    nodata_mask: np.ndarray | None = None,
    advance: Callable[[int], object] | None = None,
) -> list[tuple[float, np.ndarray]]:
    """Contour lines of a north-up DEM every *interval* metres.

    Returns
    -------
    list of (elevation, (m, 2) array of map x, y)
        One entry per line; lines stop at nodata cells.  A DEM less than
        two cells wide or high has no contour lines.  *advance* is told
        each level drawn.

    Notes
    -----
    Marching squares through ``contourpy`` (the engine of Matplotlib's
    contours) on cell-centre values; levels are whole multiples of
    *interval*.
    """
    z = np.asarray(dem, dtype=np.float64)
    mask = ~np.isfinite(z) if nodata_mask is None else (nodata_mask | ~np.isfinite(z))
    if mask.all() or min(z.shape) < 2:  # marching squares needs a 2 x 2 block of cells
        return []
    rows, cols = z.shape
    xs = transform.c + (np.arange(cols) + 0.5) * transform.a
    ys = transform.f + (np.arange(rows) + 0.5) * transform.e
    gen = contourpy.contour_generator(
        xs, ys, np.ma.array(z, mask=mask), line_type=contourpy.LineType.Separate, name="serial"
    )
    lo, hi = np.nanmin(z[~mask]), np.nanmax(z[~mask])
    lines = []
    for level in np.arange(np.ceil(lo / interval) * interval, hi + interval * 1e-9, interval):  # levels_between's
        for line in gen.lines(float(level)):
            if len(line) >= 2:
                lines.append((float(level), np.asarray(line)))
        if advance is not None:
            advance(1)
    return lines
