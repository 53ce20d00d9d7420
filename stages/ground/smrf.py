"""Simple morphological filter (SMRF) for ground points.

Pingel, T. J., Clarke, K. C., McBride, W. A. (2013).  An improved simple
morphological filter for the terrain classification of airborne LIDAR data.
ISPRS J. Photogramm. Remote Sens. 77, 21-30.
doi:10.1016/j.isprsjprs.2012.12.002
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from stages.ground.surface import (
    as_xyz,
    index_points,
    inpaint,
    min_grid,
    pad_linear,
    sample_bilinear,
    slope_grid,
)

#: Points tested against the provisional DEM at a time.
_BLOCK = 1 << 20
_CROSS = ndimage.generate_binary_structure(2, 1)
_SQUARE = ndimage.generate_binary_structure(2, 2)


def _element(step: int) -> np.ndarray:
    # Alternating a cross and a square: their Minkowski sum over r steps is
    # an octagon of radius r, a close, cheap stand-in for a disk.
    return _CROSS if step % 2 == 1 else _SQUARE


def progressive_filter(surface: np.ndarray, *, cell_size: float, slope: float, max_radius: int) -> np.ndarray:
    """Flag cells that an opening of growing radius lowers by more than the slope allows.

    Parameters
    ----------
    surface : ndarray (rows, cols)
        A filled minimum surface (no NaN).
    cell_size : float
        ``c`` (m).
    slope : float
        ``s``: the threshold at radius ``r`` cells is ``s * r * c``.
    max_radius : int
        Largest radius, in cells.

    Returns
    -------
    ndarray of bool
        True for object cells.

    Notes
    -----
    The surface is padded by continuing its slopes (:func:`pad_linear`), so
    that the survey's uphill edges are not mistaken for objects.  The
    opening at radius ``r`` uses an octagon (alternately a 3x3 cross and
    square, ``r`` times) instead of the paper's disk; the erosion is carried
    from one radius to the next, so radius ``r`` costs ``r + 1`` 3x3 passes.
    """
    pad = max_radius
    surface = pad_linear(surface, pad)
    objects = np.zeros(surface.shape, dtype=bool)
    previous = surface
    eroded = surface
    for radius in range(1, max_radius + 1):
        eroded = ndimage.grey_erosion(eroded, footprint=_element(radius), mode="nearest")
        opened = eroded
        for step in range(1, radius + 1):
            opened = ndimage.grey_dilation(opened, footprint=_element(step), mode="nearest")
        objects |= (previous - opened) > slope * radius * cell_size
        previous = opened
    return objects[pad:-pad, pad:-pad]


def smrf(
    xyz: np.ndarray,
    *,
    cell_size: float = 1.0,
    slope: float = 0.15,
    max_window_size: float = 18.0,
    elevation_threshold: float = 0.5,
    elevation_scalar: float = 1.25,
) -> np.ndarray:
    """Classify ground points with the simple morphological filter.

    Parameters
    ----------
    xyz : ndarray, shape (n, 3)
        Point coordinates (m).
    cell_size : float
        ``c``: cell size of the minimum surface (m).
    slope : float
        ``s``: slope threshold (rise over run) of the progressive filter.
    max_window_size : float
        ``w_max``: largest window *radius* (m); larger than half the widest
        building.
    elevation_threshold : float
        ``et``: base height threshold (m) of the final point test.
    elevation_scalar : float
        ``es``: how much the local slope of the provisional DEM raises the
        threshold.

    Returns
    -------
    ndarray of bool, shape (n,)
        True where the point is ground.

    Notes
    -----
    Steps of the paper: (1) minimum surface at ``c``, empty cells inpainted;
    (2) low outliers, on a separate fork: the progressive filter on the
    negated surface with slope 5 and radius 1 cell; (3) the progressive
    filter with radii 1..``w_max / c``, threshold ``s * r * c``, on the
    surface of step 1 (low cells included); (4) object and low cells emptied
    and re-inpainted: the provisional DEM; (5) a point is ground when
    ``|z - DEM| <= et + es * slope(DEM)`` at the point.

    The low cells leave the provisional DEM only, as the paper says ("the
    resulting mask is used to flag low outlier cells as OBJ before the
    inpainting of the provisional DEM") and as PDAL does.  In a dense forest
    most cells' lowest point is canopy, and a cell that holds a ground return
    is then a pit more than 5 m deep: emptying it *before* the object filter
    (as this function did until 2026-12-01) leaves a surface of canopy wider
    than the window, which the filter keeps as ground (docs/GROUND.md).

    Departures: the opening uses an octagon instead of a disk, and the
    surface is padded by continuing its slopes so that uphill survey edges
    are not flagged (see :func:`progressive_filter`); inpainting is the harmonic (Laplacian)
    interpolant (the paper uses D'Errico's spring metaphor, a close relative);
    the DEM and its slope are sampled at each point bilinearly.

    References
    ----------
    .. [1] Pingel et al. (2013), doi:10.1016/j.isprsjprs.2012.12.002

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> pts = np.column_stack([rng.uniform(0, 50, (2000, 2)), np.zeros(2000)])
    >>> bool(smrf(pts).all())
    True
    """
    xyz = as_xyz(xyz)
    if len(xyz) == 0:
        return np.zeros(0, dtype=bool)
    idx = index_points(xyz[:, :2], cell_size)
    zmin = min_grid(xyz[:, 2], idx)
    surface = inpaint(zmin)
    # Low outliers: a separate fork, as in the paper; they leave only the provisional DEM.  Emptying them
    # before the object filter (this code until 2026-12-01) removes the ground cells of a dense forest:
    # a ground cell among cells whose lowest point is canopy is a "pit" of the minimum surface.
    low = progressive_filter(-surface, cell_size=cell_size, slope=5.0, max_radius=1)
    max_radius = max(1, int(math.ceil(max_window_size / cell_size)))
    objects = progressive_filter(surface, cell_size=cell_size, slope=slope, max_radius=max_radius)
    provisional = zmin.copy()
    provisional[objects | low] = np.nan
    if np.isnan(provisional).all():
        return np.zeros(len(xyz), dtype=bool)
    dem = inpaint(provisional)
    slope_dem = slope_grid(dem, cell_size)
    ground = np.empty(len(xyz), dtype=bool)
    for a in range(0, len(xyz), _BLOCK):  # in blocks: bilinear sampling makes ten temporaries per point
        x, y, z = xyz[a : a + _BLOCK, 0], xyz[a : a + _BLOCK, 1], xyz[a : a + _BLOCK, 2]
        at = sample_bilinear(dem, idx, x, y)
        grad = sample_bilinear(slope_dem, idx, x, y)
        ground[a : a + _BLOCK] = np.abs(z - at) <= elevation_threshold + elevation_scalar * grad
    return ground
