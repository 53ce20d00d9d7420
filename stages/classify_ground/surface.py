"""Grid helpers shared by the ground filters: minimum surfaces, inpainting, sampling.

Grids here are internal to the algorithms: row 0 is the *lowest* y (south), so
``row = floor((y - y0) / c)``; cell (r, k) has its centre at
``(x0 + (k + 0.5) c, y0 + (r + 0.5) c)``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyamg
from pyamg.relaxation.relaxation import gauss_seidel
from scipy import ndimage, sparse
from scipy.sparse.linalg import LinearOperator, cg, spsolve


def as_xyz(xyz: np.ndarray) -> np.ndarray:
    """Check and convert the coordinates every ground filter takes: (n, 3) float64."""
    xyz = np.asarray(xyz, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError("xyz must have shape (n, 3)")
    return xyz


@dataclass(frozen=True)
class CellIndex:
    """Where each point falls on an algorithm's grid."""

    x0: float
    y0: float
    cell_size: float
    rows: int
    cols: int
    row: np.ndarray
    col: np.ndarray

    @property
    def flat(self) -> np.ndarray:
        return self.row * self.cols + self.col


def grid_corner(lowest: np.ndarray, cell_size: float) -> tuple[float, float]:
    """The corner of a grid over points whose lowest x, y are *lowest*: rounded down to whole multiples of the cell."""
    return float(np.floor(lowest[0] / cell_size) * cell_size), float(np.floor(lowest[1] / cell_size) * cell_size)


def index_points(xy: np.ndarray, cell_size: float) -> CellIndex:
    """Grid the bounding box of *xy* with square cells of *cell_size*.

    The grid's corner is the box's corner rounded down to a whole multiple
    of *cell_size*, so every subset of the points (a tile) puts each point in
    the same cell, at the same place in the cell, as the whole set does.
    """
    x0, y0 = grid_corner(xy.min(axis=0), cell_size)
    # the highest indices from the highest x, y (floor of a shifted, scaled value keeps their order: the same
    # numbers), then each index a column at a time: one float temporary, not two
    hi = xy.max(axis=0)
    col_max, row_max = np.floor((hi[0] - x0) / cell_size), np.floor((hi[1] - y0) / cell_size)
    kind = np.int32 if col_max * (row_max + 1) + col_max < 2**31 else np.int64  # int32 when the grid allows
    col = np.floor((xy[:, 0] - x0) / cell_size).astype(kind)
    row = np.floor((xy[:, 1] - y0) / cell_size).astype(kind)
    return CellIndex(x0, y0, cell_size, int(row_max) + 1, int(col_max) + 1, row, col)


def min_grid(z: np.ndarray, idx: CellIndex) -> np.ndarray:
    """Lowest *z* per cell; NaN where a cell holds no point."""
    out = np.full(idx.rows * idx.cols, np.inf)
    np.minimum.at(out, idx.flat, z)
    out[~np.isfinite(out)] = np.nan
    return out.reshape(idx.rows, idx.cols)


#: Residual, relative to the relief's, at which :func:`inpaint` stops: 0.2 mm at most on a survey's grid,
#: a fifth of LAS's usual 1 mm scale (docs/stages/classify_ground.md).
INPAINT_TOL = 1e-8
#: Systems up to this many cells are solved directly: too few for a multigrid hierarchy.
_DIRECT = 500
#: CG steps (symmetric Gauss-Seidel preconditioner) tried before a multigrid solver is built: about
#: what building and running one costs, counted in those steps (both grow with the cells to fill), so
#: no grid costs more than twice the better of the two (docs/stages/classify_ground.md).
_CHEAP_STEPS = 60
#: Multigrid-preconditioned CG steps allowed (it takes about five on a survey's grid).
_MAX_CYCLES = 200


