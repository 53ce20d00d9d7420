"""North-up raster grids and their windows, points counted into their cells, gaps filled, cells joined.

:class:`Grid` anchors every cell at whole multiples of its resolution, so a
window (a tile) has the values of the same cells of the whole grid;
:func:`check_grid_size` refuses a DTM grid the run could not hold.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from affine import Affine
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from lidar.memory import free_memory, gigabytes
from pipeline.errors import ConfigError

if TYPE_CHECKING:
    from lidar.units import Units


@dataclass(frozen=True)
class Grid:
    """A north-up raster grid: top-left corner, resolution, size.

    A *window* of a grid (:meth:`window`) keeps the grid's corner as its
    anchor and counts its first row and column from it (``row0``,
    ``col0``): every coordinate is computed from the anchor and the global
    cell index, so a window's values are bit for bit those of the same cells
    of the whole grid (what makes tiled rasters identical to untiled ones).
    """

    xmin: float
    ymax: float
    resolution: float
    cols: int
    rows: int
    row0: int = 0
    col0: int = 0

    @classmethod
    def covering(cls, xmin: float, ymin: float, xmax: float, ymax: float, resolution: float) -> Grid:
        """The smallest cell-aligned grid holding every point of the box.

        A point at (x, y) falls in column ``floor((x - xmin) / resolution)`` and
        row ``floor((ymax - y) / resolution)`` (cells are closed at the left and
        top edges), so the grid has one more column and row than the box spans.

        >>> Grid.covering(10.2, 5.5, 12.9, 7.5, 1.0)
        Grid(xmin=10.0, ymax=8.0, resolution=1.0, cols=3, rows=3, row0=0, col0=0)
        """
        x0 = math.floor(xmin / resolution) * resolution
        y1 = math.ceil(ymax / resolution) * resolution
        cols = int(math.floor((xmax - x0) / resolution)) + 1
        rows = int(math.floor((y1 - ymin) / resolution)) + 1
        return cls(float(x0), float(y1), float(resolution), cols, rows)

    def window(self, r0: int, r1: int, c0: int, c1: int) -> Grid:
        """Rows ``r0:r1`` and columns ``c0:c1`` of this grid (indices of this grid)."""
        return Grid(self.xmin, self.ymax, self.resolution, c1 - c0, r1 - r0, self.row0 + r0, self.col0 + c0)

    @property
    def transform(self) -> Affine:
        """The affine pixel-to-map transform (rasterio convention)."""
        return Affine(
            self.resolution,
            0.0,
            self.xmin + self.col0 * self.resolution,
            0.0,
            -self.resolution,
            self.ymax - self.row0 * self.resolution,
        )

    def centres(self, row_start: int = 0, row_stop: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """x, y of the centres of rows ``row_start:row_stop``, each (rows, cols)."""
        row_stop = self.rows if row_stop is None else row_stop
        xs = self.xmin + (np.arange(self.col0, self.col0 + self.cols) + 0.5) * self.resolution
        ys = self.ymax - (np.arange(self.row0 + row_start, self.row0 + row_stop) + 0.5) * self.resolution
        return np.meshgrid(xs, ys)


def cell_of(points: np.ndarray, grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """Row and column of the cell holding each point (-1 outside the grid)."""
    col = np.floor((points[:, 0] - grid.xmin) / grid.resolution).astype(np.int64) - grid.col0
    row = np.floor((grid.ymax - points[:, 1]) / grid.resolution).astype(np.int64) - grid.row0
    outside = (col < 0) | (col >= grid.cols) | (row < 0) | (row >= grid.rows)
    col[outside] = -1
    row[outside] = -1
    return row, col


def cell_count(points: np.ndarray, grid: Grid) -> np.ndarray:
    """Number of points per cell."""
    row, col = cell_of(points, grid)
    inside = row >= 0
    counts = np.bincount(row[inside] * grid.cols + col[inside], minlength=grid.rows * grid.cols)
    return counts.reshape(grid.rows, grid.cols)


def cell_mean(points: np.ndarray, values: np.ndarray, grid: Grid) -> np.ndarray:
    """Mean of *values* over the points of each cell (NaN where a cell holds no point)."""
    row, col = cell_of(points, grid)
    inside = row >= 0
    k = row[inside] * grid.cols + col[inside]
    total = np.bincount(k, np.asarray(values, dtype=np.float64)[inside], grid.rows * grid.cols)
    count = np.bincount(k, minlength=grid.rows * grid.cols)
    return np.where(count > 0, total / np.maximum(count, 1), np.nan).reshape(grid.rows, grid.cols)


def cell_max_count(points: np.ndarray | Sequence[np.ndarray], grid: Grid) -> tuple[np.ndarray, np.ndarray]:
    """:func:`cell_max` (NaN where empty) and :func:`cell_count` in one pass over the points.

    *points*: an (n, 3) array, or its three columns x, y, z (1-D arrays,
    memory-mapped ones too: no stacked copy is made).
    """
    x, y, z = (points[:, 0], points[:, 1], points[:, 2]) if isinstance(points, np.ndarray) else points
    col = np.floor((x - grid.xmin) / grid.resolution).astype(np.int64) - grid.col0
    row = np.floor((grid.ymax - y) / grid.resolution).astype(np.int64) - grid.row0
    inside = (col >= 0) & (col < grid.cols) & (row >= 0) & (row < grid.rows)
    k = row * grid.cols + col
    del row, col
    if not inside.all():
        k, z = k[inside], np.asarray(z)[inside]
    highest = np.full(grid.rows * grid.cols, -np.inf)
    np.maximum.at(highest, k, z)
    highest[~np.isfinite(highest)] = np.nan
    count = np.bincount(k, minlength=grid.rows * grid.cols)
    return highest.reshape(grid.rows, grid.cols), count.reshape(grid.rows, grid.cols)


def cell_max(points: np.ndarray, grid: Grid, nodata: float = np.nan) -> np.ndarray:
    """Highest z per cell (*nodata* where a cell holds no point)."""
    row, col = cell_of(points, grid)
    inside = row >= 0
    out = np.full(grid.rows * grid.cols, -np.inf)
    np.maximum.at(out, row[inside] * grid.cols + col[inside], points[inside, 2])
    out[~np.isfinite(out)] = nodata
    return out.reshape(grid.rows, grid.cols)


#: Bytes per cell of the survey's grid that a run holds at once, at most: the
#: raster products (hillshade, contours, accuracy, report) read the DTM whole,
#: as float64 with temporaries of its size (the report's peak, measured:
#: 118 bytes a cell on a grid of 22.7 million cells).
BYTES_PER_CELL = 120


def check_grid_size(
    grid: Grid,
    box: tuple[float, float, float, float],
    units: Units | None = None,
    memory: int | None = None,
    source: str = "the points",
) -> None:
    """Refuse, before anything is allocated, a grid the run could not hold (one sentence, exit 2).

    *box*: the usable points' extent in metres (stray points left out, so the
    grid's size follows the configuration); *units*: the CRS's (the message
    speaks metres, as ``stages.rasterize.resolution`` does); *memory* (bytes)
    defaults to :func:`lidar.memory.free_memory`; *source* names the
    input in the message.

    Raises
    ------
    ConfigError
        Naming ``stages.rasterize.resolution``, the cells, the need and the
        resolution that would fit.
    """
    memory = free_memory() if memory is None else memory
    cells = grid.cols * grid.rows
    need = cells * BYTES_PER_CELL
    if need <= memory:
        return
    width, height = box[2] - box[0], box[3] - box[1]
    fits = grid.resolution * math.sqrt(need / max(memory, 1)) * 1.05
    raise ConfigError(
        f"stages.rasterize.resolution: {grid.resolution:g} m cells over this {width:,.0f} x {height:,.0f} m survey "
        f"({source}) make {cells:,} cells (about {gigabytes(need)} for the products), more than the "
        f"{gigabytes(memory)} of free memory; use a coarser resolution (at least {round_up(fits):g} m here)."
    )


def round_up(value: float) -> float:
    """*value* rounded up to two significant digits: 0.0417 -> 0.042."""
    scale = 10.0 ** (math.floor(math.log10(value)) - 1)
    return math.ceil(value / scale) * scale


def fill_nearest(grid: np.ndarray, max_cells: float | None = None) -> np.ndarray:
    """Replace NaN cells by the value of the nearest non-NaN cell.

    With *max_cells*, cells farther than that (in cells) from any value stay
    NaN (so a grid without any value stays as it is); without, a grid
    without any value is an error.
    """
    empty = np.isnan(grid)
    if not empty.any():
        return grid
    if empty.all():
        if max_cells is not None:
            return grid
        raise ValueError("the grid has no value to fill from")

    dist, (ri, ci) = ndimage.distance_transform_edt(empty, return_distances=True, return_indices=True)
    out = grid[ri, ci]
    if max_cells is not None:
        out[dist > max_cells] = np.nan
    return out


def step_labels(cells: np.ndarray, height: np.ndarray, step: float, *, corners: bool = True) -> np.ndarray:
    """Labels (1, 2, ...; 0 none) of the *cells* joined where neighbours' *height*s differ by at most *step*.

    Neighbours across sides, and across corners with *corners*; a graph's
    connected components (a chain of small steps joins, one large step
    parts), numbered in the order of their first cell (row by row).
    Heights that are not finite never join.
    """
    ny, nx = cells.shape
    ids = np.arange(ny * nx).reshape(ny, nx)
    rows, cols = [], []
    for da, db in ((1, 0), (0, 1), (1, 1), (1, -1))[: 4 if corners else 2]:
        a0, a1 = slice(0, ny - da), slice(da, ny)
        b0, b1 = (slice(0, nx - db), slice(db, nx)) if db >= 0 else (slice(-db, nx), slice(0, nx + db))
        with np.errstate(invalid="ignore"):  # two unknown heights (inf) do not join
            ok = cells[a0, b0] & cells[a1, b1] & (np.abs(height[a0, b0] - height[a1, b1]) <= step)
        rows.append(ids[a0, b0][ok])
        cols.append(ids[a1, b1][ok])
    r, c = np.concatenate(rows), np.concatenate(cols)
    graph = coo_matrix((np.ones(len(r), dtype=np.int8), (r, c)), shape=(ny * nx, ny * nx))
    n, component = connected_components(graph, directed=False)
    members = cells.ravel()
    # the components holding cells, numbered 1, 2, ... in order (np.unique's inverse, without its sort)
    present = np.zeros(n, dtype=bool)
    present[component[members]] = True
    labels = np.zeros(ny * nx, dtype=np.int64)
    labels[members] = np.cumsum(present)[component[members]]
    return labels.reshape(ny, nx)
