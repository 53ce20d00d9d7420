"""Cell-aligned grids and interpolation of scattered points onto them.

A grid's edges are whole multiples of its resolution, so DTMs of
neighbouring surveys (or tiles) made at the same resolution line up cell for
cell.  Values are computed at cell centres.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field
from scipy import ndimage
from scipy.spatial import cKDTree

from lidar.arrays import sorted_union
from lidar.delaunay import delaunay
from lidar.grid import Grid
from lidar.neighbours import canonical_neighbours
from pipeline.config import StrictModel

#: Most neighbours (cells x k) one block of :func:`idw` or :func:`nearest` asks the k-d tree for at once.
NEIGHBOUR_BLOCK = 1 << 21

if TYPE_CHECKING:
    from pipeline.log import Progress


#: Most ``idw.neighbors``: each cell's search grows with it (1,000 take 30 s for the sample's 196,608 cells, 2 cores).
MAX_NEIGHBORS = 1_000


class IdwParams(StrictModel):
    """The parameters of :func:`idw` (``stages.rasterize.idw``)."""

    neighbors: int = Field(
        8,
        ge=1,
        le=MAX_NEIGHBORS,
        description=f"nearest ground points averaged per cell (at most {MAX_NEIGHBORS:,}: each cell's cost grows "
        "with it; fewer when the tile has fewer ground points)",
    )
    power: float = Field(2.0, gt=0, description="weights are 1 / distance**power")


class TinParams(StrictModel):
    """The parameters of :func:`tin` (``stages.rasterize.tin``)."""

    thin: bool = Field(
        True,
        description="in cells with more than 4 ground points, triangulate one per half cell (the nearest to its "
        "centre); false: every ground point",
    )


#: Each method's parameters at their defaults: the functions' defaults are the configuration's.
_TIN, _IDW = TinParams(), IdwParams()


def thin_points(xy: np.ndarray, cell: float, *, sparse: int = 0) -> np.ndarray:
    """Indices (ascending) of one point per square of side *cell*: the nearest to its centre.

    *xy* are coordinates relative to a grid anchor (a whole multiple of
    2 *cell*), so the squares of a tile are the squares of the whole
    survey.  Ties (equal distance, coincident points) go to the first point
    in the input order.  With *sparse*, every point of a block of 2 x 2
    squares holding at most *sparse* points is kept (coincident ones once,
    the first).  Cost: a few unbuffered ``ufunc.at`` passes, no sort of the
    dense blocks.
    """
    n = len(xy)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    col = np.floor(xy[:, 0] / cell).astype(np.int64)
    row = np.floor(-xy[:, 1] / cell).astype(np.int64)
    c_lo, r_lo = int(col.min()) // 2 * 2, int(row.min()) // 2 * 2
    width = int(col.max()) - c_lo + 2
    size = (int(row.max()) - r_lo + 2) * width
    d = xy[:, 0] - (col + 0.5) * cell
    d *= d
    dy = xy[:, 1] + (row + 0.5) * cell
    dy *= dy
    d += dy
    del dy
    col -= c_lo
    row -= r_lo
    square = row * width + col
    best = np.full(size, np.inf)
    np.minimum.at(best, square, d)
    cand = np.flatnonzero(d == best[square])
    first = np.full(size, n, dtype=np.int64)
    np.minimum.at(first, square[cand], cand)
    keep = np.zeros(n, dtype=bool)
    keep[first[first < n]] = True
    if sparse:
        block = (row // 2) * (width // 2) + col // 2
        few = np.bincount(block)[block] <= sparse
        keep &= ~few
        alone = np.flatnonzero(few)
        keep[alone[_unique_xy(xy[alone])]] = True
    return np.flatnonzero(keep)


def _unique_xy(xy: np.ndarray) -> np.ndarray:
    """Indices (ascending) of the first point of each distinct x, y."""
    order = np.lexsort((np.arange(len(xy)), xy[:, 1], xy[:, 0]))
    s = xy[order]
    new = np.ones(len(xy), dtype=bool)
    new[1:] = (s[1:, 0] != s[:-1, 0]) | (s[1:, 1] != s[:-1, 1])
    return np.sort(order[new])


def tin(
    points: np.ndarray | list[np.ndarray],
    grid: Grid,
    *,
    nodata_distance: float,
    nodata: float = np.nan,
    thin: bool = _TIN.thin,
    margin: float | None = 25.0,
    batch_cells: int = 1_000_000,
    progress: Progress | None = None,
    max_hull_edge: float = 0.0,
) -> np.ndarray:
    """Linear interpolation on the Delaunay triangulation (TIN) of *points*, at the cell centres of *grid*.

    *points*: x, y, z (n, 3) of at least 3 points, or a list holding them
    (emptied: the array is freed once the TIN has what it needs).  Cells
    farther than *nodata_distance* from every point, or outside the hull,
    get *nodata*.  *thin*: in cells holding more than four points, one point
    per half-cell square is triangulated (:func:`thin_points`).  *margin*:
    the points within it of the grid are triangulated first, and all of
    them only when that could change a cell (None: all at once).
    *batch_cells* bounds memory; *progress* goes to ``grid.rows``.  The
    triangulation is Shewchuk's Triangle (doi:10.1007/BFb0014497), drawn by
    scan conversion as GDAL and PDAL do; the margin's proof is the
    empty-circumcircle property of Delaunay triangles (docs/stages/rasterize.md).
    Returns a (grid.rows, grid.cols) float64 array.
    """
    pts = np.asarray(points.pop() if isinstance(points, list) else points, dtype=np.float64)
    if len(pts) < 3:
        raise ValueError("a TIN needs at least 3 points")
    # Work around the grid's anchor (the whole grid's corner, for a window
    # too): exact differences on large absolute coordinates (UTM), the same
    # in a tile as in the whole survey.
    origin = np.array([grid.xmin, grid.ymax])
    xy = pts[:, :2] - origin
    z = pts[:, 2].copy()  # not a view: the points handed over are freed here (a third of their memory kept)
    del pts, points
    far = _far_from(xy, grid, nodata_distance)  # water, gaps: nodata even inside the hull

    def chosen(sel: np.ndarray) -> np.ndarray:
        """The points of *sel* (whole cells) that are triangulated: thinned, or distinct x, y."""
        return sel[thin_points(xy[sel], grid.resolution / 2.0, sparse=4) if thin else _unique_xy(xy[sel])]

    inner = _near_grid(xy, grid, margin)
    if inner is None:  # every point is near the grid
        out, _ = _tin_draw(xy, z, chosen(np.arange(len(z))), grid, batch_cells, progress, max_hull_edge)
    else:
        keep = chosen(np.flatnonzero(inner))
        rest: list[np.ndarray] = []

        def outer() -> np.ndarray:  # the points left out, chosen as they would be; once, if asked for
            if not rest:
                rest.append(chosen(np.flatnonzero(~inner)))
            return rest[0]

        out, drawn = _tin_draw(xy, z, keep, grid, batch_cells, progress, max_hull_edge)
        if not _same_as_all(xy, keep, outer, drawn, grid, margin, np.isnan(out).reshape(far.shape) & ~far):
            keep = sorted_union(keep, outer())  # ascending: the input order, as if all were triangulated at once
            out, _ = _tin_draw(xy, z, keep, grid, batch_cells, None, max_hull_edge)  # the rows counted once
    out = out.reshape(grid.rows, grid.cols)
    out[far] = np.nan
    out[np.isnan(out)] = nodata
    return out


def _near_grid(xy: np.ndarray, grid: Grid, margin: float | None) -> np.ndarray | None:
    """Points in the cells of *grid* or within *margin* (whole cells) of it; None: all of them, or no margin."""
    if margin is None:
        return None
    res = grid.resolution
    m = int(math.ceil(margin / res))
    # the cell of each point as :func:`thin_points` sees it (squares of half a cell, two per cell)
    col = np.floor(xy[:, 0] / (res / 2.0)).astype(np.int64) // 2 - grid.col0
    inner = (col >= -m) & (col < grid.cols + m)
    del col
    row = np.floor(-xy[:, 1] / (res / 2.0)).astype(np.int64) // 2 - grid.row0
    inner &= (row >= -m) & (row < grid.rows + m)
    return None if inner.all() else inner


def _long_on_hull(xy: np.ndarray, simplices: np.ndarray, neighbours: np.ndarray, limit: float) -> np.ndarray:
    """Triangles with an edge on the triangulation's hull (no neighbour across it) longer than *limit*."""
    out = np.zeros(len(simplices), dtype=bool)
    hull = np.flatnonzero((neighbours < 0).any(axis=1))  # a few in a million: only these are measured
    a = xy[simplices[hull]]
    # edge k lies opposite vertex k (Triangle's neighbour k shares it)
    length = np.hypot(*(a[:, [2, 0, 1]] - a[:, [1, 2, 0]]).transpose(2, 0, 1))
    out[hull[((neighbours[hull] < 0) & (length > limit)).any(axis=1)]] = True
    return out


