"""The survey's outline: where the rasters may have values, so the DTM does not reach into notches of the coverage.

A TIN covers the convex hull of its points: along a concave edge of the
coverage (the ends of flight lines, a bay between swaths) it draws long,
thin triangles whose far corners lie metres away, below or above, and the
cells inside them take heights no point supports (on ``configs/flight.yaml``,
1,084 level open-ground cells 1 to 8 m below the true terrain, 94 % of the
open ground's squared error).  IDW, nearest and the DSM's gap filling reach
``nodata_distance`` beyond the data the same way.

The outline is the χ-shape of the coverage (Duckham et al. 2008,
doi:10.1016/j.patcog.2008.03.023): the Delaunay triangulation of the centres
of the square cells (``CELL_M``) holding a usable point, peeled from the
outside: a triangle with an edge on the boundary longer than the limit is
removed, which exposes its neighbours, until no boundary edge is that long.
Holes enclosed by data (buildings, ponds, voids) are never reached and stay
inside; only notches open to the outside are cut.  We depart from the paper
in two ways: the points are occupied cells, not the points themselves (a
few hundred thousand for a 100 M-point survey), and triangles are removed
even when that leaves the shape non-simple (it is a mask, not a polygon).
The limit is the larger of ``outline_edge`` and four times the median edge
of the triangulation, so a sparse survey is not peeled away.

The outline is one small raster of the whole survey, made before the tiles
are, so every tile cuts its cells by the same shape: tiled rasters equal
untiled ones.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lidar.delaunay import delaunay
from lidar.grid import Grid
from stages.rasterize.interpolate import triangle_cover

#: Side of the outline's cells, metres.
CELL_M = 5.0
#: The peeling limit is at least this many times the triangulation's median edge.
MEDIAN_EDGES = 4.0


def occupied_cells(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The sorted unique keys of the outline cells (``CELL_M``, on multiples of it) holding the points (metres)."""
    ix = np.floor(np.asarray(x) / CELL_M).astype(np.int64) + _OFFSET
    iy = np.floor(np.asarray(y) / CELL_M).astype(np.int64) + _OFFSET
    return np.unique((ix << 32) | iy)


_OFFSET = 1 << 30  # cell indices of +-5,000 km: the key's halves stay positive


def _unkey(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return (keys >> 32) - _OFFSET, (keys & 0xFFFFFFFF) - _OFFSET


@dataclass(frozen=True)
class Outline:
    """The outline as a raster of ``CELL_M`` cells, row 0 north: cell (``ix0 + col``, ``iy1 - row``) is
    ``inside[row, col]``; ``everywhere``: no outline (every place is inside)."""

    ix0: int
    iy1: int
    inside: np.ndarray
    everywhere: bool = False

    def contains(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Whether the points (metres) lie inside the outline."""
        if self.everywhere:
            return np.ones(np.shape(x), dtype=bool)
        col = np.floor(np.asarray(x) / CELL_M).astype(np.int64) - self.ix0
        row = self.iy1 - np.floor(np.asarray(y) / CELL_M).astype(np.int64)
        rows, cols = self.inside.shape
        ok = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
        out = np.zeros(np.shape(x), dtype=bool)
        out[ok] = self.inside[row[ok], col[ok]]
        return out

    def save(self, path: Path) -> None:
        """The mask as ``.npy`` (an empty array: everywhere); its corner goes with the task, not the file."""
        np.save(path, np.zeros((0, 0), dtype=bool) if self.everywhere else self.inside, allow_pickle=False)

    @classmethod
    def load(cls, path: Path, ix0: int, iy1: int) -> Outline:
        inside = np.load(path, allow_pickle=False)
        return cls(ix0, iy1, inside, everywhere=inside.size == 0)


EVERYWHERE = Outline(0, 0, np.zeros((0, 0), dtype=bool), everywhere=True)


def survey_outline(keys: np.ndarray, min_edge: float) -> Outline:
    """The χ-shape of the occupied cells *keys* (:func:`occupied_cells`), peeled along boundary edges longer
    than ``max(min_edge, MEDIAN_EDGES x median edge)`` metres; *min_edge* 0: no outline (everywhere)."""

    ix, iy = _unkey(np.asarray(keys, dtype=np.int64))
    if min_edge <= 0 or len(ix) < 3:
        return EVERYWHERE
    ix0, iy1 = int(ix.min()), int(iy.max())
    grid = Grid(ix0 * CELL_M, (iy1 + 1) * CELL_M, CELL_M, int(ix.max()) - ix0 + 1, iy1 - int(iy.min()) + 1)
    # the cell centres relative to the grid's top-left corner, as the TIN draws them
    xy = np.column_stack(((ix - ix0 + 0.5) * CELL_M, -(iy1 - iy + 0.5) * CELL_M))
    mesh = delaunay(xy)  # a lattice (cocircular points): lidar.delaunay
    if mesh is None:  # all on a line: nothing to peel
        return EVERYWHERE
    simplices, neighbours = mesh
    kept = _peel(simplices, neighbours, xy, min_edge)
    inside = triangle_cover(xy, simplices[kept], grid)
    inside[iy1 - iy, ix - ix0] = True  # an occupied cell is always inside
    return Outline(ix0, iy1, inside)


def _peel(simplices: np.ndarray, neighbours: np.ndarray, xy: np.ndarray, min_edge: float) -> np.ndarray:
    """Which triangles stay: those with an exposed edge (on the boundary, or shared with a removed triangle)
    longer than the limit go, round after round, until none has one."""
    a = xy[simplices]  # (t, 3, 2)
    # edge k lies opposite vertex k, from vertex k + 1 to vertex k + 2 (Triangle's neighbour k shares it)
    length = np.hypot(*(a[:, [2, 0, 1]] - a[:, [1, 2, 0]]).transpose(2, 0, 1))
    limit = max(min_edge, MEDIAN_EDGES * float(np.median(length)))
    long = length > limit
    kept = np.ones(len(simplices), dtype=bool)
    frontier = np.flatnonzero((long & (neighbours < 0)).any(axis=1))
    while len(frontier):
        kept[frontier] = False
        nb = neighbours[frontier].ravel()
        nb = np.unique(nb[nb >= 0])
        nb = nb[kept[nb]]
        around = neighbours[nb]
        exposed = (around < 0) | ~kept[np.maximum(around, 0)]
        frontier = nb[(exposed & long[nb]).any(axis=1)]
    return kept
