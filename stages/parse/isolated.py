"""Points far from the survey's dense core, flagged withheld in the LAS that ``parse`` writes.

A stray point inside its header's bounds (the bounds were computed with it)
would still size every grid: :func:`withhold_isolated` finds such points on
a coarse occupancy grid (:class:`IsolationGrid`) and withholds them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import laspy
import numpy as np
from scipy import ndimage

from lidar.clouds import progress_chunk
from pipeline.log import stage_progress

#: Cells per side of the occupancy grid that finds points far from the survey.
ISOLATION_GRID = 256
#: A group of points is isolated when it holds at most this share of the survey (and at most
#: ISOLATED_MAX_POINTS) and lies farther than ISOLATED_GAP of the survey's extent, and at least
#: ISOLATED_MIN_GAP_UNITS (in the CRS's units), from the rest.
ISOLATED_MAX_SHARE = 1e-4
ISOLATED_MAX_POINTS = 100
ISOLATED_GAP = 0.1
ISOLATED_MIN_GAP_UNITS = 500.0


class IsolationGrid:
    """Points counted per cell of the ``ISOLATION_GRID``-cell grid over a box (x, y), as
    :func:`withhold_isolated` counts them.

    Parameters
    ----------
    mins, maxs : array-like
        The box's lower and upper corners (x, y first; further values are ignored); its
        longer side must be positive.
    """

    def __init__(self, mins, maxs):
        self.mins = np.asarray(mins, dtype=np.float64)[:2].copy()
        self.maxs = np.asarray(maxs, dtype=np.float64)[:2].copy()
        span = float(max(self.maxs[0] - self.mins[0], self.maxs[1] - self.mins[1]))
        self.cell = span / ISOLATION_GRID * (1 + 1e-9)
        self.counts = np.zeros(ISOLATION_GRID * ISOLATION_GRID, dtype=np.int64)

    def index(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Flat cell index (row-major, rows along y) of points inside the box."""
        cx = np.minimum(((x - self.mins[0]) / self.cell).astype(np.int64), ISOLATION_GRID - 1)
        cy = np.minimum(((y - self.mins[1]) / self.cell).astype(np.int64), ISOLATION_GRID - 1)
        return cy * ISOLATION_GRID + cx

    def add(self, x: np.ndarray, y: np.ndarray) -> None:
        """Count points (inside the box)."""
        self.counts += np.bincount(self.index(x, y), minlength=self.counts.size)

    def covers(self, x_range: tuple[float, float], y_range: tuple[float, float]) -> bool:
        """Whether points spanning *x_range* and *y_range* (min, max) lie inside the box."""
        in_x = self.mins[0] <= x_range[0] and x_range[1] <= self.maxs[0]
        return bool(in_x and self.mins[1] <= y_range[0] and y_range[1] <= self.maxs[1])

    def is_over(self, mins: np.ndarray, maxs: np.ndarray) -> bool:
        """Whether this grid is the one over the box *mins*, *maxs* (bit for bit)."""
        return bool(np.array_equal(self.mins, np.asarray(mins)[:2]) and np.array_equal(self.maxs, np.asarray(maxs)[:2]))


@dataclass(frozen=True)
class Withheld:
    """Points :func:`withhold_isolated` flagged, and the box of the usable points left."""

    count: int
    usable_box: list[float] | None


def withhold_isolated(path: Path, block: int = 1 << 20, counted: IsolationGrid | None = None) -> Withheld | None:
    """Flag withheld, in place, the few points of an intermediate LAS that lie far from the survey's dense core.

    The points are counted on the isolation grid over the header's bounds
    (:class:`IsolationGrid`); small groups of occupied cells far from the
    largest one (:func:`_far_cells`) are withheld, and the box of the usable
    points is recomputed.  Only uncompressed LAS 1.4 formats 6-8 (what the
    pipeline writes) are changed, through a memory map of their records.
    *counted*, the points already counted while the file was written
    (:func:`stages.parse.read_las.copy_records`), saves a pass when it is
    the grid over the file's header bounds and holds every point.  Returns
    the points withheld and the usable points' box, or None when no group of
    cells is far from the survey.  Why: ``docs/stages/parse.md``.
    """
    records = _Records.of(path)
    if records is None:
        return None
    if (
        counted is not None
        and counted.is_over(records.mins, records.maxs)
        and int(counted.counts.sum()) == records.count
    ):
        grid = counted
    else:
        grid = _count_points(records, block)
    flagged_cells = _far_cells(grid, records.count)
    if not flagged_cells.any():
        return None
    return _flag(records, grid, flagged_cells, block)


