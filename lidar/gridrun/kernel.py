"""What a grid stage computes, said once: the contract between a stage and the run service.

A grid stage reclassifies points by a grid of the survey's cells.  Pass 1
gathers statistics per cell from the points (:meth:`GridKernel.gather`);
the stage's computation turns a window of those statistics into result
grids, looking at most :attr:`GridKernel.reach` metres around each cell
(:meth:`GridKernel.window`); pass 2 gives each point a value from the
results of its own window (:meth:`GridKernel.values`) and its new class
(:meth:`GridKernel.classes`).  The same computation on the points of a tile
and its buffer (:meth:`GridKernel.tile`) serves where the grid does not fit
or its cells do not align with the tiles.  Where each runs is
:func:`lidar.gridrun.service.run_grid_stage`'s choice; the classes are the
same.

Grids are anchored at whole multiples of their cell.  A cell is named by
its *label* on each axis (:class:`Axis`); a :class:`Frame` places a grid's
arrays by the labels of their first cell, so that a window of the survey's
grid and the grid a tile of points makes hold the same cells.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, ClassVar

import numpy as np


@dataclass(frozen=True)
class Axis:
    """One axis of a grid's arrays: the coordinate it follows (0: x, 1: y) and its direction.

    An ascending axis holds in its cell ``k`` the coordinates ``[k c, (k + 1) c)``
    and its arrays run from low to high; a descending one (*down*: the rows
    of a north-up raster) holds ``((k - 1) c, k c]`` in its cell ``k`` (the
    cell's top) and its arrays run from high to low.
    """

    coord: int
    down: bool = False

    def covering(self, lo: float, hi: float, cell: float) -> tuple[int, int]:
        """``(first label, cells)`` of the fewest cells holding every coordinate in ``[lo, hi]``."""
        if self.down:
            first = math.ceil(hi / cell)
            return first, int(math.floor((first * cell - lo) / cell)) + 1
        first = math.floor(lo / cell)
        return first, int(math.floor((hi - first * cell) / cell)) + 1

    def index(self, v: np.ndarray, first: int, cell: float) -> np.ndarray:
        """The array index of the cell holding each coordinate *v*, on arrays whose first cell is *first*."""
        if self.down:
            return np.floor((first * cell - v) / cell).astype(np.int64)
        return np.floor((v - first * cell) / cell).astype(np.int64)

    def label(self, first: int, index: int) -> int:
        """The label of array index *index* on arrays whose first cell is *first*."""
        return first - index if self.down else first + index

    def span(self, first: int, count: int, lo: int, hi: int) -> slice:
        """The array indices of labels *lo* to *hi* (both included) on arrays of *count* cells from *first*; cut to them."""
        a, b = (first - hi, first - lo + 1) if self.down else (lo - first, hi - first + 1)
        return slice(min(max(a, 0), count), min(max(b, 0), count))

    def own(self, i: int, tile: int) -> tuple[int, int]:
        """Labels (first, last) of the cells holding the points of tile *i*: coordinates ``[i s, (i + 1) s)``, *tile* cells of side."""
        return (i * tile, (i + 1) * tile) if self.down else (i * tile, (i + 1) * tile - 1)

    def window(self, i: int, tile: int, buffer: int) -> tuple[int, int]:
        """Labels (first, last) of the cells that meet the open span of tile *i* grown by *buffer* cells each way."""
        if self.down:
            return i * tile - buffer + 1, (i + 1) * tile + buffer
        return i * tile - buffer, (i + 1) * tile + buffer - 1

    def tiles(self, first: int, count: int, tile: int) -> range:
        """The tiles whose own cells may meet arrays of *count* cells from *first*."""
        lo, hi = (first - count + 1, first) if self.down else (first, first + count - 1)
        start = -(-lo // tile) - 1 if self.down else lo // tile
        return range(start, hi // tile + 1)


@dataclass(frozen=True)
class Frame:
    """A grid's arrays placed on the survey: cell (m), axes, the labels of their first cell, their shape."""

    cell: float
    axes: tuple[Axis, Axis]
    first: tuple[int, int]
    shape: tuple[int, int]

    @classmethod
    def covering(cls, axes: tuple[Axis, Axis], box: tuple[float, float, float, float], cell: float) -> Frame:
        """The frame of the fewest cells holding the box ``(xmin, ymin, xmax, ymax)``."""
        spans = [a.covering(box[a.coord], box[a.coord + 2], cell) for a in axes]
        return cls(cell, axes, (spans[0][0], spans[1][0]), (spans[0][1], spans[1][1]))

    @property
    def size(self) -> int:
        return self.shape[0] * self.shape[1]

    def corner(self, axis: int) -> float:
        """The coordinate (m) of the edge of the first cell on *axis* where its label lies: ``label * cell``."""
        return float(self.first[axis] * self.cell)

    def indices(self, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The array indices of each point's cell on both axes (outside the arrays where they fall outside)."""
        a, b = self.axes
        return a.index(xyz[:, a.coord], self.first[0], self.cell), b.index(xyz[:, b.coord], self.first[1], self.cell)

    def flat(self, xyz: np.ndarray) -> np.ndarray:
        """The flat array index of each point's cell; -1 where a point lies outside."""
        i, j = self.indices(xyz)
        k = i * self.shape[1] + j
        k[(i < 0) | (i >= self.shape[0]) | (j < 0) | (j >= self.shape[1])] = -1
        return k

    def cut(self, rows: slice, cols: slice) -> Frame:
        """The frame of ``arrays[rows, cols]`` (slices of array indices, steps of 1)."""
        a, b = self.axes
        first = (a.label(self.first[0], rows.start), b.label(self.first[1], cols.start))
        return Frame(self.cell, self.axes, first, (rows.stop - rows.start, cols.stop - cols.start))


#: The LAS columns a kernel may read besides x, y, z (:attr:`GridKernel.fields`), with their types.
LAS_COLUMNS = {"classification": np.uint8, "return_number": np.uint8, "number_of_returns": np.uint8, "withheld": bool}


class GridKernel:
    """What a grid stage computes (the contract of :func:`lidar.gridrun.service.run_grid_stage`).

    A stage subclasses it as a frozen dataclass of JSON values (its
    parameters' dump, its cell): the kernel travels to the workers and into
    the tile cache's keys.  Per point, ``columns`` are what the kernel reads
    of a LAS chunk besides x, y, z (metres), as :meth:`columns` gives them;
    *tested* points (:meth:`tested`) get a value, from the grid
    (:meth:`values`) or from their tile (:meth:`tile`), and every point its
    new class by its value (:meth:`classes`).  A kernel without a grid form
    (:attr:`grid_form` False) runs on tiles of points only.
    """

    #: The numbers :meth:`classes` counts, in its order, the points first: the stage's metrics.
    counts: ClassVar[tuple[str, ...]] = ("points",)
    #: The axes of the grid's arrays (:class:`Axis`): which coordinate each follows, and how.
    axes: ClassVar[tuple[Axis, Axis]] = (Axis(1), Axis(0))
    #: Passes over the points that gather the statistics (:meth:`gather` is told which).
    passes: ClassVar[int] = 1
    #: Whether the kernel computes on the survey's grid; without, on tiles of points only.
    grid_form: ClassVar[bool] = True
    #: The LAS columns it reads besides x, y, z (:data:`LAS_COLUMNS`): what :meth:`columns` gives.
    fields: ClassVar[tuple[str, ...]] = ("classification", "withheld")

    #: Cells beyond a tile's own that pass 2 reads for its points (the results kept of its window).
    margin: ClassVar[int] = 0
    # A kernel also has ``cell`` (m), its grid's cell, and ``reach`` (m), how far its computation looks from
    # a cell or a point: the buffer a tile or a window needs (fields or properties of the subclass).
    cell: float
    reach: float

    def __getstate__(self) -> dict[str, Any]:
        """Its fields only: what a worker needs (anything cached is made again there)."""
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def columns(self, chunk: Any) -> dict[str, np.ndarray]:
        """What the kernel reads of a chunk of LAS records besides x, y, z: its :attr:`fields`."""
        return {name: np.asarray(getattr(chunk, name), dtype=LAS_COLUMNS[name]) for name in self.fields}

    def tested(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        """Which points get a value (:meth:`values`, :meth:`tile`)."""
        raise NotImplementedError

    def classes(
        self, cols: dict[str, np.ndarray], tested: np.ndarray, values: np.ndarray
    ) -> tuple[np.ndarray, tuple[int, ...]]:
        """The points' new classes by the *values* of the *tested* ones, and the :attr:`counts`."""
        raise NotImplementedError

    def tile(self, xyz: np.ndarray, cols: dict[str, np.ndarray], tested: np.ndarray) -> np.ndarray:
        """The values of the *tested* points of a tile (its core and buffer), computed from its points alone."""
        raise NotImplementedError

    # The grid form.

    def selected(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        """Which points pass 1 gathers (the grid covers them)."""
        raise NotImplementedError

    def stats(self, size: int) -> dict[str, np.ndarray]:
        """Empty statistics of *size* cells (flat arrays), as :meth:`gather` fills them."""
        raise NotImplementedError

    def gather(
        self, stats: dict[str, np.ndarray], step: int, k: np.ndarray, xyz: np.ndarray, cols: dict[str, np.ndarray]
    ) -> None:
        """Pass 1 (its *step* of :attr:`passes`) on selected points: their flat cells *k*, coordinates, columns.

        Chunks come in file order: statistics summed point by point in that
        order (``np.add.at``) are those of all the points at once, bit for bit.
        """
        raise NotImplementedError

    def occupied(self, stats: dict[str, np.ndarray]) -> np.ndarray:
        """The cells that hold a selected point (a grid of the statistics' shape)."""
        raise NotImplementedError

    def window(self, stats: dict[str, np.ndarray], frame: Frame, threads: int = 1) -> dict[str, np.ndarray] | None:
        """The result grids of a window of the statistics (on *frame*); None when it has none.

        The window is cut to the box of its occupied cells: the grid a tile
        of points makes.
        """
        raise NotImplementedError

    def values(
        self, xyz: np.ndarray, cols: dict[str, np.ndarray], results: dict[str, np.ndarray] | None, frame: Frame | None
    ) -> np.ndarray:
        """The values of tested points by the *results* on *frame* (None: the window had none)."""
        raise NotImplementedError

    def unchanged(self, results: dict[str, np.ndarray] | None) -> bool:
        """Whether no point would change class by these results (then the input is kept as it is).

        The counts of a kept input are its points and zeros.
        """
        return False


class StageKernel(GridKernel):
    """A kernel that carries its stage's parameters as their JSON dump (*params*, a field of the subclass) and
    validates them once where it runs (:attr:`model`, by the class's :attr:`Params`)."""

    Params: ClassVar[Any]
    params: dict

    @cached_property
    def model(self) -> Any:
        return self.Params.model_validate(self.params)
