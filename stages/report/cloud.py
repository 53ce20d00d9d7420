"""What the report shows of a point cloud, read chunk by chunk: strips, classes, first returns, repeatability.

Memory does not grow with the number of points: every figure is a grid of
the DTM's shape, or a few grids per strip on a lattice of cells
(:class:`StripSpans`).  The per-file table beside it (:func:`las_info`) is
``pipeline info``'s summary.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import laspy
import numpy as np
from affine import Affine

from lidar import glossary
from lidar.checkpoints import sample_dtm
from lidar.clouds import cloud_crs, read_chunks_counted
from lidar.las_summary import summary
from lidar.units import Units

#: Strips x cells above which the repeatability grids are kept on a lattice of cells.
MAX_SPAN_CELLS = 20_000_000


@dataclass
class CloudSummary:
    """What the report shows of the classified points, gathered chunk by chunk."""

    units: Units
    strip_grid: np.ndarray  # point_source_id of the last point seen in each DTM cell (-1: none)
    strips: np.ndarray  # every point_source_id met, ascending
    class_counts: np.ndarray  # points per ASPRS class (256 bins)
    points: int
    first_returns: np.ndarray | None = None  # first returns (not noise, not withheld) per DTM cell
    repeatability_m: float | None = None  # smooth surface repeatability (see MEASURES), metres
    repeatability_cells: int = 0
    header: dict = field(default_factory=dict)  # lasinfo-like figures of the file
    class_0_kept: int = 0  # points in class 0 (never classified) not flagged withheld
    class_by_strip: dict[int, np.ndarray] = field(default_factory=dict)  # point_source_id -> points per class
    class_grid: np.ndarray | None = None  # class of the highest point in each DTM cell (-1: none)
    top_grid: np.ndarray | None = None  # the highest point's z in each DTM cell (NaN: none), CRS units


def las_info(path: str | Path, gps_range: tuple[float, float] | None = None) -> dict:
    """One row of the report's per-file table, from :func:`lidar.las_summary.summary` (``pipeline info``).

    *gps_range*: the GPS time range when the caller has already read it (the
    header is then all that is read); otherwise one pass over the points.
    """
    s = summary(path, points=gps_range is None)
    if gps_range is None:
        gps = s.get("gps_time") or {}
        gps_range = (gps.get("min"), gps.get("max"))
    tmin, tmax = (np.nan if v is None else v for v in gps_range)
    adjusted = bool(s["global_encoding"] & 1)
    by_return = list(s["points_by_return_header"])
    while by_return and by_return[-1] == 0:
        by_return.pop()
    lo, hi = s["bounds_header"]["min"], s["bounds_header"]["max"]
    return {
        "file": Path(path).name,
        "LAS version": s["version"],
        "point format": s["point_format"],
        "points": s["points"],
        "bounds x": f"{lo[0]:,.2f} – {hi[0]:,.2f}",
        "bounds y": f"{lo[1]:,.2f} – {hi[1]:,.2f}",
        "bounds z": f"{lo[2]:,.2f} – {hi[2]:,.2f}",
        "CRS": s["crs"]["name"] or "none in the header",
        "GPS time": f"{tmin:,.3f} – {tmax:,.3f} ({'adjusted standard' if adjusted else 'GPS week'} time)"
        if np.isfinite(tmin)
        else "none",
        "points by return": ", ".join(f"{i + 1}: {v:,}" for i, v in enumerate(by_return)) or "—",
    }


@dataclass
class CloudTally:
    """The per-cell and per-class counts of :class:`CloudSummary`, added up chunk by chunk."""

    rows: int
    cols: int
    strip_grid: np.ndarray  # point_source_id of the last point seen in each cell (-1: none)
    first: np.ndarray  # first returns per cell, flat
    seen: set[int] = field(default_factory=set)
    counts: np.ndarray = field(default_factory=lambda: np.zeros(256, dtype=np.int64))
    points: int = 0
    class_0_kept: int = 0
    by_strip: dict[int, np.ndarray] = field(default_factory=dict)
    top_z: np.ndarray | None = None  # highest z per cell, flat (-inf: none)
    top_class: np.ndarray | None = None  # its class (-1: none)
    tmin: float = np.inf
    tmax: float = -np.inf

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> CloudTally:
        rows, cols = shape
        return cls(rows, cols, np.full((rows, cols), -1, dtype=np.int64), np.zeros(rows * cols, dtype=np.int64))

    def add(self, chunk, r: np.ndarray, c: np.ndarray, sid: np.ndarray, cls: np.ndarray) -> np.ndarray:
        """Count one chunk whose points fall in cells (*r*, *c*); returns its usable first returns."""
        self.strip_grid[r, c] = sid  # in file order: the last point seen wins
        self.seen.update(int(v) for v in np.unique(sid))
        self.counts += np.bincount(cls, minlength=256)
        self.points += len(chunk)
        strips, which = np.unique(sid, return_inverse=True)
        per_strip = np.bincount(which * 256 + cls, minlength=len(strips) * 256).reshape(len(strips), 256)
        for s, counts in zip(strips, per_strip, strict=True):
            self.by_strip[int(s)] = self.by_strip.get(int(s), 0) + counts
        withheld = np.asarray(chunk.withheld, dtype=bool)
        self.class_0_kept += int(((cls == 0) & ~withheld).sum())
        usable = glossary.usable(cls, withheld)
        self._highest((r * self.cols + c)[usable], np.asarray(chunk.z)[usable], cls[usable])
        t = np.asarray(chunk.gps_time)
        t = t[np.isfinite(t)]
        if len(t):
            self.tmin, self.tmax = min(self.tmin, float(t.min())), max(self.tmax, float(t.max()))
        ret = np.asarray(chunk.return_number)
        one = usable & (ret <= 1)
        self.first += np.bincount((r * self.cols + c)[one], minlength=self.rows * self.cols)
        return one

    def _highest(self, cell: np.ndarray, z: np.ndarray, cls: np.ndarray) -> None:
        """Keep each cell's highest point (noise and withheld left out by the caller) and its class."""
        if self.top_z is None:
            self.top_z = np.full(self.rows * self.cols, -np.inf)
            self.top_class = np.full(self.rows * self.cols, -1, dtype=np.int16)
        np.maximum.at(self.top_z, cell, z)
        top = z == self.top_z[cell]
        self.top_class[cell[top]] = cls[top]


