"""Regions of a grid of the surface: planar regions, what lies around them, their walls.

Shared by the roofs (:mod:`stages.classify_objects.objects`) and the
bridge decks (:mod:`stages.classify_objects.bridges`): pure functions of
cell heights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from lidar.grid import Grid, step_labels

#: Cells around a roof looked at for its walls: this many cells out.
RING = 1

#: Widest wall shadow (m): an empty cell takes the lowest point seen this far beyond it (:func:`seen_below`).
SHADOW = 6.0


@dataclass(frozen=True)
class Surface:
    """Per cell: the highest and lowest point, counts, how planar its 3 x 3 cells are, and its ground points' z."""

    grid: Grid
    top: np.ndarray  # highest z per cell (NaN: empty)
    bottom: np.ndarray  # lowest z per cell
    count: np.ndarray  # points per cell
    single: np.ndarray  # single returns per cell
    residual: np.ndarray  # RMS (m) of ``top`` about the plane of its 3 x 3 cells (NaN: fewer than 6 cells)
    ground_sum: np.ndarray  # sum of the z of the cell's ground (2) points, added in file order
    ground_count: np.ndarray  # the cell's ground points
    last_top: np.ndarray  # highest last return per cell (NaN: none): a roof under a crown, the crown's echoes left out
    last_count: np.ndarray  # last returns per cell
    last_residual: np.ndarray | None  # ``residual`` of ``last_top``; None when every point is a last return


def planar_segments(top: np.ndarray, residual: np.ndarray, planarity: float, step: float) -> np.ndarray:
    """Labels (1, 2, ...; 0 = none) of the regions of planar cells joined across cell sides without a jump.

    A cell is planar when its residual is at most *planarity*; two planar
    neighbours (4-connected) join when their heights differ by at most *step*.
    """

    return step_labels(residual <= planarity, top, step, corners=False)  # NaN residual: not planar


def neighbour_views(shape: tuple[int, int], reach: int = 1, corners: bool = True):
    """For each offset (dr, dc) within *reach* (not 0, 0): the slices of the cells and of their neighbours.

    Yields ``(here, there, r0, c0)``: ``array[there]`` holds, at each cell of
    ``array[here]``, its neighbour (r + dr, c + dc); ``r0, c0`` is the first
    cell of *here*.  Without *corners*, only the offsets along a row or a
    column.
    """
    rows, cols = shape
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            if (dr == 0 and dc == 0) or (not corners and dr != 0 and dc != 0):
                continue
            r0, r1 = max(0, -dr), rows - max(0, dr)
            c0, c1 = max(0, -dc), cols - max(0, dc)
            yield (slice(r0, r1), slice(c0, c1)), (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc)), r0, c0


def wall_shares(labels: np.ndarray, top: np.ndarray, bottom: np.ndarray, min_height: float, n: int) -> np.ndarray:
    """Per label (index = label): the share of the cells within ``RING`` cells of it that lie below it.

    A cell around a region (not in it, holding points) lies below it when its
    lowest point is at least *min_height* below the highest top of the
    region's cells within ``RING`` cells of it.  Empty cells (voids, the
    survey's edge) do not count.  Regions with no cell around: share 0.
    *n*: the number of labels plus one (the length of the result).
    """
    rows, cols = labels.shape
    cells, owners, heights = [], [], []
    for here, there, r0, c0 in neighbour_views(labels.shape, RING):
        lab = labels[there]
        take = (lab > 0) & (lab != labels[here]) & np.isfinite(bottom[here])
        rr, cc = np.nonzero(take)
        cells.append((rr + r0) * cols + (cc + c0))
        owners.append(lab[take])
        heights.append(top[there][take])
    cell = np.concatenate(cells)
    owner = np.concatenate(owners)
    height = np.concatenate(heights)
    if len(cell) == 0:
        return np.zeros(n)
    key = owner * (rows * cols) + cell
    order = np.lexsort((height, key))
    last = np.r_[key[order][1:] != key[order][:-1], True]  # the highest roof top of each (region, cell)
    key, height = key[order][last], height[order][last]
    owner, cell = key // (rows * cols), key % (rows * cols)
    below = bottom.ravel()[cell] <= height - min_height
    around = np.bincount(owner, minlength=n)
    down = np.bincount(owner, weights=below.astype(np.float64), minlength=n)
    return np.divide(down, around, out=np.zeros(n), where=around > 0)


def grown(labels: np.ndarray, top: np.ndarray, bottom: np.ndarray, step: float) -> np.ndarray:
    """*labels* grown by one cell into unlabelled cells whose every point lies within *step* of a region's top.

    A roof's eaves and its ridge are not planar, but they are the roof's,
    not what stands around it; a cell holding a wall's foot, or the bend at
    the top of a slope, has points farther down and stays out.  A cell next
    to two regions joins the larger label.
    """
    out = labels.copy()
    free = (labels == 0) & np.isfinite(top)
    for here, there, _, _ in neighbour_views(labels.shape):
        lab = labels[there]
        level = (np.abs(top[here] - top[there]) <= step) & (np.abs(bottom[here] - top[there]) <= step)
        join = free[here] & (lab > 0) & level
        out[here] = np.where(join, np.maximum(out[here], lab), out[here])
    return out


def seen_below(bottom: np.ndarray, roofs: np.ndarray, reach_cells: int) -> np.ndarray:
    """*bottom* with its empty cells filled with the lowest point seen around them outside *roofs*.

    An empty cell beside a roof is, in airborne data, mostly the shadow of
    its wall (or a window, a dark or wet surface): it takes the lowest
    *bottom* of the cells outside *roofs* within *reach_cells* cells (a
    square); NaN where there is none.
    """

    outside = np.where(roofs | np.isnan(bottom), np.inf, bottom)
    low = ndimage.minimum_filter(outside, size=2 * reach_cells + 1, mode="constant", cval=np.inf)
    low[np.isinf(low)] = np.nan
    return np.where(np.isnan(bottom) & ~roofs, low, bottom)
