"""The bare earth under bridge decks: interpolated across each deck from the terrain either side of it.

The USGS Lidar Base Specification (usgs.gov, its Bridge and Saddle
Requirements): bridges are removed from the bare-earth DEM, and "the
bare-earth surface below the bridge shall be a continuous, logical
interpolation of the apparent terrain lateral to the bridge deck".  A
TIN of the ground points around a deck also joins its approaches, which
stand metres above the river at the deck's ends; here each cell under a
deck takes instead the straight line between the first DTM cells off the
deck on either side, across the deck (the shortest of four crossings).
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage


def deck_footprint(deck_points: np.ndarray) -> np.ndarray:
    """The cells under decks (bool grid) from the count of deck points (class 17) per cell.

    A deck's points leave empty cells between them on a fine grid: gaps of
    up to four cells are closed (a closing of two, local: tiles with a
    margin give the same cells), then one cell added around.
    """

    seen = deck_points > 0
    if not seen.any():
        return seen
    square = np.ones((3, 3), bool)
    closed = ndimage.binary_closing(np.pad(seen, 2), square, iterations=2)[2:-2, 2:-2] | seen
    return ndimage.binary_dilation(closed, square)


#: The four directions looked along (row, column steps), each with the one perpendicular to it.
DIRECTIONS = ((0, 1), (1, 0), (1, 1), (1, -1))
ACROSS = {(0, 1): (1, 0), (1, 0): (0, 1), (1, 1): (1, -1), (1, -1): (1, 1)}


def _march(mask: np.ndarray, r: np.ndarray, c: np.ndarray, d: tuple[int, int], reach: int):
    """From cells (*r*, *c*), both ways along *d*: the steps to the first cell of *mask* (NaN: none within *reach*)."""
    rows, cols = mask.shape
    ends = []
    for sign in (1, -1):
        k_hit = np.full(len(r), np.nan)
        todo = np.ones(len(r), dtype=bool)
        for k in range(1, reach + 1):
            rr, cc = r + sign * k * d[0], c + sign * k * d[1]
            inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            hit = todo & inside & mask[np.clip(rr, 0, rows - 1), np.clip(cc, 0, cols - 1)]
            k_hit[hit] = k
            todo &= ~hit & inside
            if not todo.any():
                break
        ends.append(k_hit)
    return ends


def across_decks(dtm: np.ndarray, footprint: np.ndarray, max_cells: float) -> np.ndarray:
    """*dtm* with the cells of *footprint* interpolated across the deck from the cells off it either side.

    At each cell, the deck runs along the direction (of the row, the column
    and the two diagonals) in which the footprint through the cell is the
    longest; across it, the first cell off the footprint with a value is
    looked for both ways, up to *max_cells* cells' length, and the cell
    takes the two values weighted by the distance to the other.  A cell
    with none on either side, or without a value (nodata), keeps its own.
    Each cell depends on the cells within *max_cells* of it only: a tile
    with that margin gives the same values as the whole grid.
    """
    r, c = np.nonzero(footprint)
    longest = np.full(len(r), -1.0)
    along = np.zeros(len(r), dtype=np.int64)
    off = ~footprint
    for i, d in enumerate(DIRECTIONS):
        step = float(np.hypot(*d))
        reach = int(max_cells / step)
        k1, k2 = _march(off, r, c, d, reach)
        run = (np.nan_to_num(k1, nan=reach + 1) + np.nan_to_num(k2, nan=reach + 1)) * step
        better = run > longest
        longest[better], along[better] = run[better], i
    out = dtm.copy()
    valued = np.isfinite(dtm) & off
    for i, d in enumerate(DIRECTIONS):
        mine = along == i
        if not mine.any():
            continue
        a = ACROSS[d]
        rr, cc = r[mine], c[mine]
        k1, k2 = _march(valued, rr, cc, a, int(max_cells / float(np.hypot(*a))))
        z1 = dtm[
            np.clip(rr + np.nan_to_num(k1).astype(int) * a[0], 0, dtm.shape[0] - 1),
            np.clip(cc + np.nan_to_num(k1).astype(int) * a[1], 0, dtm.shape[1] - 1),
        ]
        z2 = dtm[
            np.clip(rr - np.nan_to_num(k2).astype(int) * a[0], 0, dtm.shape[0] - 1),
            np.clip(cc - np.nan_to_num(k2).astype(int) * a[1], 0, dtm.shape[1] - 1),
        ]
        z1, z2 = np.where(np.isnan(k1), np.nan, z1), np.where(np.isnan(k2), np.nan, z2)
        both = (z1 * k2 + z2 * k1) / (k1 + k2)
        z = np.where(np.isfinite(both), both, np.where(np.isfinite(z1), z1, z2))
        keep = np.isfinite(z) & np.isfinite(dtm[rr, cc])
        out[rr[keep], cc[keep]] = z[keep]
    return out