def _tin_draw(
    xy, z, keep, grid: Grid, batch_cells: int, progress, max_hull_edge: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate the points *keep* (ascending) and draw them on *grid*: flat values, drawing triangles."""

    out = np.full(grid.rows * grid.cols, np.nan)
    drawn = np.zeros((0, 3), dtype=np.int64)
    if len(keep) >= 3:
        vxy = np.ascontiguousarray(xy[keep])
        mesh = delaunay(vxy)
        simplices = None if mesh is None else mesh[0]  # None: all points on a line
        if simplices is not None and max_hull_edge:
            simplices = simplices[~_long_on_hull(vxy, simplices, mesh[1], max_hull_edge)]
        if simplices is not None and len(simplices):
            drawn = keep[_draw_triangles(vxy, z[keep], simplices, grid, out, batch_cells, progress)]
            return out, drawn
    if progress is not None:
        progress.update(grid.rows)
    return out, drawn


def _same_as_all(xy, keep, outer, drawn, grid: Grid, margin: float, undrawn: np.ndarray) -> bool:
    """Whether the TIN of the points *keep* drew the grid as the TIN of *keep* and *outer* would.

    True when every triangle that drew a cell (*drawn*, rows of indices
    into *xy*) has an empty circumcircle among the *outer* points (it is
    then a triangle of the whole triangulation), and no cell within reach
    of a point yet drawn by no triangle (*undrawn*, outside the hull of
    *keep*) lies inside the convex hull of all the points (where the whole
    triangulation would draw it).  Circumcircles inside the region of
    *keep* (the grid plus *margin*) need no look at *outer*, a function
    (the points left out are chosen only if they are needed).
    """
    if undrawn.any():
        from scipy.spatial import ConvexHull, QhullError

        rest = outer()
        if not len(rest):
            return True
        try:
            hull = ConvexHull(np.concatenate((xy[keep], xy[rest])))
        except QhullError:  # all points on a line: nothing is drawn either way
            return not len(drawn)
        gx, gy = grid.centres()
        q = np.column_stack((gx[undrawn] - grid.xmin, gy[undrawn] - grid.ymax))
        if in_hull(hull, q, 1e-9 * max(1.0, float(np.abs(q).max()))).any():  # on or inside the hull
            return False
    if not len(drawn):
        return True
    a, b, c = xy[drawn[:, 0]], xy[drawn[:, 1]], xy[drawn[:, 2]]
    bx, by = b[:, 0] - a[:, 0], b[:, 1] - a[:, 1]
    cx, cy = c[:, 0] - a[:, 0], c[:, 1] - a[:, 1]
    d = 2.0 * (bx * cy - by * cx)
    b2, c2 = bx * bx + by * by, cx * cx + cy * cy
    ux, uy = (cy * b2 - by * c2) / d, (bx * c2 - cx * b2) / d
    radius = np.hypot(ux, uy) * (1.0 + 1e-9) + 1e-9  # a point on the circle counts as inside: no ties
    ux += a[:, 0]
    uy += a[:, 1]
    res = grid.resolution
    m = int(math.ceil(margin / res))
    x0, x1 = (grid.col0 - m) * res, (grid.col0 + grid.cols + m) * res
    y1, y0 = -(grid.row0 - m) * res, -(grid.row0 + grid.rows + m) * res
    out_of = ~((ux - radius > x0) & (ux + radius < x1) & (uy - radius > y0) & (uy + radius < y1))
    if not out_of.any():
        return True

    rest = outer()
    if not len(rest):
        return True
    tree = cKDTree(xy[rest], balanced_tree=False, compact_nodes=False)
    dist, _ = tree.query(np.column_stack((ux[out_of], uy[out_of])), k=1, workers=-1)
    return bool((dist > radius[out_of]).all())


def in_hull(hull, xy: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """Which of the points *xy* (n, 2+) lie inside the 2-D convex *hull* (``scipy.spatial.ConvexHull``), every
    facet's ``normal . p + offset`` at most *tol* (positive: on the hull too; negative: strictly inside).
    In blocks of 65,536 points."""
    eq = hull.equations
    xy = np.asarray(xy)[:, :2]
    out = np.empty(len(xy), dtype=bool)
    for start in range(0, len(xy), 65_536):
        block = xy[start : start + 65_536]
        out[start : start + len(block)] = ((block @ eq[:, :2].T + eq[:, 2]) <= tol).all(axis=1)
    return out


def _far_from(xy: np.ndarray, grid: Grid, distance: float) -> np.ndarray:
    """Cells of *grid* whose centre is farther than *distance* from every point (*xy* relative to the anchor).

    A Euclidean distance transform of the cells holding a point gives each
    cell's distance to the nearest such cell's centre; the nearest point is
    within half a cell's diagonal of that.  Only cells that this leaves in
    doubt (within that margin of *distance*) are measured exactly, on a
    k-d tree of the points: the same answer as a k-d tree for every cell.
    """

    res = grid.resolution
    pad = int(math.ceil(distance / res)) + 2
    # the cells of the grid plus a margin, counted from the whole grid's anchor
    r0, c0 = grid.row0 - pad, grid.col0 - pad
    rows, cols = grid.rows + 2 * pad, grid.cols + 2 * pad
    col = np.floor(xy[:, 0] / res).astype(np.int64) - c0
    row = np.floor(-xy[:, 1] / res).astype(np.int64) - r0
    inside = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    held = np.zeros((rows, cols), dtype=bool)
    held[row[inside], col[inside]] = True
    if not held.any():
        return np.ones((grid.rows, grid.cols), dtype=bool)
    cells = ndimage.distance_transform_edt(~held)[pad : pad + grid.rows, pad : pad + grid.cols] * res
    slack = 0.7072 * res  # > half the diagonal, for rounding
    far = cells - slack > distance
    doubt = np.flatnonzero((cells + slack >= distance) & ~far)
    if len(doubt):
        gx, gy = grid.centres()
        q = np.column_stack((gx.ravel()[doubt] - grid.xmin, gy.ravel()[doubt] - grid.ymax))
        d, _ = cKDTree(xy, balanced_tree=False, compact_nodes=False).query(
            q, k=1, distance_upper_bound=distance, workers=-1
        )
        far.ravel()[doubt] = ~np.isfinite(d)
    return far


def triangle_cover(xy: np.ndarray, simplices: np.ndarray, grid: Grid) -> np.ndarray:
    """Which cells of *grid* (rows, cols) have their centre inside one of the triangles *simplices* of *xy*.

    *xy* relative to the grid's anchor, as :func:`_draw_triangles` takes them.
    """
    out = np.full(grid.rows * grid.cols, np.nan)
    if len(simplices):
        _draw_triangles(xy, np.ones(len(xy)), simplices, grid, out, 1 << 22, None)
    return np.isfinite(out).reshape(grid.rows, grid.cols)


#: With a progress, the triangles are drawn in at least this many batches, of at least MIN_BATCH_CELLS candidates.
PROGRESS_BATCHES = 20
MIN_BATCH_CELLS = 10_000


def _draw_triangles(xy, z, simplices, grid: Grid, out: np.ndarray, batch_cells: int, progress) -> np.ndarray:
    """Fill *out* (flat, rows * cols) with each triangle's plane at the cell centres inside it.

    Coordinates *xy* are relative to the grid's anchor (top-left corner of
    the whole grid); cell centres are at ``((col + 0.5) r, -(row + 0.5) r)``
    with the whole grid's row and column.  Only triangles whose box holds a
    cell centre of the grid are drawn (most of a dense TIN's hold none), in
    a canonical order: vertices in ascending index, triangles in
    lexicographic order.  A subset of the points (a tile) triangulates its
    interior into the same triangles; drawn in the same order from the same
    vertex order, they give the same values bit for bit (a cell on an edge
    shared by two triangles takes the later one's, everywhere alike).
    Returns the triangles that drew a cell (vertex indices, ascending).
    """
    res = grid.resolution
    s, c0, c1, r0, r1 = _canonical_boxes(xy, simplices, grid)
    p0, p1, p2 = xy[s[:, 0]], xy[s[:, 1]], xy[s[:, 2]]
    ax, ay = p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1]
    bx, by = p2[:, 0] - p0[:, 0], p2[:, 1] - p0[:, 1]
    det = ax * by - ay * bx
    # The candidate cells: in each row of a triangle's box, the columns from one
    # before to one after where the row's centre line crosses the triangle (a
    # superset of the cells the test below accepts, as the test's tolerance is
    # far below a cell), in the box's row-major order: the cells drawn and their
    # order are those of the whole box, with about half the candidates.
    rows_in = r1 - r0 + 1
    rows_in[np.abs(det) < 1e-12] = 0  # degenerate (collinear) triangles draw nothing
    pair_end = np.cumsum(rows_in)
    pair_t = np.repeat(np.arange(len(rows_in)), rows_in)
    pair_row = r0[pair_t] + np.arange(len(pair_t)) - np.repeat(pair_end - rows_in, rows_in)
    pair_c0, pair_c1 = c0[pair_t], c1[pair_t]
    wide = np.flatnonzero(((rows_in > 2) & (c1 - c0 > 2))[pair_t])  # small boxes: every cell (cheaper)
    if len(wide):
        lo, hi = _row_spans(xy, s, pair_t[wide], pair_row[wide], res)
        pair_c0[wide], pair_c1[wide] = np.maximum(lo, pair_c0[wide]), np.minimum(hi, pair_c1[wide])
    pair_w = np.maximum(pair_c1 - pair_c0 + 1, 0)
    pair_cells = np.cumsum(pair_w)  # candidates up to each pair's last
    ends = np.concatenate(([0], pair_cells))[pair_end]  # candidates up to each triangle's last
    total = int(ends[-1]) if len(ends) else 0
    z0, z1, z2 = z[s[:, 0]], z[s[:, 1]], z[s[:, 2]]
    eps = 1e-9
    used = np.zeros(len(ends), dtype=bool)
    if progress is not None:  # batches small enough for the progress to move (drawn in the same order: same cells)
        batch_cells = min(batch_cells, max(-(-total // PROGRESS_BATCHES), MIN_BATCH_CELLS))
    first = 0
    while first < len(ends):
        # triangles [first, last): at most batch_cells candidate cells (at least one triangle)
        base = int(ends[first - 1]) if first else 0
        last = max(first + 1, int(np.searchsorted(ends, base + batch_cells, side="right")))
        n = int(ends[last - 1]) - base
        if n:
            p_lo, p_hi = (int(pair_end[first - 1]) if first else 0), int(pair_end[last - 1])
            w = pair_w[p_lo:p_hi]
            pair = np.repeat(np.arange(p_lo, p_hi), w)
            col = pair_c0[pair] + np.arange(n) - np.repeat(pair_cells[p_lo:p_hi] - w - base, w)
            row = pair_row[pair]
            t = pair_t[pair]
            vx = (col + 0.5) * res - p0[t, 0]
            vy = -(row + 0.5) * res - p0[t, 1]
            l1 = (vx * by[t] - vy * bx[t]) / det[t]
            l2 = (ax[t] * vy - ay[t] * vx) / det[t]
            inside = (l1 >= -eps) & (l2 >= -eps) & (l1 + l2 <= 1.0 + eps)
            value = z0[t] + l1 * (z1[t] - z0[t]) + l2 * (z2[t] - z0[t])  # exact on flat triangles
            out[(row[inside] - grid.row0) * grid.cols + (col[inside] - grid.col0)] = value[inside]
            used[t[inside]] = True
        if progress is not None and total:
            progress.update(grid.rows * n / total)
        first = last
    if progress is not None and not total:
        progress.update(grid.rows)
    return s[used]


def _row_spans(xy, s, tri: np.ndarray, row: np.ndarray, res: float) -> tuple[np.ndarray, np.ndarray]:
    """For each (triangle *tri*, grid *row*): the first and last column whose centre may be in the triangle.

    The row's centre line meets the triangle's edges between x_lo and x_hi;
    the columns returned run from one before the first centre at or right
    of x_lo to one after the last at or left of x_hi (an edge's crossing is
    taken at its clamped end when the line misses it by rounding).
    """
    y = -(row + 0.5) * res
    lo = np.full(len(tri), np.inf)
    hi = np.full(len(tri), -np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        xa, ya = xy[s[tri, i], 0], xy[s[tri, i], 1]
        xb, yb = xy[s[tri, j], 0], xy[s[tri, j], 1]
        dy = yb - ya
        meets = (np.minimum(ya, yb) - res <= y) & (y <= np.maximum(ya, yb) + res)
        flat = dy == 0
        f = np.clip(np.divide(y - ya, dy, out=np.zeros_like(y), where=~flat), 0.0, 1.0)
        x = xa + f * (xb - xa)
        x_lo = np.where(flat, np.minimum(xa, xb), x)
        x_hi = np.where(flat, np.maximum(xa, xb), x)
        lo = np.where(meets, np.minimum(lo, x_lo), lo)
        hi = np.where(meets, np.maximum(hi, x_hi), hi)
    c0 = np.ceil(lo / res - 0.5) - 1
    c1 = np.floor(hi / res - 0.5) + 1
    empty = ~(np.isfinite(c0) & np.isfinite(c1))
    c0[empty], c1[empty] = 0, -1
    return c0.astype(np.int64), c1.astype(np.int64)


def _canonical_boxes(xy, simplices, grid: Grid) -> tuple[np.ndarray, ...]:
    """The triangles whose box holds a cell centre of *grid*, in canonical order, and their boxes.

    Returns ``(s, c0, c1, r0, r1)``: the vertices of each triangle in
    ascending index, the triangles in lexicographic order (:func:`_draw_triangles`),
    and the first and last column and row (whole-grid indices, int64) of
    the cell centres in each triangle's box.
    """
    res = grid.resolution
    # Each triangle's box in whole-grid cell indices, a million triangles at a
    # time (bounded temporaries); keep those that hold a cell centre.
    boxes = []
    for start in range(0, len(simplices), 1_000_000):
        part = simplices[start : start + 1_000_000]
        x = [xy[part[:, i], 0] for i in range(3)]
        y = [xy[part[:, i], 1] for i in range(3)]
        c0 = np.maximum(np.ceil(np.minimum(np.minimum(x[0], x[1]), x[2]) / res - 0.5), grid.col0)
        c1 = np.minimum(np.floor(np.maximum(np.maximum(x[0], x[1]), x[2]) / res - 0.5), grid.col0 + grid.cols - 1)
        r0 = np.maximum(np.ceil(-np.maximum(np.maximum(y[0], y[1]), y[2]) / res - 0.5), grid.row0)
        r1 = np.minimum(np.floor(-np.minimum(np.minimum(y[0], y[1]), y[2]) / res - 0.5), grid.row0 + grid.rows - 1)
        some = (c1 >= c0) & (r1 >= r0)
        boxes.append((part[some], c0[some], c1[some], r0[some], r1[some]))
    simplices = np.concatenate([b[0] for b in boxes])
    c0, c1, r0, r1 = (np.concatenate([b[i] for b in boxes]) for i in range(1, 5))
    del boxes
    s = simplices.astype(np.int64)
    lo, hi = s.min(axis=1), s.max(axis=1)
    s = np.column_stack((lo, s.sum(axis=1) - lo - hi, hi))  # vertices ascending
    order = np.lexsort(s.T[::-1])
    s = s[order]
    c0, c1 = c0[order].astype(np.int64), c1[order].astype(np.int64)
    r0, r1 = r0[order].astype(np.int64), r1[order].astype(np.int64)
    return s, c0, c1, r0, r1


def _query_grid(
    points: np.ndarray, grid: Grid, k: int, nodata_distance: float, block_rows: int, progress, margin: float | None
):
    """Yield (first cell, last cell + 1, distances, indices) of the k nearest points of each cell centre (canonical).

    Cells are counted row by row; a block is at most *block_rows* rows and
    at most :data:`NEIGHBOUR_BLOCK` neighbours (fewer cells when *k* is
    large), so the tables stay small whatever *k*.

    With *margin*, the k-d tree holds only the points within *margin*
    (whole cells) of the grid; a cell whose k-th neighbour in it is not
    nearer than the edge of that region (every point left out lies beyond
    it) is asked again of a tree of every point.  The answer is the same
    either way (the same points, the same distances, ties by the same
    index order); a tile's buffer is mostly far from its cells.
    """

    origin = np.array([grid.xmin, grid.ymax])
    xy = points[:, :2] - origin
    inner = _near_grid(xy, grid, margin)
    every: list = []

    def full():  # the tree of every point, once, if needed
        if not every:
            every.append(cKDTree(xy, balanced_tree=False, compact_nodes=False))
        return every[0]

    if inner is None or not inner.any():  # every point near the grid, or none
        tree, kept = full(), None
    else:
        kept = np.flatnonzero(inner)
        tree = cKDTree(xy[kept], balanced_tree=False, compact_nodes=False)  # unbalanced: 3x faster to build
        kept = np.append(kept, len(xy))  # "no neighbour" stays "no neighbour"
        res = grid.resolution
        m = int(math.ceil(margin / res))
        x0, x1 = (grid.col0 - m) * res, (grid.col0 + grid.cols + m) * res
        y1, y0 = -(grid.row0 - m) * res, -(grid.row0 + grid.rows + m) * res
    for start, stop, q in _cell_blocks(grid, origin, min(block_rows * grid.cols, max(1, NEIGHBOUR_BLOCK // k))):
        dist, idx = canonical_neighbours(tree, q, k, nodata_distance)
        if kept is not None:
            idx = kept[idx]
            # every point left out lies outside the region [x0, x1) x (y0, y1]: farther than its edge
            edge = np.minimum(np.minimum(q[:, 0] - x0, x1 - q[:, 0]), np.minimum(q[:, 1] - y0, y1 - q[:, 1]))
            doubt = np.flatnonzero(~(dist[:, -1] < edge * (1.0 - 1e-9) - 1e-9))  # a missing neighbour too
            if len(doubt):
                dist[doubt], idx[doubt] = canonical_neighbours(full(), q[doubt], k, nodata_distance)
        yield start, stop, dist, idx
        if progress is not None and stop // grid.cols > start // grid.cols:
            progress.update(stop // grid.cols - start // grid.cols)  # rows finished


def _cell_blocks(grid: Grid, origin: np.ndarray, block: int):
    """Yield (first cell, last cell + 1, centres relative to *origin*) of *grid*'s cells, *block* cells at a time."""
    total = grid.rows * grid.cols
    for start in range(0, total, block):
        stop = min(total, start + block)
        r0, r1 = start // grid.cols, (stop - 1) // grid.cols + 1
        gx, gy = grid.centres(r0, r1)
        cut = slice(start - r0 * grid.cols, stop - r0 * grid.cols)
        yield start, stop, np.column_stack((gx.ravel()[cut] - origin[0], gy.ravel()[cut] - origin[1]))


def idw(
    points: np.ndarray,
    grid: Grid,
    *,
    nodata_distance: float,
    neighbors: int = _IDW.neighbors,
    power: float = _IDW.power,
    nodata: float = np.nan,
    block_rows: int = 64,
    margin: float | None = 10.0,
    progress: Progress | None = None,
) -> np.ndarray:
    """Inverse-distance-weighted mean of the ``neighbors`` nearest points of each cell centre.

    Weights are ``1 / d**power`` over the neighbours closer than
    ``nodata_distance``; a cell with none is *nodata*; a point exactly on a
    cell centre gives its own value (Shepard 1968,
    doi:10.1145/800186.810616).  *margin* (metres, None: off): the
    neighbours are looked for among the points within it of the grid first
    (:func:`_query_grid`; the same answer, a smaller k-d tree).
    """
    pts = np.asarray(points, dtype=np.float64)
    k = int(min(neighbors, len(pts)))
    out = np.empty((grid.rows, grid.cols), dtype=np.float64)
    z = np.append(pts[:, 2], np.nan)  # index len(pts) = "no neighbour"
    for start, stop, dist, idx in _query_grid(pts, grid, k, nodata_distance, block_rows, progress, margin):
        valid = np.isfinite(dist)
        with np.errstate(divide="ignore"):
            w = np.where(valid, 1.0 / np.maximum(dist, 1e-12) ** power, 0.0)
        wsum = w.sum(axis=1)
        values = np.where(
            wsum > 0, (w * np.where(valid, z[idx], 0.0)).sum(axis=1) / np.where(wsum > 0, wsum, 1), nodata
        )
        out.reshape(-1)[start:stop] = values
    return out


def nearest(
    points: np.ndarray,
    grid: Grid,
    *,
    nodata_distance: float,
    nodata: float = np.nan,
    block_rows: int = 64,
    margin: float | None = 10.0,
    progress: Progress | None = None,
) -> np.ndarray:
    """Value of the nearest point to each cell centre (*nodata* beyond ``nodata_distance``; *margin* as :func:`idw`)."""
    pts = np.asarray(points, dtype=np.float64)
    out = np.empty((grid.rows, grid.cols), dtype=np.float64)
    z = np.append(pts[:, 2], nodata)
    for start, stop, _, idx in _query_grid(pts, grid, 1, nodata_distance, block_rows, progress, margin):
        out.reshape(-1)[start:stop] = z[idx[:, 0]]
    return out
