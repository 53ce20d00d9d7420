"""Terrain products derived from an elevation grid: hillshade and contour lines."""

from __future__ import annotations

import numpy as np


def hillshade(
    dem: np.ndarray, resolution: float, *, azimuth: float = 315.0, altitude: float = 45.0, z_factor: float = 1.0
) -> np.ndarray:
    """Illumination of a north-up DEM, 0 (dark) to 255 (lit); NaN where the DEM is NaN.

    Horn (1981) gradients on the 3x3 neighbourhood, the formula of GDAL's
    ``gdaldem hillshade`` and ESRI's Hillshade.  *azimuth* is the direction
    the light comes from, clockwise from north (default 315 = north-west);
    *altitude* its angle above the horizon, degrees.

    Horn, B. K. P. (1981).  Hill shading and the reflectance map.
    Proceedings of the IEEE 69(1), 14-47.  doi:10.1109/PROC.1981.11918

    >>> flat = np.zeros((5, 5))
    >>> round(float(hillshade(flat, 1.0)[2, 2]), 3)  # 255 * sin(45 deg)
    180.312
    """
    z = np.pad(np.asarray(dem, dtype=np.float64) * z_factor, 1, mode="edge")
    # Horn's weights; rows go south, so "north" is row - 1.
    a, b, c = z[:-2, :-2], z[:-2, 1:-1], z[:-2, 2:]
    d, f = z[1:-1, :-2], z[1:-1, 2:]
    g, h, i = z[2:, :-2], z[2:, 1:-1], z[2:, 2:]
    dzdx = ((c + 2 * f + i) - (a + 2 * d + g)) / (8.0 * resolution)  # east positive
    dzdy = ((g + 2 * h + i) - (a + 2 * b + c)) / (8.0 * resolution)  # south positive
    slope = np.arctan(np.hypot(dzdx, dzdy))
    aspect = np.arctan2(dzdy, -dzdx)
    zenith = np.radians(90.0 - altitude)
    azimuth_math = np.radians((360.0 - azimuth + 90.0) % 360.0)
    shade = np.cos(zenith) * np.cos(slope) + np.sin(zenith) * np.sin(slope) * np.cos(azimuth_math - aspect)
    return np.clip(255.0 * shade, 0.0, 255.0)


def contour_lines(
    dem: np.ndarray, transform, *, interval: float, nodata_mask: np.ndarray | None = None
) -> list[tuple[float, np.ndarray]]:
    """Contour lines of a north-up DEM every *interval* metres.

    Returns
    -------
    list of (elevation, (m, 2) array of map x, y)
        One entry per line; lines stop at nodata cells.  A DEM less than
        two cells wide or high has no contour lines.

    Notes
    -----
    Marching squares through ``contourpy`` (the engine of Matplotlib's
    contours) on cell-centre values; levels are whole multiples of
    *interval*.
    """
    import contourpy

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
    for level in np.arange(np.ceil(lo / interval) * interval, hi + interval * 1e-9, interval):
        for line in gen.lines(float(level)):
            if len(line) >= 2:
                lines.append((float(level), np.asarray(line)))
    return lines
