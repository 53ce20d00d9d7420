"""Shaded relief of an elevation grid (Horn 1981), for the ``hillshade`` stage and the report's maps."""

from __future__ import annotations

import numpy as np

#: The light of a shaded relief unless said otherwise: from the north-west (degrees clockwise from north), 45
#: degrees above the horizon, no vertical exaggeration (the cartographers' convention, and gdaldem's defaults).
AZIMUTH, ALTITUDE, Z_FACTOR = 315.0, 45.0, 1.0


def hillshade(
    dem: np.ndarray,
    resolution: float,
    *,
    azimuth: float = AZIMUTH,
    altitude: float = ALTITUDE,
    z_factor: float = Z_FACTOR,
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
    # Horn's shade cos(zenith) cos(slope) + sin(zenith) sin(slope) cos(azimuth - aspect), with
    # aspect = atan2(dzdy, -dzdx) and slope = atan(|g|), written without the angles:
    # cos(slope) = 1 / sqrt(1 + |g|^2), sin(slope) cos(azimuth - aspect) = (-cos(azimuth) dzdx
    # + sin(azimuth) dzdy) / sqrt(1 + |g|^2) (one square root a cell instead of five
    # trigonometric functions; equal to a few units in the last place).
    zenith = np.radians(90.0 - altitude)
    azimuth_math = np.radians((360.0 - azimuth + 90.0) % 360.0)
    tilt = np.cos(zenith) + np.sin(zenith) * (np.sin(azimuth_math) * dzdy - np.cos(azimuth_math) * dzdx)
    shade = tilt / np.sqrt(1.0 + dzdx * dzdx + dzdy * dzdy)
    return np.clip(255.0 * shade, 0.0, 255.0)
