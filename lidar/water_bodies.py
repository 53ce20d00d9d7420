"""Water bodies: outlines of the water points with one level each, written and read as a GeoPackage, burnt into grids.

``classify_water`` makes them (:func:`water_bodies` on its water and ground
points, :func:`write_water_bodies`); ``rasterize`` flattens the DTM inside
them (:func:`read_water_bodies`, :func:`burn_levels`).  Method and
thresholds: docs/stages/classify_water.md, "Water bodies and
hydro-flattening".
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pyogrio.raw
import rasterio.features
import shapely
from affine import Affine
from scipy import ndimage

from lidar.grid import step_labels
from lidar.vectors import polygon_z_wkb, wkb_polygons, write_gpkg

#: The layer's name in ``water.gpkg``.
LAYER = "water_bodies"
#: The layer's name in ``breaklines.gpkg``.
BREAKLINES = "breaklines"


@dataclass(frozen=True)
class WaterBody:
    """One water body's polygon: rings (outer first, (n, 2), metres), level (m), area (m2), the body's points and
    height spread (m); a body whose cells touch only at corners has one polygon per part, each with its figures.

    ``shores``: the stretches of its outline that run along ground (not
    along the survey's edge or a data gap): its breaklines.
    ``flat``: its water points span at most the flatness limit, so the DTM
    is flattened at ``level`` inside it; or, a river (``heights``: each
    ring's vertex heights, m), about a level that falls along its axis
    (:func:`river_profile`), so the DTM is flattened bank to bank,
    descending downstream (:func:`burn_levels`).
    """

    rings: list[np.ndarray]
    level: float
    area: float
    points: int
    spread: float
    flat: bool
    heights: list[np.ndarray] | None = None
    shores: tuple[np.ndarray, ...] = ()  # its outline's stretches along a shore ((k, 2) lines, metres): breaklines


#: A river's profile: its water heights' median per this many metres along its axis, before the monotone fit.
RIVER_BIN_M = 5.0
#: A body is a river when it is at least this many times longer (along its axis) than wide.
RIVER_ELONGATION = 3.0
#: Neighbouring cells whose lowest water points differ by more (m) are not one body: a river and the level bank
#: above it (waves of 25 cm, 1 sigma, stay one body).
STEP = 1.0
#: A body is no water when more than this share of the cells around it hold ground or water lower than it (by
#: min_bank plus max_spread): it would drain there (a level bank above a river).  A pond's outlet is a few cells.
DRAINS = 0.25
#: A body whose points are sparser than this share of the ground on its banks is water seen through dropouts
#: (the laser's echoes from water are few: the sea of a coast returns about one pulse in five, a river in IGN's
#: crop_2 about half the ground's density).  Level ground beside it is the same water, unseen.  Land detected as
#: level returns as many echoes as the land around it.
DROPOUT_SHARE = 0.5


def wave_allowance(heights: np.ndarray, tolerance: float) -> float:
    """How far (m) above its level a water body's own echoes reach: *tolerance*, or more on rough water.

    A body's echoes scatter about its level by its waves and the scanner's
    noise: a robust sigma (1.4826 x their median absolute deviation) times
    ``sqrt(2 ln n)``, the largest departure expected of *n* normal
    deviates.  A calm river (2 cm, 15 k echoes: 9 cm) keeps *tolerance*
    (0.15 m); the simulated coast's sea (waves of 5 cm, 19.6 k echoes)
    reaches 0.22 m.

    >>> wave_allowance(np.array([0.0, 0.0, 0.0]), 0.15)
    0.15
    """
    n = len(heights)
    if n < 3:
        return tolerance
    sigma = 1.4826 * float(np.median(np.abs(heights - np.median(heights))))
    return max(tolerance, sigma * math.sqrt(2.0 * math.log(n)))


def binned_medians(station: np.ndarray, values: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per bin of *step* along *station* (from its lowest), ascending: the mean station, the median of *values*, the count.

    One sort, then each bin once (not a pass over every point per bin).

    >>> binned_medians(np.array([0.0, 5.1, 0.4, 5.3]), np.array([1.0, 4.0, 3.0, 2.0]), 5.0)[1]
    array([2., 3.])
    """
    bins = np.floor((station - station.min()) / step).astype(np.int64)
    order = np.argsort(bins, kind="stable")
    bins, station, values = bins[order], station[order], values[order]
    starts = np.flatnonzero(np.r_[True, bins[1:] != bins[:-1]])
    counts = np.diff(np.r_[starts, len(bins)])
    medians = np.array([np.median(v) for v in np.split(values, starts[1:])])
    return np.add.reduceat(station, starts) / counts, medians, counts


def river_axis(ring: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The axis of a body's outer *ring* ((n, 2+) vertices, metres): its centroid and unit direction (x >= 0).

    The principal direction of the vertices: computed the same way from the
    vertices in ``water.gpkg`` by every reader.
    """
    xy = np.asarray(ring, dtype=np.float64)[:-1, :2]
    centre = xy.mean(axis=0)
    direction = np.linalg.eigh(np.cov((xy - centre).T))[1][:, -1]
    if direction[0] < 0 or (direction[0] == 0 and direction[1] < 0):
        direction = -direction
    return centre, direction


def river_profile(xyz: np.ndarray, ring: np.ndarray, max_spread: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Knots (stations along :func:`river_axis`, m; levels, m) of a river's water surface, or None if no river.

    The body must be :data:`RIVER_ELONGATION` times longer than wide.  The
    water heights' median per :data:`RIVER_BIN_M` along the axis, fitted by
    a monotone (isotonic) regression falling the way the heights fall
    (``scipy.optimize.isotonic_regression``, weighted by the points per
    bin); None when the water points spread more than *max_spread* (5th to
    95th percentile) about it.
    """
    centre, direction = river_axis(ring)
    across = np.array([-direction[1], direction[0]])
    vertices = np.asarray(ring)[:, :2] - centre
    length, width = np.ptp(vertices @ direction), np.ptp(vertices @ across)
    if len(xyz) < 3 or length < RIVER_ELONGATION * width:
        return None
    station = (xyz[:, :2] - centre) @ direction
    centres, median, counts = binned_medians(station, xyz[:, 2], RIVER_BIN_M)
    if len(centres) < 2:
        return None
    falls = np.polyfit(centres, median, 1, w=np.sqrt(counts))[0] < 0
    # lazy: scipy.optimize takes about 0.25 s to import, in every worker that makes rasters; only rivers need it
    from scipy.optimize import isotonic_regression

    levels = isotonic_regression(median, weights=counts, increasing=not falls).x
    residual = xyz[:, 2] - np.interp(station, centres, levels)
    if np.percentile(residual, 95) - np.percentile(residual, 5) > max_spread:
        return None
    return centres, levels


def _ring_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _cells(xy: np.ndarray, cell: float, lo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row (north down) and column of each point on a grid of *cell* whose upper-left corner is *lo* (x0, y1)."""
    col = np.floor((xy[:, 0] - lo[0]) / cell).astype(np.int64)
    row = np.floor((lo[1] - xy[:, 1]) / cell).astype(np.int64)
    return row, col


def _per_cell(values: np.ndarray, corner: tuple[float, float], cell: float, xy: np.ndarray, fill) -> np.ndarray:
    """The value of each point's cell (*xy* metres) in the grid *values* of *cell* m whose upper-left corner is
    *corner*; *fill* for points beyond it."""
    row, col = _cells(xy, cell, np.asarray(corner))
    inside = (row >= 0) & (row < values.shape[0]) & (col >= 0) & (col < values.shape[1])
    out = np.full(len(xy), fill, dtype=values.dtype)
    out[inside] = values[row[inside], col[inside]]
    return out


@dataclass(frozen=True)
class CellMask:
    """Cells of *cell* metres on a grid whose upper-left corner is *corner* (x0, y1): :meth:`holds` tells points in."""

    corner: tuple[float, float]
    cell: float
    mask: np.ndarray

    def holds(self, xy: np.ndarray) -> np.ndarray:
        """Which points (metres) lie in a masked cell."""
        return _per_cell(self.mask, self.corner, self.cell, xy, False)


@dataclass(frozen=True)
class CellLevels:
    """A level (m) per cell of *cell* metres on a grid whose upper-left corner is *corner* (x0, y1); NaN: none;
    and how far above it the water's echoes reach there (*reach*, m: :func:`wave_allowance`)."""

    corner: tuple[float, float]
    cell: float
    level: np.ndarray
    reach: np.ndarray

    def at(self, xy: np.ndarray) -> np.ndarray:
        """The level of each point's cell (metres); NaN where it has none."""
        return _per_cell(self.level, self.corner, self.cell, xy, np.nan)

    def water(self, xyz: np.ndarray) -> np.ndarray:
        """Which points ((n, 3), metres) lie at most the cell's reach above its level (none where it has none)."""
        above = xyz[:, 2] - self.at(xyz[:, :2])
        return above <= _per_cell(self.reach, self.corner, self.cell, xyz[:, :2], np.nan)  # NaN: False


@dataclass
class _Grids:
    """The grids :func:`water_bodies` works on (rows north down, from the upper-left corner *lo*)."""

    lo: np.ndarray
    row: np.ndarray  # each water point's cell
    col: np.ndarray
    least: np.ndarray  # lowest water point per cell (NaN: none)
    label: np.ndarray  # the bodies
    mask: np.ndarray  # their cells, closed over dropouts
    lowest: np.ndarray  # lowest ground point per cell (inf: none)
    middle: np.ndarray  # mean ground height per cell (NaN: none)
    grounds: np.ndarray  # ground points per cell
    echoes: np.ndarray  # water and ground points per cell at its lowest echo (within twice the tolerance)
    echoed: np.ndarray  # cells with an echo of any class
    beyond: np.ndarray  # cells beyond the survey


def _in_grid(xy: np.ndarray, cell: float, lo: np.ndarray, shape: tuple[int, int]):
    """Each point's cell ``(row, col)`` and whether it lies on the grid of *shape* (indices clipped onto it)."""
    row, col = _cells(xy, cell, lo)
    inside = (row >= 0) & (row < shape[0]) & (col >= 0) & (col < shape[1])
    return row.clip(0, shape[0] - 1), col.clip(0, shape[1] - 1), inside


def _grids(water, ground, others, *, cell: float, close: int, tolerance: float) -> _Grids:
    """:class:`_Grids` of the water, ground and other points ((n, 3), (m, 3), (k, 2+); metres): the water's box
    and ``close + 3`` cells around it, anchored at whole multiples of *cell*."""
    pad = close + 3
    first = np.floor(water[:, :2].min(axis=0) / cell).astype(np.int64)
    last = np.floor(water[:, :2].max(axis=0) / cell).astype(np.int64)
    lo = np.array([first[0] - pad, last[1] + 1 + pad], dtype=np.float64) * cell  # upper-left corner
    shape = (int(last[1] - first[1]) + 1 + 2 * pad, int(last[0] - first[0]) + 1 + 2 * pad)
    row, col = _cells(water[:, :2], cell, lo)
    least, label, mask = _levels(water[:, 2], row, col, shape, close)
    gr, gc, inside = _in_grid(ground[:, :2], cell, lo, shape)
    z = ground[:, 2]
    lowest = np.full(shape, np.inf)
    np.minimum.at(lowest, (gr[inside], gc[inside]), z[inside])
    flat, size = gr[inside] * shape[1] + gc[inside], shape[0] * shape[1]
    grounds = np.bincount(flat, minlength=size).reshape(shape)
    with np.errstate(invalid="ignore", divide="ignore"):
        middle = np.bincount(flat, weights=z[inside], minlength=size).reshape(shape) / grounds
    below = np.fmin(lowest, least)  # the lowest ground or water of each cell
    # the echoes of each cell at its lowest (within twice the tolerance): at a shore, the water's, not the bank's
    low = np.where(np.isnan(below), np.inf, below) + 2.0 * tolerance
    echoes = np.zeros(shape, dtype=np.int64)
    near = inside & (z <= low[gr, gc])
    np.add.at(echoes, (gr[near], gc[near]), 1)
    np.add.at(echoes, (row, col), 1)
    echoed = (grounds > 0) | (echoes > 0)
    if others is not None and len(others):
        orow, ocol, on = _in_grid(others[:, :2], cell, lo, shape)
        echoed[orow[on], ocol[on]] = True
    beyond = _beyond_the_survey(mask | echoed)
    return _Grids(lo, row, col, least, label, mask, lowest, middle, grounds, echoes, echoed, beyond)


def water_bodies(
    water: np.ndarray,
    ground: np.ndarray,
    *,
    cell: float,
    min_area: float,
    close: int,
    max_spread: float,
    min_bank: float,
    tolerance: float = 0.0,
    others: np.ndarray | None = None,
) -> tuple[list[WaterBody], CellMask, CellLevels]:
    """The water bodies of the water points *water* ((n, 3), metres), with the ground points *ground* around them.

    *others*: the other points around them ((m, 2) or more columns,
    metres), which tell the survey's edge from a roof or a tree's shadow.

    Cells of *cell* (anchored at whole multiples) holding a water point,
    closed by *close* cells (the dropouts between echoes), make bodies
    (8 neighbours, across steps of at most :data:`STEP` between their
    lowest water points); a body reaches *close* cells on into what was
    never seen beyond the survey's edge (unseen cells joined to the grid's
    border).  A body's level is the median height of its water points; its
    banks, the lowest ground point per cell in the ring of two cells around
    it.  A body is no water when its banks rise less than *min_bank* above
    its level (their median; a body without banks is kept: paved ground,
    level and wide, that drains away at its edges), or when more than
    :data:`DRAINS` of the ring lies lower than its water there.  Of the
    others, those of *min_area* or more are returned, their level lowered to
    the 5th percentile of the banks when that is lower (the water at or
    below its banks); flat when the spread of their water heights (5th to
    95th percentile) is at most *max_spread*.  A body seen through
    dropouts (its points sparser than :data:`DROPOUT_SHARE` of the ground in
    the cells around it that stand above its level) first grows through the
    cells next to it whose lowest ground lies within *tolerance* (m) of its
    level: the same water, unseen (0: no growth).  Also returns the cells of
    the bodies taken for no water, and the level of each cell a body grew
    into (the ground there within *tolerance* of it is water).
    """
    if len(water) == 0:
        empty = np.zeros((0, 0), dtype=bool)
        none = np.zeros((0, 0))
        return [], CellMask((0.0, 0.0), cell, empty), CellLevels((0.0, 0.0), cell, none, none)
    g = _grids(water, ground, others, cell=cell, close=close, tolerance=tolerance)
    lo, shape = g.lo, g.label.shape
    below = np.fmin(g.lowest, g.least)
    of_point = g.label[g.row, g.col]
    eight = np.ones((3, 3), bool)
    bodies, grown, reach = [], np.full(shape, np.nan), np.full(shape, np.nan)
    rejected, claimed = np.zeros(shape, dtype=bool), np.zeros(shape, dtype=bool)
    drop = max(min_bank, 0.0) + max_spread  # how much lower the ring must lie for the water to drain there
    pad = close + 3
    for k, (rows, cols) in enumerate(ndimage.find_objects(g.label), start=1):
        rows = slice(max(rows.start - pad, 0), rows.stop + pad)  # room for the ring of banks, and to grow
        cols = slice(max(cols.start - pad, 0), cols.stop + pad)
        body = g.label[rows, cols] == k
        heights = water[of_point == k, 2]
        level = float(np.median(heights))
        seen_through = False
        if tolerance > 0:
            allowance = wave_allowance(heights, tolerance)
            rows, cols, body, seen_through = _seen_through(g, rows, cols, body, level, allowance, close, (grown, reach))
        ring = ndimage.binary_dilation(body, structure=eight, iterations=2) & ~body
        banks = _banks(g.lowest[rows, cols][ring], level, tolerance if seen_through else None)
        if (len(banks) and float(np.median(banks)) - level < min_bank) or _drains(
            body, ring, g.least[rows, cols], below[rows, cols], drop
        ):
            rejected[rows, cols] |= body
            continue
        if seen_through:
            claimed[rows, cols] |= body
        if float(body.sum()) * cell * cell < min_area:
            continue
        if len(banks) and not seen_through:  # a body seen through dropouts has its own level, and no echo of it
            level = min(level, float(np.percentile(banks, 5)))  # is left in its ring
        spread = float(np.percentile(heights, 95) - np.percentile(heights, 5))
        corner = (lo[0] + cols.start * cell, lo[1] - rows.start * cell)
        if close > 0:  # a body cut by the survey's edge reaches it: it runs on beyond (the dropouts at the edge)
            body |= ndimage.binary_dilation(body, structure=eight, iterations=close) & g.beyond[rows, cols]
        shore = ~g.beyond[rows, cols]  # beside the body and within the survey: its shore
        parts = _polygons(body, corner, cell, level, len(heights), spread, spread <= max_spread, shore)
        bodies += [p if p.flat else _as_river(p, water[of_point == k], max_spread) for p in parts]
    rejected &= ~claimed  # a patch refused alone that a kept body grew around and into is its water
    grown[rejected] = reach[rejected] = np.nan
    corner = (float(lo[0]), float(lo[1]))
    return bodies, CellMask(corner, cell, rejected), CellLevels(corner, cell, grown, reach)


def _seen_through(
    g: _Grids, rows: slice, cols: slice, body: np.ndarray, level: float, allowance: float, close: int, out
):
    """A body (its cells *body* in the window *rows*, *cols* of the grids *g*), grown when it is seen through
    dropouts (:func:`_dropout_rate`, :func:`_grown`; *allowance*: how far its echoes depart from its *level*,
    :func:`wave_allowance`), its level and allowance written in *out* (two grids) over its cells; returns its
    window, its cells there and whether it was."""
    window = np.s_[rows, cols]
    sparse = _dropout_rate(
        body,
        g.lowest[window],
        g.echoes[window],
        g.grounds[window],
        g.mask[window],
        level,
        allowance,
        close + 3,  # as far as the ground around the water is read: past a band of its unseen water
    )
    if sparse is None:
        return rows, cols, body, False
    # grown over the whole grid, then looked at around that
    whole = np.zeros(g.label.shape, dtype=bool)
    whole[window] = body
    whole = _grown(whole, g.middle, g.least, g.echoes, g.beyond, ~g.echoed, level, allowance, close, sparse)
    out[0][whole], out[1][whole] = level, allowance
    r, c = np.nonzero(whole)
    rows = slice(max(int(r.min()) - 2, 0), int(r.max()) + 3)
    cols = slice(max(int(c.min()) - 2, 0), int(c.max()) + 3)
    return rows, cols, whole[rows, cols], True


def _banks(ring_lowest: np.ndarray, level: float, tolerance: float | None) -> np.ndarray:
    """The banks' heights: the ring's lowest ground per cell where it has some; for a body seen through dropouts
    (*tolerance* given), those at or above its level less *tolerance* (the ground below it is water or an outlet,
    which the drain rule judges), unless none is."""
    banks = ring_lowest[np.isfinite(ring_lowest)]
    if tolerance is not None and (banks >= level - tolerance).any():
        banks = banks[banks >= level - tolerance]
    return banks


def poisson_rate(mean: float) -> float:
    """The rate of a Poisson count whose mean over the non-zero counts is *mean* (0 when *mean* <= 1).

    Solves ``mean = rate / (1 - exp(-rate))`` by Newton steps from ``mean``.

    >>> round(poisson_rate(1.0 / (1.0 - math.exp(-1.0))), 9), poisson_rate(1.0)
    (1.0, 0.0)
    """
    if mean <= 1.0:
        return 0.0
    rate = mean
    for _ in range(50):
        e = math.exp(-rate)
        f = rate / (1.0 - e) - mean
        if abs(f) < 1e-12 * mean:
            break
        rate -= f / ((1.0 - e - rate * e) / (1.0 - e) ** 2)
    return rate


def _dropout_rate(
    body: np.ndarray,
    lowest: np.ndarray,
    echoes: np.ndarray,
    grounds: np.ndarray,
    water: np.ndarray,
    level: float,
    tolerance: float,
    depth: int,
) -> float | None:
    """The rate (echoes a cell) below which a body's surroundings are as sparse as water seen through dropouts;
    None when the body is not seen through dropouts.

    *body*: its cells; *lowest*: the lowest ground per cell (inf: none);
    *echoes*: water and ground points per cell at its lowest echo (within
    twice the tolerance), *grounds*: ground points per cell; *water*: the
    cells of every body found.  A body is seen through dropouts when its
    cells hold fewer echoes a cell than :data:`DROPOUT_SHARE` of the ground
    on its banks: the cells around it (*depth* deep) whose ground stands
    more than *tolerance* above its *level*, outside other water (a canal
    beside a higher lake: the lake is no bank).
    A bank cell without ground may be a roof or a tree's, so the banks'
    rate is :func:`poisson_rate` of their mean over cells with ground.
    """
    above = np.isfinite(lowest) & (lowest > level + tolerance)
    land = ndimage.binary_dilation(body, structure=np.ones((3, 3), bool), iterations=depth) & ~water & above
    if not land.any():
        return None
    sparse = DROPOUT_SHARE * poisson_rate(grounds[land].sum() / land.sum())
    return sparse if echoes[body].sum() / body.sum() < sparse else None


def _grown(
    body: np.ndarray,
    middle: np.ndarray,
    least: np.ndarray,
    echoes: np.ndarray,
    beyond: np.ndarray,
    void: np.ndarray,
    level: float,
    tolerance: float,
    close: int,
    sparse: float,
) -> np.ndarray:
    """A body seen through dropouts grown through its unseen water: its cells and those joined to it (8 neighbours).

    It grows through the ground within *tolerance* of its *level* that is
    as sparse as it (*sparse*: echoes a cell, over the square of ``2 close
    + 1`` cells counting that ground and voids, not the body's), and across the
    dropouts between its echoes: *void* cells (no echo of any class: not a
    tree's shadow) within *close* cells of water or of that ground, also
    where they join the unseen beyond a sparse survey's edge; never into
    *beyond*, the cells beyond the survey.  *middle*: the mean ground height
    per cell (NaN: none; the lowest of a water surface's many echoes lies
    below it by their noise); *echoes* as for :func:`_dropout_rate`.  Cells
    it encloses whose ground or water (*least*: the lowest water point per
    cell) lies within *tolerance* of its level, or that hold no echo, are
    its water too, however dense their echoes: an island stands above it.
    """
    eight = np.ones((3, 3), bool)
    at_level = (np.abs(middle - level) <= tolerance) & ~body
    side = 2 * close + 1
    with np.errstate(invalid="ignore", divide="ignore"):
        rate = ndimage.uniform_filter(np.where(at_level, echoes, 0).astype(np.float64), side, mode="constant")
        rate /= ndimage.uniform_filter((at_level | void).astype(np.float64), side, mode="constant")
    seen = body | (at_level & (rate < sparse))
    unseen = void & ndimage.binary_dilation(seen, eight, iterations=close)
    out = ndimage.binary_propagation(body, structure=eight, mask=seen | unseen) & ~beyond | body
    with np.errstate(invalid="ignore"):
        level_water = np.abs(least - level) <= tolerance
    return out | (ndimage.binary_fill_holes(out) & (at_level | level_water | void))


def _levels(
    z: np.ndarray, row: np.ndarray, col: np.ndarray, shape: tuple[int, int], close: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each cell's lowest water point (NaN: none), the bodies' labels and their cells, from the water points'
    heights *z* in cells (*row*, *col*) of a grid of *shape*, closed by *close* cells.

    Cells join across a step of at most :data:`STEP` between their lowest
    water points (a cell across a bank's foot holds both levels: its lowest
    is the water's); a cell the closing filled takes its neighbours' lowest.
    A river and a level bank above it are two bodies.
    """
    mask = np.zeros(shape, dtype=bool)
    mask[row, col] = True
    if close > 0:
        mask = ndimage.binary_closing(mask, structure=np.ones((3, 3), bool), iterations=close)
    height = np.full(shape, np.inf)
    np.minimum.at(height, (row, col), z)
    least = np.where(np.isinf(height), np.nan, height)
    for _ in range(close + 1):  # ring by ring into the cells the closing filled
        height = np.where(np.isinf(height), ndimage.minimum_filter(height, 3, mode="constant", cval=np.inf), height)
    return least, step_labels(mask, height, STEP), mask


def _beyond_the_survey(seen: np.ndarray) -> np.ndarray:
    """The cells not *seen* that reach the grid's border through unseen cells (4 neighbours): beyond the survey."""
    unseen, _ = ndimage.label(~seen)
    border = np.unique(np.r_[unseen[0], unseen[-1], unseen[:, 0], unseen[:, -1]])
    return np.isin(unseen, border[border > 0])


def _drains(body: np.ndarray, ring: np.ndarray, least: np.ndarray, below: np.ndarray, drop: float) -> bool:
    """Whether more than :data:`DRAINS` of the *ring*'s cells hold ground or water (*below*) *drop* m or more
    lower than the *body*'s own lowest water (*least*) next to them: water there would drain."""
    own = _neighbours_mean(np.where(body, least, np.nan), 5)[ring]
    around = below[ring]
    seen = np.isfinite(around) & np.isfinite(own)
    return bool(seen.any()) and float(np.mean(around[seen] < own[seen] - drop)) > DRAINS


def _neighbours_mean(values: np.ndarray, size: int) -> np.ndarray:
    """The mean of the finite *values* in each cell's *size* x *size* window (NaN where there is none)."""
    known = np.isfinite(values)
    total = ndimage.uniform_filter(np.where(known, values, 0.0), size, mode="constant")
    count = ndimage.uniform_filter(known.astype(np.float64), size, mode="constant")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 1e-9, total / count, np.nan)


def _as_river(body: WaterBody, xyz: np.ndarray, max_spread: float) -> WaterBody:
    """*body* flattened as a river when its water points *xyz* fall along it (:func:`river_profile`), else as it is."""
    profile = river_profile(xyz, body.rings[0], max_spread)
    if profile is None:
        return body
    centre, direction = river_axis(body.rings[0])
    heights = [np.interp((np.asarray(r)[:, :2] - centre) @ direction, *profile) for r in body.rings]
    return replace(body, level=float(np.median(profile[1])), flat=True, heights=heights)


def _polygons(body, corner, cell, level, points, spread, flat, banks=None) -> list[WaterBody]:
    """The polygons (4-connected parts) of a body's cells, with its figures; drawn in by half a cell at its shores.

    The cells' outline lies up to a cell beyond the outermost water points
    (half a cell on average).  Where the cell beyond lies within the survey
    (*banks*, bool like *body*: a shore), the outline is drawn in by half a
    cell, to the water's edge, where its breakline belongs
    (:func:`shore_lines`); where it faces the unseen beyond the survey's
    edge, it stays.
    """
    side = np.zeros(body.shape, dtype=bool)
    if banks is not None and banks.any():
        twice = np.ones((2, 2), dtype=bool)
        bank = np.kron(banks & ~body, twice)
        shore = ndimage.binary_dilation(bank) & np.kron(body, twice)  # the half cells next to a bank (4 neighbours)
        body, side, cell = np.kron(body, twice) & ~shore, bank | shore, 0.5 * cell
    smallest = (2 * cell) ** 2 if banks is not None and banks.any() else 0.0  # a whole cell of the grid drawn in
    transform = Affine(cell, 0.0, corner[0], 0.0, -cell, corner[1])
    out = []
    for geometry, value in rasterio.features.shapes(body.astype(np.uint8), mask=body, transform=transform):
        rings = [np.asarray(r, dtype=np.float64) for r in geometry["coordinates"]]
        area = _ring_area(rings[0]) - sum(_ring_area(r) for r in rings[1:])
        if value == 1 and area >= smallest:  # not a corner the drawing in cut off
            part = rasterio.features.rasterize([(geometry, 1)], out_shape=body.shape, transform=transform) > 0
            shores = tuple(shore_lines(part & body, side, corner, cell))
            out.append(WaterBody(rings, level, area, points, spread, flat, shores=shores))
    return out


def shore_lines(body: np.ndarray, side: np.ndarray, corner: tuple[float, float], cell: float) -> list[np.ndarray]:
    """The sides of the *body* cells that face a *side* cell, joined into lines ((k, 2) vertices, metres).

    *corner*: the grid's upper-left corner; *cell*: its side.

    >>> body = np.zeros((4, 4), bool); body[1:3, 1:3] = True
    >>> side = np.zeros((4, 4), bool); side[3, :] = True  # ground south of the body only
    >>> [line.tolist() for line in shore_lines(body, side, (0.0, 4.0), 1.0)]
    [[[1.0, 1.0], [3.0, 1.0]]]
    """
    b = np.pad(body, 1)
    o = np.pad(side & ~body, 1)
    # horizontal sides: between rows r - 1 and r (padded), columns c; vertical: between columns c - 1 and c
    hr, hc = np.nonzero((b[:-1, 1:-1] & o[1:, 1:-1]) | (o[:-1, 1:-1] & b[1:, 1:-1]))
    vr, vc = np.nonzero((b[1:-1, :-1] & o[1:-1, 1:]) | (o[1:-1, :-1] & b[1:-1, 1:]))
    if not len(hr) and not len(vr):
        return []
    starts = np.column_stack((np.r_[hc, vc], np.r_[hr, vr])).astype(np.float64)  # (column, row) corners
    ends = starts + np.r_[np.tile([1.0, 0.0], (len(hr), 1)), np.tile([0.0, 1.0], (len(vr), 1))]
    segments = shapely.multilinestrings(shapely.linestrings(np.stack((starts, ends), axis=1)))
    merged = shapely.simplify(shapely.line_merge(segments), 0.0)  # no collinear vertex
    lines = []
    for line in getattr(merged, "geoms", [merged]):
        ij = np.asarray(line.coords, dtype=np.float64)
        lines.append(np.column_stack((corner[0] + ij[:, 0] * cell, corner[1] - ij[:, 1] * cell)))
    return lines


def write_water_bodies(path: Path, bodies: list[WaterBody], *, crs, units) -> None:
    """The bodies as a GeoPackage 1.2 of PolygonZ (every vertex at the body's level), in the CRS's *units*."""
    h, v = units.horizontal, units.vertical
    geometry = [
        polygon_z_wkb([r / h for r in b.rings], b.level / v if b.heights is None else [z / v for z in b.heights])
        for b in bodies
    ]
    fields = {
        "level": np.array([b.level / v for b in bodies], dtype=np.float64),
        "area_m2": np.array([b.area for b in bodies], dtype=np.float64),
        "points": np.array([b.points for b in bodies], dtype=np.int64),
        "spread_m": np.array([b.spread for b in bodies], dtype=np.float64),
        "flattened": np.array([int(b.flat) for b in bodies], dtype=np.int32),
    }
    write_gpkg(path, geometry, fields, crs=crs, layer=LAYER, geometry_type="Polygon Z")


def read_water_bodies(path: Path, units) -> list[tuple[list[np.ndarray], float]]:
    """The flattened bodies of a ``water.gpkg``: (rings, level) each, in metres; rings (n, 3): x, y, height."""
    _, _, geometry, fields = pyogrio.raw.read(str(path), layer=LAYER, columns=["level", "flattened"])
    out = []
    for wkb, level, flat in zip(geometry, fields[0], fields[1], strict=True):
        if wkb is None or not flat:
            continue
        for rings in wkb_polygons(bytes(wkb), z=True):
            scale = np.array([units.horizontal, units.horizontal, units.vertical])
            out.append(([r * scale for r in rings], float(level) * units.vertical))
    return out


def burn_levels(bodies: list[tuple[list[np.ndarray], float]], shape: tuple[int, int], transform) -> np.ndarray:
    """Each cell's water level where its centre lies inside a body (NaN elsewhere); *transform* in metres.

    A body whose rings carry vertex heights that differ (a river) takes, at
    each cell, the height its vertices give at the cell's station along
    :func:`river_axis` (the same bank to bank, falling downstream); any
    other, its level.
    """
    levels = np.full(shape, np.nan)
    if not bodies or shape[0] == 0 or shape[1] == 0:
        return levels

    def polygon(rings):
        return {"type": "Polygon", "coordinates": [np.asarray(r)[:, :2].tolist() for r in rings]}

    rivers = [(rings, level) for rings, level in bodies if is_river(rings)]
    lakes = [(polygon(rings), level) for rings, level in bodies if not is_river(rings)]
    if lakes:
        levels = rasterio.features.rasterize(
            lakes, out_shape=shape, transform=transform, fill=np.nan, dtype="float64", all_touched=False
        )
    for rings, _ in rivers:
        inside = rasterio.features.rasterize([(polygon(rings), 1)], out_shape=shape, transform=transform, fill=0)
        r, c = np.nonzero(inside)
        if not len(r):
            continue
        x, y = transform @ (c + 0.5, r + 0.5)
        levels[r, c] = river_levels(rings, np.column_stack((x, y)))
    return levels


def write_breaklines(path: Path, bodies: list[WaterBody], *, crs, units) -> None:
    """The flattened bodies' shores as 3-D breaklines: a GeoPackage 1.2 of MultiLineString Z, one per body.

    A lake's vertices stand at its level; a river's at the height its
    outline's vertices give their stations (:func:`river_levels`), as the
    DTM is burnt.  Fields: ``water_body`` (the body's feature id in
    ``water.gpkg``), ``kind`` (lake or river), ``level``.
    """
    h, v = units.horizontal, units.vertical
    geometry, ids, kinds, levels = [], [], [], []
    for fid, b in enumerate(bodies, start=1):
        if not b.flat or not b.shores:
            continue
        rings = (
            b.rings
            if b.heights is None
            else [np.column_stack((r[:, :2], z)) for r, z in zip(b.rings, b.heights, strict=True)]
        )
        lines = []
        for line in b.shores:
            z = river_levels(rings, line) if b.heights is not None else np.full(len(line), b.level)
            lines.append(np.column_stack((line / h, z / v)))
        geometry.append(shapely.to_wkb(shapely.MultiLineString(lines), output_dimension=3, flavor="iso"))
        ids.append(fid)
        kinds.append("river" if b.heights is not None else "lake")
        levels.append(b.level / v)
    fields = {
        "water_body": np.array(ids, dtype=np.int64),
        "kind": np.array(kinds, dtype=object),
        "level": np.array(levels, dtype=np.float64),
    }
    write_gpkg(path, geometry, fields, crs=crs, layer=BREAKLINES, geometry_type="MultiLineString Z")


def read_breaklines(path: Path, units) -> list[np.ndarray]:
    """The lines of a ``breaklines.gpkg`` ((k, 3): x, y, height), in metres."""
    _, _, geometry, _ = pyogrio.raw.read(str(path), layer=BREAKLINES)
    scale = np.array([units.horizontal, units.horizontal, units.vertical])
    out = []
    for wkb in geometry:
        if wkb is None:
            continue
        shape = shapely.from_wkb(bytes(wkb))
        out += [np.asarray(g.coords, dtype=np.float64)[:, :3] * scale for g in getattr(shape, "geoms", [shape])]
    return out


def breakline_points(lines: list[np.ndarray], spacing: float) -> np.ndarray:
    """Vertices (n, 3) along 3-D *lines* ((k, 3) each, metres), at most *spacing* apart, heights linear between.

    >>> line = np.array([[0.0, 0.0, 1.0], [4.0, 0.0, 3.0]])
    >>> breakline_points([line], 1.0)[:, [0, 2]].tolist()
    [[0.0, 1.0], [1.0, 1.5], [2.0, 2.0], [3.0, 2.5], [4.0, 3.0]]
    """
    out = [np.zeros((0, 3))]
    for line in lines:
        xyz = np.asarray(line, dtype=np.float64)
        step = np.diff(xyz, axis=0)
        pieces = np.maximum(np.ceil(np.hypot(step[:, 0], step[:, 1]) / spacing), 1).astype(np.int64)
        start = np.repeat(np.arange(len(step)), pieces)
        t = (np.arange(len(start)) - np.repeat(np.cumsum(pieces) - pieces, pieces)) / np.repeat(pieces, pieces)
        out += [xyz[start] + t[:, None] * step[start], xyz[-1:]]  # each segment from its start; the line's end
    return np.concatenate(out)


def is_river(rings: list[np.ndarray]) -> bool:
    return np.asarray(rings[0]).shape[1] >= 3 and bool(np.ptp(np.asarray(rings[0])[:, 2]) > 0)


def river_levels(rings: list[np.ndarray], xy: np.ndarray) -> np.ndarray:
    """A river's water level (m) at points *xy* (metres): its vertex heights interpolated at their stations."""
    centre, direction = river_axis(rings[0])
    vertices = np.concatenate([np.asarray(r)[:, :3] for r in rings])
    station = (vertices[:, :2] - centre) @ direction
    order = np.argsort(station, kind="stable")
    return np.interp((np.asarray(xy) - centre) @ direction, station[order], vertices[order, 2])