class StripSpans:
    """Smooth surface repeatability (intraswath), gathered chunk by chunk.

    Per strip and cell, the lowest and highest residual of the strip's ground
    single returns about the DTM (metres) and their count.  When strips x
    cells would exceed :data:`MAX_SPAN_CELLS`, only every n-th row and column
    is kept (the lattice grows as strips appear; a strip whose grids were
    made on a finer lattice is left out from then on).
    """

    def __init__(self, dtm: np.ndarray, transform: Affine, shape: tuple[int, int], units: Units) -> None:
        self.dtm, self.transform, self.units = dtm, transform, units
        self.rows, self.cols = shape
        self.lattice = 1
        self.ranges: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}

    def add(
        self,
        x: np.ndarray,
        y: np.ndarray,
        z: np.ndarray,
        r: np.ndarray,
        c: np.ndarray,
        sid: np.ndarray,
        single: np.ndarray,
        strips_seen: int,
    ) -> None:
        """Add the points *single* of a chunk (cells *r*, *c*; strips *sid*), *strips_seen* strips met so far."""
        if not single.any():
            return
        rows, cols = self.rows, self.cols
        if strips_seen * rows * cols > MAX_SPAN_CELLS:
            self.lattice = max(self.lattice, int(np.ceil(np.sqrt(strips_seen * rows * cols / MAX_SPAN_CELLS))))
        lattice = self.lattice
        sel = single & (r % lattice == 0) & (c % lattice == 0)
        res = (z[sel] - sample_dtm(self.dtm, self.transform, np.column_stack((x[sel], y[sel])))) * self.units.vertical
        key = (r[sel] // lattice) * (-(-cols // lattice)) + c[sel] // lattice
        size = (-(-rows // lattice)) * (-(-cols // lattice))
        ok = np.isfinite(res)
        for s in np.unique(sid[sel][ok]):
            m = ok & (sid[sel] == s)
            lo, hi, cnt = self.ranges.get(int(s)) or (
                np.full(size, np.inf, np.float32),
                np.full(size, -np.inf, np.float32),
                np.zeros(size, np.int32),
            )
            if len(lo) != size:  # the lattice grew: this strip's cells are dropped
                continue
            np.minimum.at(lo, key[m], res[m])
            np.maximum.at(hi, key[m], res[m])
            np.add.at(cnt, key[m], 1)
            self.ranges[int(s)] = (lo, hi, cnt)

    def median_span(self, resolution: float) -> tuple[float | None, int]:
        """The median height range over the level cells with 4 returns of one strip or more, and their count."""
        level = level_cells(self.dtm, resolution, self.units)[:: self.lattice, :: self.lattice].ravel()
        spans = [np.zeros(0, np.float32)]
        for lo, hi, cnt in self.ranges.values():
            if len(cnt) != len(level):
                continue  # allocated before the lattice grew: another geometry of cells
            good = (cnt >= 4) & level
            spans.append(hi[good] - lo[good])
        spans = np.concatenate(spans)
        cells = int(len(spans))
        return (float(np.median(spans)) if cells else None), cells


def level_cells(dtm: np.ndarray, resolution: float, units: Units) -> np.ndarray:
    """The DTM's level cells: slope 5 % at most (NaN: not level; one row or column: none)."""
    if min(dtm.shape) >= 2:
        gy, gx = np.gradient(dtm * units.vertical, resolution * units.horizontal)
        return np.hypot(gx, gy) <= 0.05
    return np.zeros(dtm.shape, dtype=bool)  # one row or column: no slope, so no level cell


def summarise_cloud(
    path: str | Path,
    *,
    origin: tuple[float, float],
    resolution: float,
    shape: tuple[int, int],
    dtm: np.ndarray | None = None,
    advance: Callable[[int], object] | None = None,
) -> CloudSummary:
    """Strip coverage, class counts, first returns per cell and the intraswath figure, read in chunks.

    Parameters
    ----------
    path : str or Path
        The classified LAS/LAZ file.
    origin, resolution, shape
        The DTM's upper-left corner and cell size (CRS units), rows x cols.
    dtm : ndarray, optional
        The DTM, for the repeatability (None: not measured).
    advance : callable, optional
        Told the points read.
    """
    rows, cols = shape
    x0, y1 = origin
    tally = CloudTally.empty(shape)
    spans = None
    with laspy.open(str(path)) as reader:
        units = Units.of(cloud_crs(reader))
        if dtm is not None:
            spans = StripSpans(dtm, Affine(resolution, 0, x0, 0, -resolution, y1), shape, units)
        for chunk in read_chunks_counted(reader, 1_000_000, advance):  # the strips' lattice grows chunk by chunk
            x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
            c = np.clip(((x - x0) / resolution).astype(int), 0, cols - 1)
            r = np.clip(((y1 - y) / resolution).astype(int), 0, rows - 1)
            sid = np.asarray(chunk.point_source_id).astype(np.int64)
            cls = np.asarray(chunk.classification)
            one = tally.add(chunk, r, c, sid, cls)
            if spans is not None:
                # one strip's ground single returns about the DTM, per cell: their height range
                single = one & (cls == 2) & (np.asarray(chunk.number_of_returns) <= 1) & (sid > 0)
                spans.add(x, y, z, r, c, sid, single, len(tally.seen))
    repeat, cells = spans.median_span(resolution) if spans is not None and spans.ranges else (None, 0)
    return CloudSummary(
        units,
        tally.strip_grid,
        np.array(sorted(tally.seen), dtype=np.int64),
        tally.counts,
        tally.points,
        tally.first.reshape(rows, cols),
        repeat,
        cells,
        las_info(path, (tally.tmin, tally.tmax)),
        tally.class_0_kept,
        tally.by_strip,
        tally.top_class.reshape(rows, cols) if tally.top_class is not None else None,
        np.where(np.isfinite(tally.top_z), tally.top_z, np.nan).reshape(rows, cols)
        if tally.top_z is not None
        else None,
    )