def inpaint(grid: np.ndarray) -> np.ndarray:
    """Fill NaN cells with the harmonic (Laplacian) interpolant of the known cells.

    Each unknown cell equals the mean of its four neighbours, known cells are
    fixed: a sparse linear system over the unknown cells only.  This is
    method 2 of D'Errico's ``inpaint_nans``, the family of methods Pingel et
    al. (2013) use to fill SMRF's minimum surface; it is smooth across large
    gaps (buildings, water) where nearest-neighbour fill makes steps.

    The system is symmetric and positive definite; it is solved by
    conjugate gradients from each cell's nearest known value to a relative
    residual of :data:`INPAINT_TOL`.  Scattered empty cells (a sparse
    survey) converge in tens of steps preconditioned by a symmetric
    Gauss-Seidel sweep (Saad 2003, *Iterative methods for sparse linear
    systems*, 2nd ed., sec. 10.2, doi:10.1137/1.9780898718003); wide
    gaps (water, large buildings) need algebraic multigrid (PyAMG's
    Ruge-Stuben solver, Bell, Olson & Schroder 2022,
    doi:10.21105/joss.04142), built only when :data:`_CHEAP_STEPS` have not
    converged.  Both cost in proportion to the cells to fill, where a
    direct factorization's fill-in grows faster: on a sparse survey's grid
    (2 M cells, 1.56 M to fill) 1.6 to 3.0 s against 12 s for SciPy's sparse
    LU; the solutions differ by 0.2 mm at most.
    """

    unknown = np.isnan(grid)
    if not unknown.any():
        return grid
    if unknown.all():
        raise ValueError("the grid has no value to fill from")
    level = float(np.nanmean(grid))  # solved about it: the residual measures relief, not altitude
    a, rhs = _laplace_system(grid - level, unknown)
    out = grid.copy()
    if a.shape[0] <= _DIRECT:
        out[unknown] = level + spsolve(a.tocsc(), rhs)
        return out
    _, (near_r, near_c) = ndimage.distance_transform_edt(unknown, return_indices=True)
    start = grid[near_r[unknown], near_c[unknown]] - level
    x, _ = cg(a, rhs, x0=start, rtol=INPAINT_TOL, atol=0.0, M=_symmetric_gauss_seidel(a), maxiter=_CHEAP_STEPS)
    if np.linalg.norm(rhs - a @ x) > INPAINT_TOL * np.linalg.norm(rhs):  # not SciPy's flag: 0 after 0 steps
        x = pyamg.ruge_stuben_solver(a).solve(rhs, x0=x, tol=INPAINT_TOL, accel="cg", maxiter=_MAX_CYCLES)
    out[unknown] = level + x
    return out


def _symmetric_gauss_seidel(a: sparse.csr_matrix) -> LinearOperator:
    """One symmetric Gauss-Seidel sweep from zero, ``(D + U)^-1 D (D + L)^-1``: a preconditioner for CG
    (symmetric and positive definite when *a* is)."""

    def sweep(v: np.ndarray) -> np.ndarray:
        z = np.zeros(a.shape[0])
        gauss_seidel(a, z, np.asarray(v, dtype=np.float64).ravel(), iterations=1, sweep="symmetric")
        return z

    return LinearOperator(a.shape, matvec=sweep, dtype=np.float64)


def _laplace_system(grid: np.ndarray, unknown: np.ndarray) -> tuple[sparse.csr_matrix, np.ndarray]:
    """The five-point Laplace system over the *unknown* cells of *grid*: no flux across the grid's edge."""
    rows, cols = grid.shape
    n = int(unknown.sum())
    number = np.full((rows + 2, cols + 2), -2, dtype=np.int32)  # -2 outside the grid, -1 a known cell
    number[1:-1, 1:-1] = -1
    number[1:-1, 1:-1][unknown] = np.arange(n, dtype=np.int32)
    value = np.zeros((rows + 2, cols + 2))
    value[1:-1, 1:-1] = np.where(unknown, 0.0, grid)
    ur, uc = np.nonzero(unknown)
    at = (ur + 1) * (cols + 2) + (uc + 1)
    number, value = number.ravel(), value.ravel()
    diag, rhs = np.zeros(n), np.zeros(n)
    me = np.arange(n, dtype=np.int32)
    row, column = [me], [me]
    for step in (-(cols + 2), -1, 1, cols + 2):
        other = number[at + step]
        diag += other != -2
        rhs += value[at + step]  # 0 outside and at unknown cells
        linked = other >= 0
        row.append(me[linked])
        column.append(other[linked])
    i, j = np.concatenate(row), np.concatenate(column)
    values = np.full(len(i), -1.0)
    values[:n] = diag
    return sparse.coo_matrix((values, (i, j)), shape=(n, n)).tocsr(), rhs


def sample_bilinear_all(
    grids: tuple[np.ndarray, ...], idx: CellIndex, x: np.ndarray, y: np.ndarray
) -> list[np.ndarray]:
    """Bilinear interpolation of cell-centre values of several grids of one shape at the same points.

    Clamped at the grids' edges; the weights are computed once for all grids.
    """
    fx = (x - idx.x0) / idx.cell_size - 0.5
    fy = (y - idx.y0) / idx.cell_size - 0.5
    rows, cols = grids[0].shape
    c0 = np.clip(np.floor(fx).astype(np.int64), 0, max(cols - 2, 0))
    r0 = np.clip(np.floor(fy).astype(np.int64), 0, max(rows - 2, 0))
    tx = np.clip(fx - c0, 0.0, 1.0)
    ty = np.clip(fy - r0, 0.0, 1.0)
    # the four corners as flat indices (the next column and row, or the same one on a grid one cell wide)
    i00 = r0 * cols + c0
    i01 = i00 + (1 if cols > 1 else 0)
    i10 = i00 + (cols if rows > 1 else 0)
    i11 = i10 + (i01 - i00)
    ux, uy = 1 - tx, 1 - ty
    out = []
    for grid in grids:
        flat = grid.ravel()
        top = flat.take(i00) * ux + flat.take(i01) * tx
        bottom = flat.take(i10) * ux + flat.take(i11) * tx
        out.append(top * uy + bottom * ty)
    return out


