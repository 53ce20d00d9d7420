"""Noise detection before ground classification: isolated points and low outliers.

Two pure functions, each returning a mask; the ``denoise`` stage driver turns
them into ASPRS classes 7 (low noise) and 18 (high noise).
"""

from __future__ import annotations

import numpy as np


def neighbour_distance(xyz: np.ndarray, *, neighbors: int = 8, radius: float = 20.0) -> np.ndarray:
    """Mean 3D distance of every point to its ``neighbors`` nearest neighbours.

    Distances are counted up to *radius*: a neighbour farther away (or
    missing) counts as *radius*.  The value of a point then depends only on
    the points within *radius* of it, which is what lets a tile with a
    buffer of *radius* compute it exactly.
    """
    from scipy.spatial import cKDTree

    xyz = np.asarray(xyz, dtype=np.float64)
    if len(xyz) == 0:
        return np.zeros(0)
    # Coordinates relative to a whole-metre corner: exact differences, the
    # same for any subset of the points.
    centred = xyz - np.floor(xyz.min(axis=0))
    k = min(neighbors + 1, len(xyz))
    dist, _ = cKDTree(centred, balanced_tree=False, compact_nodes=False).query(
        centred, k=k, distance_upper_bound=radius, workers=-1
    )
    dist = np.minimum(dist.reshape(len(xyz), k)[:, 1:], radius)
    if k - 1 < neighbors:  # fewer points than neighbours: the missing ones are far
        dist = np.hstack((dist, np.full((len(xyz), neighbors - k + 1), radius)))
    return dist.mean(axis=1)


def exact_mean_std(parts) -> tuple[float, float, int]:
    """Mean and standard deviation of the values of the arrays *parts* yields (a callable).

    Sums are exact (:func:`math.fsum`), so the result does not depend on how
    the values are cut into parts or ordered: tiles give the untiled figure
    bit for bit.  *parts* is called twice (mean, then deviation).
    """
    import math

    n = 0

    def values():
        nonlocal n
        for part in parts():
            n += len(part)
            yield from part.tolist()

    total = math.fsum(values())
    if n == 0:
        return 0.0, 0.0, 0
    mean = total / n
    var = math.fsum(v for part in parts() for v in ((part - mean) ** 2).tolist()) / n
    return mean, math.sqrt(var), n


def isolated_points(
    xyz: np.ndarray, *, neighbors: int = 8, multiplier: float = 3.0, radius: float = 20.0
) -> np.ndarray:
    """Statistical outlier test: points far from their neighbours.

    For every point, the mean 3D distance to its ``neighbors`` nearest
    neighbours; a point is isolated when that distance exceeds the mean over
    all points by more than ``multiplier`` standard deviations (Rusu et al.
    2008, the statistical outlier removal of PCL and PDAL).  Departure:
    distances are counted up to *radius* (:func:`neighbour_distance`), so
    that a tile computes them exactly; the mean and deviation are exact sums
    (:func:`exact_mean_std`).

    Rusu, R. B., Marton, Z. C., Blodow, N., Dolha, M., Beetz, M. (2008).
    Towards 3D point cloud based object maps for household environments.
    Robotics and Autonomous Systems 56(11), 927-941.
    doi:10.1016/j.robot.2008.08.005

    Parameters
    ----------
    xyz : ndarray, shape (n, 3)
    neighbors : int
        ``k``, neighbours per point.
    multiplier : float
        Standard deviations above the mean distance.
    radius : float
        Distances are counted up to this (m).

    Returns
    -------
    ndarray of bool
        True for isolated points.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    if len(xyz) <= neighbors:
        return np.zeros(len(xyz), dtype=bool)
    mean = neighbour_distance(xyz, neighbors=neighbors, radius=radius)
    mu, sigma, _ = exact_mean_std(lambda: [mean])
    return mean > mu + multiplier * sigma


def low_outliers(xyz: np.ndarray, *, cell_size: float = 10.0, elevation_threshold: float = 1.0) -> np.ndarray:
    """Extended local minimum: points well below everything else in their cell.

    In each cell, points are taken from the lowest up; a point is a low
    outlier while the gap to the next higher point of the cell exceeds
    ``elevation_threshold``.  This is the extended local minimum (ELM) test of
    Chen et al. (2012), as in PDAL's ``filters.elm``.  Multipath and
    below-ground echoes come out; a cell's real lowest ground, with other
    ground points close above it, stays.

    Chen, Z., Devereux, B., Gao, B., Amable, G. (2012).  Upward-fusion urban
    DTM generating method using airborne Lidar data.  ISPRS J. Photogramm.
    Remote Sens. 72, 121-130.  doi:10.1016/j.isprsjprs.2012.07.001

    Parameters
    ----------
    xyz : ndarray, shape (n, 3)
    cell_size : float
        Side of the square cells (m).
    elevation_threshold : float
        Height gap (m) that separates an outlier from the points above it.

    Returns
    -------
    ndarray of bool
        True for low outliers.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    if n == 0:
        return np.zeros(0, dtype=bool)
    # Cells on whole multiples of cell_size (not on the data's corner), so a
    # tile of the survey cuts the same cells as the whole survey.
    col = np.floor(xyz[:, 0] / cell_size).astype(np.int64)
    row = np.floor(xyz[:, 1] / cell_size).astype(np.int64)
    col -= col.min()
    row -= row.min()
    cell = row * (int(col.max()) + 1) + col
    order = np.lexsort((xyz[:, 2], cell))
    c, z = cell[order], xyz[order, 2]
    same_next = np.append(c[1:] == c[:-1], False)
    gap = np.where(same_next, np.append(z[1:] - z[:-1], 0.0), 0.0)
    big = gap > elevation_threshold
    # A point is an outlier when every gap from the bottom of its cell up to
    # and including its own is big: count the small gaps so far in the cell.
    start = np.append(True, c[1:] != c[:-1])
    small_so_far = np.cumsum(~big)
    offset = np.maximum.accumulate(np.where(start, np.arange(n), 0))
    before = np.where(offset > 0, small_so_far[np.maximum(offset - 1, 0)], 0)
    outlier_sorted = (small_so_far - before) == 0
    out = np.zeros(n, dtype=bool)
    out[order] = outlier_sorted
    return out
