"""Noise detection before ground classification: isolated points and low outliers.

Two pure tests, each returning a mask (:func:`isolated_points`,
:func:`low_outliers`); the ``denoise`` stage driver turns them into ASPRS
classes 7 (low noise) and 18 (high noise).
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial import cKDTree

from stages.denoise.params import IsolatedParams, LowParams

#: The tests' parameters at their defaults: the functions' defaults are the configuration's.
_ISOLATED, _LOW = IsolatedParams(), LowParams()


def isolated_points(
    xyz: np.ndarray,
    *,
    neighbors: int = _ISOLATED.neighbors,
    spacing_neighbors: int = _ISOLATED.spacing_neighbors,
    multiplier: float = _ISOLATED.multiplier,
    min_distance: float = _ISOLATED.min_distance,
    radius: float = _ISOLATED.radius,
) -> np.ndarray:
    """Points isolated in 3-D at the scale of the point spacing around them.

    A point is isolated when its *neighbors*-th nearest point in 3-D is
    farther than *multiplier* times the local point spacing (the plan
    distance to its *spacing_neighbors*-th nearest point) and farther than
    *min_distance* (m), both counted up to *radius* (m).  The threshold is
    the point's own neighbourhood, the idea of the local outlier factor
    (Breunig et al. 2000, doi:10.1145/335191.335388); we depart from the
    survey-wide statistical outlier removal of PCL and PDAL (Rusu et al.
    2008, doi:10.1016/j.robot.2008.08.005), which took canopy for noise
    (docs/stages/denoise.md).  Returns a mask, True for isolated points.
    """
    xyz = np.asarray(xyz, dtype=np.float64)
    n = len(xyz)
    out = np.zeros(n, dtype=bool)
    if n == 0:
        return out
    # Coordinates relative to a whole-metre corner: exact differences, the
    # same for any subset of the points.
    centred = xyz - np.floor(xyz.min(axis=0))
    cand = np.arange(n)
    near = None
    if min_distance > 0:
        # A point sharing a cube of side min_distance / sqrt(3) with
        # `neighbors` others has them within min_distance: never isolated.
        # This decides most points at the cost of one count; the k-d trees
        # are asked about the rest only.
        cand, near = _crowded_cubes(centred, min_distance / np.sqrt(3.0), neighbors)
    if len(cand) == 0:
        return out
    # Whether the k-th point lies within min_distance: the points near the candidates tell.
    pts, at = _subset(centred, near, cand)
    cand = cand[_kth(pts, at, neighbors, radius) > min_distance]
    if len(cand) == 0:
        return out
    # The k-th distance and the spacing up to radius: the points within radius in plan tell.
    pts, at = _subset(centred, within_plan(centred, cand, radius), cand)
    far = _kth(pts, at, neighbors, radius)
    spacing = _kth(pts[:, :2], at, spacing_neighbors, radius)
    out[cand] = far > np.maximum(multiplier * spacing, min_distance)
    return out


def _subset(points: np.ndarray, mask: np.ndarray | None, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points of *mask* (all of them: None) in their order, and where the points *which* (in it) are there.

    A k-d tree of the subset answers as one of all the points would for
    those points whose neighbours up to the distance asked all lie in it.
    """
    if mask is None or mask.all():
        return points, which
    sub = np.flatnonzero(mask)
    return points[sub], np.searchsorted(sub, which)


#: Cubes a survey may count in one array (8 bytes each); more (a survey of great relief): counted by sorting.
DENSE_CUBES = 1 << 24


def _crowded_cubes(centred: np.ndarray, side: float, neighbors: int) -> tuple[np.ndarray, np.ndarray | None]:
    """The points with at most *neighbors* others in their cube of *side*, and which points may lie near them.

    Returns the candidates' indices and a mask of the points in the cubes
    within two of a candidate's (all the points within ``side * sqrt(3)``
    of it); None for the mask when the cubes are too many to count in one
    array (:data:`DENSE_CUBES`), where every point may be near.
    """
    n = len(centred)
    cubes = [np.floor(centred[:, axis] / side).astype(np.int64) for axis in range(3)]
    dims = [int(c.max()) + 1 for c in cubes]
    key = (cubes[0] * dims[1] + cubes[1]) * dims[2] + cubes[2]
    del cubes
    span = dims[0] * dims[1] * dims[2]
    if span > max(DENSE_CUBES, 4 * n):
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        return np.flatnonzero(counts[inverse] <= neighbors), None
    cand = np.flatnonzero(np.bincount(key, minlength=span)[key] <= neighbors)
    # a point within side * sqrt(3) of another lies at most two cubes from it along each axis
    return cand, _around(key, cand, dims, 2)


def within_plan(points: np.ndarray, which: np.ndarray, radius: float) -> np.ndarray:
    """Which points may lie within *radius* in plan of one of ``points[which]``: those in the squares of side
    *radius* next to theirs.  *points* with x, y from zero (a superset: every such point is in it)."""
    squares = np.floor(points[:, :2] / radius).astype(np.int64)
    dims = [int(d) + 1 for d in squares.max(axis=0)]
    if dims[0] * dims[1] > max(DENSE_CUBES, 4 * len(points)):  # a tiny radius over a wide survey
        return np.ones(len(points), dtype=bool)
    return _around(squares[:, 0] * dims[1] + squares[:, 1], which, dims, 1)


def _around(key: np.ndarray, which: np.ndarray, dims: list[int], reach: int) -> np.ndarray:
    """Which points (flat cell index *key* on a grid of *dims*, row-major) lie in a cell within *reach* cells,
    along every axis, of the cell of one of the points *which*.

    The cells around the candidates' are marked one offset at a time: work
    by the candidates' cells, not by the grid's size.
    """
    cells = np.unique(key[which])
    coords = []
    for d in reversed(dims[1:]):
        cells, c = np.divmod(cells, d)
        coords.append(c)
    coords = [cells, *reversed(coords)]
    marked = np.zeros(int(np.prod(dims)), dtype=bool)
    for offset in itertools.product(range(-reach, reach + 1), repeat=len(dims)):
        ok = np.ones(len(coords[0]), dtype=bool)
        flat = np.zeros(len(coords[0]), dtype=np.int64)
        for c, o, d in zip(coords, offset, dims, strict=True):
            ok &= (c + o >= 0) & (c + o < d)
            flat = flat * d + c + o
        marked[flat[ok]] = True
    return marked[key]


def _kth(points: np.ndarray, which: np.ndarray, k: int, radius: float) -> np.ndarray:
    """Distance from each of ``points[which]`` to its k-th nearest other point, counted up to *radius*."""

    if len(points) <= k:  # fewer other points than k: the missing ones are far
        return np.full(len(which), radius)
    d, _ = cKDTree(points, balanced_tree=False, compact_nodes=False).query(
        points[which], k=[k + 1], distance_upper_bound=radius, workers=-1
    )
    return np.minimum(d[:, 0], radius)


def low_outliers(
    xyz: np.ndarray, *, cell_size: float = _LOW.cell_size, elevation_threshold: float = _LOW.elevation_threshold
) -> np.ndarray:
    """Extended local minimum: points well below everything else in their cell.

    In each square cell of *cell_size* (m), points are taken from the lowest
    up; a point is a low outlier while the gap to the next higher point of
    the cell exceeds *elevation_threshold* (m): the extended local minimum
    (ELM) test of Chen et al. (2012, doi:10.1016/j.isprsjprs.2012.07.001), as
    in PDAL's ``filters.elm``.  Multipath and below-ground echoes come out; a
    cell's real lowest ground, with other ground close above it, stays.

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