class _Records:
    """The point records of an uncompressed LAS 1.4 file (formats 6-8), mapped a block at a time."""

    def __init__(self, path: Path, header):
        self.path = path
        self.count, self.offset = int(header.point_count), int(header.offset_to_point_data)
        self.size = int(header.point_format.size)
        self.scales, self.offsets = np.asarray(header.scales), np.asarray(header.offsets)
        self.mins, self.maxs = np.asarray(header.mins), np.asarray(header.maxs)

    @classmethod
    def of(cls, path: Path) -> _Records | None:
        """The file's records, or None when it has no point, another format, or bounds without area."""
        with laspy.open(str(path)) as reader:
            h = reader.header
            records = cls(path, h)
        mins, maxs = records.mins, records.maxs
        if records.count == 0 or h.point_format.id not in (6, 7, 8) or not np.isfinite(mins).all():
            return None
        span = float(max(maxs[0] - mins[0], maxs[1] - mins[1]))
        return records if span > 0 else None

    def map(self, a: int, b: int, mode: str = "r") -> np.memmap:
        """Records a:b as bytes.  Mapped on their own and unmapped after use: a map of the whole
        file would hold every page read in the process (its size in RSS)."""
        return np.memmap(
            self.path, dtype=np.uint8, mode=mode, offset=self.offset + a * self.size, shape=(b - a, self.size)
        )

    def coordinates(self, rec: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The x and y of mapped records."""
        raw = np.ascontiguousarray(rec[:, 0:8]).view("<i4").reshape(-1, 2)
        return raw[:, 0] * self.scales[0] + self.offsets[0], raw[:, 1] * self.scales[1] + self.offsets[1]


def _count_points(records: _Records, block: int) -> IsolationGrid:
    """The file's points counted on the isolation grid over its header bounds."""
    grid = IsolationGrid(records.mins, records.maxs)
    block = progress_chunk(records.count, block)
    with stage_progress(records.count, "isolated points: counting", unit="pt") as bar:
        for a in range(0, records.count, block):
            rec = records.map(a, min(a + block, records.count))
            grid.add(*records.coordinates(rec))
            del rec
            bar.update(min(block, records.count - a))
    return grid


def _far_cells(grid: IsolationGrid, count: int) -> np.ndarray:
    """Mask of the grid's cells (flat) in groups far from the survey's largest group.

    Groups of occupied cells (8-connected, one empty cell bridged) that hold
    at most ``ISOLATED_MAX_SHARE`` of the *count* points (and at most
    ``ISOLATED_MAX_POINTS``) and lie farther from the largest group than
    ``ISOLATED_GAP`` of its extent (and ``ISOLATED_MIN_GAP_UNITS``).
    """
    hist = grid.counts
    occupied = (hist > 0).reshape(ISOLATION_GRID, ISOLATION_GRID)
    labels, n_groups = ndimage.label(ndimage.binary_dilation(occupied, np.ones((3, 3))), np.ones((3, 3)))
    labels = np.where(occupied, labels, 0)
    if n_groups < 2:
        return np.zeros(0, dtype=bool)
    points = np.bincount(labels.ravel(), weights=hist, minlength=n_groups + 1)
    points[0] = 0
    main = int(np.argmax(points))
    rows, cols = np.nonzero(labels == main)
    extent = max(int(np.ptp(rows)), int(np.ptp(cols)), 1) * grid.cell
    gap = max(ISOLATED_GAP * extent, ISOLATED_MIN_GAP_UNITS)
    distance = ndimage.distance_transform_edt(labels != main) * grid.cell
    small = (points <= min(ISOLATED_MAX_POINTS, ISOLATED_MAX_SHARE * count)) & (points > 0)
    far = np.zeros(n_groups + 1, dtype=bool)
    groups = np.flatnonzero(small)
    if len(groups):
        far[groups] = np.asarray(ndimage.minimum(distance, labels=labels, index=groups)) > gap
    return far[labels.ravel()]


def _flag(records: _Records, grid: IsolationGrid, flagged_cells: np.ndarray, block: int) -> Withheld:
    """Flag withheld the points in *flagged_cells*, in place; the box of the points still usable."""
    withheld = 0
    box = None
    block = progress_chunk(records.count, block)
    with stage_progress(records.count, "isolated points: flagging", unit="pt") as bar:
        for a in range(0, records.count, block):
            rec = records.map(a, min(a + block, records.count), "r+")
            x, y = records.coordinates(rec)
            hit = flagged_cells[grid.index(x, y)]
            if hit.any():
                rec[:, 15][hit] |= 0x04  # classification flags, bit 2: withheld (LAS 1.4, formats 6-10)
                withheld += int(hit.sum())
                rec.flush()
            keep = ~hit & (rec[:, 15] & 0x04 == 0)
            del rec
            if keep.any():
                lo = np.array([x[keep].min(), y[keep].min()])
                hi = np.array([x[keep].max(), y[keep].max()])
                box = [*lo, *hi] if box is None else [*np.minimum(box[:2], lo), *np.maximum(box[2:], hi)]
            bar.update(min(block, records.count - a))
    return Withheld(withheld, None if box is None else [float(v) for v in box])