def slope_grid(grid: np.ndarray, cell_size: float) -> np.ndarray:
    """Magnitude of the gradient (rise over run) by central differences."""
    if min(grid.shape) < 2:
        return np.zeros_like(grid)
    gy, gx = np.gradient(grid, cell_size)
    return np.hypot(gx, gy)


def pad_linear(grid: np.ndarray, width: int) -> np.ndarray:
    """Pad a grid by *width* cells, continuing its slope across each edge from the cells near that edge.

    Along every row (then every column of the result), the padding continues
    the line that supports the last *width* cells before an edge from below
    at the middle of that band (the edge of their lower convex hull there).
    A planar slope thus continues exactly, an object within the band does
    not tilt it, and an object cut by the survey's boundary is bordered by
    ground-level padding.  Each padded value depends only on the cells
    within *width* of its edge, so a tile pads a shared edge as the whole
    survey does.  Why not flat or least-squares padding:
    docs/stages/classify_ground.md.
    """
    if width <= 0:
        return grid
    return _pad_rows(_pad_rows(np.asarray(grid, dtype=np.float64), width).T, width).T


def _pad_rows(grid: np.ndarray, width: int) -> np.ndarray:
    """Pad the columns' ends of every row (see :func:`pad_linear`)."""
    rows, cols = grid.shape
    band = min(width, cols)
    out = np.empty((rows, cols + 2 * width))
    out[:, width : width + cols] = grid
    ahead = np.arange(1, width + 1, dtype=np.float64)
    # between two cells, so that one edge of the lower hull spans it (at a cell, every line under it would)
    middle = band // 2 - 0.5 if band % 2 == 0 else band // 2 + 0.5
    # every pair of cells (i, j) that straddles that point: the lower hull there is the lowest of their chords
    pairs = [(i, j) for i in range(band) for j in range(i + 1, band) if i <= middle <= j]
    i, j = (np.array([p[n] for p in pairs], dtype=np.int64) for n in (0, 1))
    for side in ("low", "high"):
        cells = grid[:, :band][:, ::-1] if side == "low" else grid[:, cols - band :]
        # cells ordered towards the edge: position k = 0 .. band-1, the edge cell last
        if band > 1:
            slopes = (cells[:, j] - cells[:, i]) / (j - i)
            at_middle = cells[:, i] + slopes * (middle - i)
            best = np.argmin(at_middle, axis=1)
            slope = slopes[np.arange(rows), best]
            edge = at_middle[np.arange(rows), best] + slope * (band - 1 - middle)
        else:
            slope, edge = np.zeros(rows), cells[:, -1]
        values = edge[:, None] + slope[:, None] * ahead
        if side == "low":
            out[:, :width] = values[:, ::-1]
        else:
            out[:, width + cols :] = values
    return out


def pad_plane(grid: np.ndarray, width: int) -> np.ndarray:
    """Pad a grid by *width* cells, continuing the slope of one plane fitted to the whole grid (PMF's padding).

    A least-squares plane is fitted to the whole grid; the residual from it
    is padded with its lowest value within *width* cells of each edge, and
    the plane is added back.  A planar slope thus continues exactly, and an
    object cut by the survey's boundary is bordered by ground-level padding,
    so an opening can still remove it.  Flat ("nearest") padding instead
    makes every uphill edge look like the foot of an object, which an
    opening then lowers.
    """
    if width <= 0:
        return grid
    rows, cols = grid.shape
    yy, xx = np.mgrid[0:rows, 0:cols].astype(np.float64)
    design = np.column_stack((np.ones(grid.size), xx.ravel(), yy.ravel()))
    coef, *_ = np.linalg.lstsq(design, grid.ravel(), rcond=None)
    plane = coef[0] + coef[1] * xx + coef[2] * yy
    residual = np.pad(grid - plane, width, mode="minimum", stat_length=width)
    pyy, pxx = np.mgrid[-width : rows + width, -width : cols + width].astype(np.float64)
    return residual + coef[0] + coef[1] * pxx + coef[2] * pyy
