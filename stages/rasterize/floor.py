"""The forest floor: ground points under vegetation that lie above the ground's lower envelope are left out of the DTM.

A ground filter's tolerance (SMRF's 0.45 m and more on slopes) admits the
understory's echoes under trees: ferns, shrubs, dead wood and litter, up to
half a metre above the floor, and never below it.  A TIN through every
ground point follows them: on the ``lasR/bcts`` forest, the DTM sat +0.28 m
(median) above the provider's ground.  Under cover, so, the floor is the
lower envelope: the TIN of the lowest ground point of each cell of
``floor_cell`` (cells on whole multiples of it), densified once (an
iteration of Axelsson's densification) with, in each half cell, the highest
point above it within ``floor_tolerance``: the lowest points' TIN cuts the
top off a convex floor (a bank, a ridge under a hedge: it spans the crest
between the lowest points of its flanks), the densified one keeps what
curves gently, and the understory, farther up, stays out.  A ground point
farther than ``floor_tolerance`` above the densified TIN is left out of the
DTM (its class stays ground).  Only the points above the first TIN by more
than the tolerance are tested against the second: no point of the floor
pays for it.  In the open the point is kept whatever its height: there the
errors are the scanner's, on both sides of the surface, and the lowest point
of a cell would bias a dense survey's DTM low.

A point is under cover when the highest return of its DTM cell is more than
:data:`COVER` above it.  The envelope is Axelsson's idea of a TIN densified
from the lowest points (Axelsson, P. 2000, DEM generation from laser scanner
data using adaptive TIN models, IAPRS 33(B4), 110-117), used here to
select, not to classify.  Measured on every labelled project of
``benchmarks/real_classes.py``: docs/stages/rasterize.md.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from lidar.clouds import progress_chunk
from lidar.delaunay import delaunay
from lidar.grid import Grid, cell_of
from pipeline.log import stage_progress

#: A return this far (m) above a ground point covers it: the lower break of medium vegetation (ASPRS class 4,
#: stages.classify_objects.vegetation.breaks), a shrub's or a tree's crown rather than the floor's litter.
COVER = 2.0


def highest_per_cell(xyz: np.ndarray, cell: float, among: np.ndarray) -> np.ndarray:
    """The index of the highest of the points *among* (a mask) in each cell of side *cell* holding one."""
    chosen = np.flatnonzero(among)
    flipped = np.column_stack((xyz[chosen, :2], -xyz[chosen, 2]))
    return chosen[lowest_per_cell(flipped, cell)] if len(chosen) else chosen


def lowest_per_cell(xyz: np.ndarray, cell: float) -> np.ndarray:
    """The index of the lowest point of each cell of side *cell* (anchored at whole multiples) holding one."""
    ix = np.floor(xyz[:, 0] / cell).astype(np.int64)
    iy = np.floor(xyz[:, 1] / cell).astype(np.int64)
    key = (ix - ix.min()) * (int(iy.max() - iy.min()) + 1) + (iy - iy.min())
    order = np.lexsort((xyz[:, 2], key))
    ranked = key[order]
    return order[np.r_[True, ranked[1:] != ranked[:-1]]]


def understory(ground: np.ndarray, highest: np.ndarray, grid: Grid, *, cell: float, tolerance: float) -> np.ndarray:
    """Which *ground* points ((n, 3), metres) are understory: under cover and above the floor by *tolerance*.

    *highest*: the highest return per cell of *grid* (NaN: none), the grid
    the points lie on; *cell*: the envelope's cell (m).  The envelope is
    worked out around the covered points only (their cells and the cells
    next to them), so an open survey pays nothing.
    """
    out = np.zeros(len(ground), dtype=bool)
    if len(ground) < 3:
        return out
    row, col = cell_of(ground, grid)
    top = np.full(len(ground), np.nan)
    on = row >= 0
    top[on] = highest[row[on], col[on]]
    covered = top - ground[:, 2] > COVER
    if not covered.any():
        return out
    ix = np.floor(ground[:, 0] / cell).astype(np.int64)
    iy = np.floor(ground[:, 1] / cell).astype(np.int64)
    span = int(iy.max() - iy.min()) + 3
    key = (ix - ix.min() + 1) * span + (iy - iy.min() + 1)
    near = np.unique((key[covered][:, None] + (np.arange(-1, 2)[:, None] * span + np.arange(-1, 2)).ravel()).ravel())
    idx = np.flatnonzero(np.isin(key, near))
    sub = ground[idx]
    low = lowest_per_cell(sub, cell)
    with stage_progress(2 * len(sub), "understory, 2 passes over the ground points near cover", unit="pt") as bar:
        above = sub[:, 2] - tin_at(sub[low], sub[:, :2], bar.update)  # NaN: outside the hull
        # densified by the highest point within the tolerance of each half cell: what lifts the TIN onto a crest
        lift = highest_per_cell(sub, cell / 2, ~(above > tolerance) & (above > 0))
        test = np.flatnonzero(covered[idx] & (above > tolerance))
        if not len(test):
            return out
        vertices = sub[np.union1d(low, lift)]
        above = sub[test, 2] - tin_at(vertices, sub[test, :2], lambda n: bar.update(n * len(sub) / len(test)))
    out[idx[test]] = above > tolerance  # NaN (outside the hull): kept
    return out


#: Points a TIN is evaluated at, at most, at a time (:func:`tin_at`).
AT_ONCE = 1_000_000
#: Most triangles a point's walk crosses (:func:`tin_at`); a walk from a triangle at the nearest vertex of a
#: Delaunay TIN crosses a few.  Points still walking after it are NaN (none seen).
MAX_WALK = 1_000


def tin_at(vertices: np.ndarray, xy: np.ndarray, advance=None) -> np.ndarray:
    """The Delaunay TIN of *vertices* ((m, 3)) at the points *xy* ((n, 2)), linear in each triangle; NaN
    outside its hull, or everywhere when the vertices lie on a line.

    Triangulated as the DTM is (:func:`lidar.delaunay.delaunay`); each point is found by a visibility walk (Devillers, Pion &
    Teillaud 2002, doi:10.1142/S0129054102001047), all points a step at a
    time, from a triangle at its nearest vertex.  The walk ends in a Delaunay
    triangulation.  SciPy's ``LinearNDInterpolator`` gives the same values
    (up to the diagonal of cocircular vertices, where the Delaunay TIN is not
    unique) on coordinates from a local origin, as here; on a projected
    CRS's raw coordinates it was off by metres (Qhull's rounding).  Its
    Qhull took 14 times Triangle's time on 283 k vertices, and its walk's
    time follows the points' order (265 s for 3 M points in random order,
    0.8 s in cell order).  *advance*: told the points done.
    """
    out = np.full(len(xy), np.nan)
    origin = vertices[:, :2].mean(axis=0) if len(vertices) else np.zeros(2)
    vxy = np.ascontiguousarray(vertices[:, :2] - origin)
    mesh = delaunay(vxy)
    if mesh is None:  # on a line: no triangle
        if advance is not None:
            advance(len(xy))
        return out
    tris, neighbours = mesh
    start = np.full(len(vxy), -1, dtype=np.int64)
    start[tris.ravel()] = np.repeat(np.arange(len(tris)), 3)  # a triangle at each vertex (duplicates: none)
    used = np.flatnonzero(start >= 0)
    tree = cKDTree(vxy[used])
    step = progress_chunk(len(xy), AT_ONCE)
    for a in range(0, len(xy), step):
        q = xy[a : a + step] - origin
        out[a : a + step] = _walk(vxy, vertices[:, 2], tris, neighbours, start[used[tree.query(q)[1]]], q)
        if advance is not None:
            advance(len(q))
    return out


def _walk(vxy, z, tris, neighbours, t, q) -> np.ndarray:
    """Each point *q* located from the triangle *t* by stepping across the edge it lies farthest beyond (edge
    k is opposite vertex k, as Triangle numbers neighbours); its TIN value, NaN when it leaves the hull."""
    out = np.full(len(q), np.nan)
    todo = np.arange(len(q))
    t = t.copy()
    for _ in range(MAX_WALK):
        if not len(todo):
            break
        p = vxy[tris[t]]  # (k, 3, 2)
        qq = q[todo]
        # twice the signed area of (p[k+1], p[k+2], q), over the triangle's: barycentric coordinate k
        d = np.empty((len(todo), 3))
        for k in range(3):
            b, c = p[:, (k + 1) % 3], p[:, (k + 2) % 3]
            d[:, k] = (b[:, 0] - qq[:, 0]) * (c[:, 1] - qq[:, 1]) - (b[:, 1] - qq[:, 1]) * (c[:, 0] - qq[:, 0])
        area = d.sum(axis=1)
        lam = d / area[:, None]
        worst = lam.argmin(axis=1)
        inside = lam[np.arange(len(todo)), worst] >= -1e-12
        out[todo[inside]] = (lam[inside] * z[tris[t[inside]]]).sum(axis=1)
        nxt = neighbours[t[~inside], worst[~inside]]
        todo, t = todo[~inside], nxt
        gone = t < 0  # across the hull: outside it
        todo, t = todo[~gone], t[~gone]
    return out
