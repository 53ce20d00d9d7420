"""Buildings and vegetation on a grid of the surface: pure functions of coordinates and returns.

The surface is the highest point of each cell (a DSM); a roof is a set of
cells whose 3 x 3 neighbourhood is planar, joined without a height jump,
standing ``min_height`` or more above most of the cells around it (its
walls), with single returns dominating.  After Zhang, K., Yan, J., Chen,
S.-C. (2006), Automatic construction of building footprints from airborne
LIDAR data, IEEE TGRS 44(9), 2523-2533, doi:10.1109/TGRS.2006.874137
(planar regions grown on a grid, told from trees by planarity); it departs
from it in testing the step at a region's edge instead of trusting the
ground filter, so a roof the filter took for ground is still found.
Method and departures: docs/stages/classify_objects.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dtm.common import glossary
from dtm.common.grid import Grid, cell_of, fill_nearest

#: The classes this stage may change: what the ground filter left (1) and took for ground (2).
CANDIDATES = (glossary.UNCLASSIFIED, glossary.GROUND)
BUILDING, LOW_VEGETATION, MEDIUM_VEGETATION, HIGH_VEGETATION, BRIDGE = 6, 3, 4, 5, 17

#: A building point stands at least this high (m) above the ground under it (the foot of a wall stays).
WALL_FOOT = 0.5

#: Cells around a roof looked at for its walls: this many cells out.
RING = 1

#: How far (m) around a roof's planar cells its walls and eaves may lie: its planar cells stop a cell
#: short of its edge, and on cells of a metre or less its wall's points lie in the edge cell or the one beyond.
WALLS = 2.0

#: Widest wall shadow (m): an empty cell takes the lowest point seen this far beyond it (:func:`seen_below`).
SHADOW = 6.0


@dataclass(frozen=True)
class Surface:
    """The highest and lowest point of each cell, counts, and how planar each cell's 3 x 3 neighbourhood is."""

    grid: Grid
    row: np.ndarray  # of each point
    col: np.ndarray
    top: np.ndarray  # highest z per cell (NaN: empty)
    bottom: np.ndarray  # lowest z per cell
    count: np.ndarray  # points per cell
    single: np.ndarray  # single returns per cell
    residual: np.ndarray  # RMS (m) of ``top`` about the plane of its 3 x 3 cells (NaN: fewer than 6 cells)


def surface(xyz: np.ndarray, single: np.ndarray, cell: float) -> Surface:
    """The :class:`Surface` of points *xyz* (metres) on cells of *cell* m anchored at whole multiples of it."""
    lo, hi = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
    grid = Grid.covering(lo[0], lo[1], hi[0], hi[1], cell)
    row, col = cell_of(xyz, grid)
    k = row * grid.cols + col
    size = grid.rows * grid.cols
    top = np.full(size, -np.inf)
    np.maximum.at(top, k, xyz[:, 2])
    bottom = np.full(size, np.inf)
    np.minimum.at(bottom, k, xyz[:, 2])
    count = np.bincount(k, minlength=size)
    top[count == 0] = np.nan
    bottom[count == 0] = np.nan
    shape = (grid.rows, grid.cols)
    top, bottom = top.reshape(shape), bottom.reshape(shape)
    singles = np.bincount(k, weights=np.asarray(single, dtype=np.float64), minlength=size).reshape(shape)
    return Surface(grid, row, col, top, bottom, count.reshape(shape), singles, plane_residual(top))


def plane_residual(top: np.ndarray) -> np.ndarray:
    """RMS (m) of each cell's 3 x 3 neighbourhood of *top* about its least-squares plane.

    NaN where the cell is empty or fewer than 6 of the 9 cells hold a value.
    Each value depends only on its 9 cells: a window of the grid gives the
    same values as the whole grid.

    >>> z = np.add.outer(np.arange(4.0), 0.5 * np.arange(4.0))
    >>> float(np.nanmax(plane_residual(z))) < 1e-6
    True
    """
    from scipy import ndimage

    w = np.isfinite(top).astype(np.float64)
    z = np.where(w > 0, top, 0.0)
    u = np.array([[-1.0, 0, 1]] * 3)  # columns
    v = u.T  # rows
    one = np.ones((3, 3))

    def box(values: np.ndarray, kernel: np.ndarray) -> np.ndarray:
        return ndimage.correlate(values, kernel, mode="constant", cval=0.0)

    s0, su, sv = box(w, one), box(w, u), box(w, v)
    suu, suv, svv = box(w, u * u), box(w, u * v), box(w, v * v)
    sz, suz, svz, szz = box(z, one), box(z, u), box(z, v), box(z * z, one)
    ok = (s0 >= 6) & (w > 0)
    s0, su, sv, suu, suv, svv = (m[ok] for m in (s0, su, sv, suu, suv, svv))
    b0, b1, b2 = sz[ok], suz[ok], svz[ok]
    # The normal equations [[s0, su, sv], [su, suu, suv], [sv, suv, svv]] c = b solved by their adjugate: a
    # batched np.linalg.solve of 3 x 3 systems took 3.5 s a million cells, this 0.1 s.  Six of nine cells
    # never lie on one line, so the determinant is positive.
    c00, c01, c02 = suu * svv - suv * suv, sv * suv - su * svv, su * suv - suu * sv
    c11, c12, c22 = s0 * svv - sv * sv, su * sv - s0 * suv, s0 * suu - su * su
    det = s0 * c00 + su * c01 + sv * c02
    fit = (
        b0 * (c00 * b0 + c01 * b1 + c02 * b2)
        + b1 * (c01 * b0 + c11 * b1 + c12 * b2)
        + b2 * (c02 * b0 + c12 * b1 + c22 * b2)
    ) / det  # c . b
    out = np.full(top.shape, np.nan)
    out[ok] = np.sqrt(np.maximum(szz[ok] - fit, 0.0) / s0)
    return out


def planar_segments(top: np.ndarray, residual: np.ndarray, planarity: float, step: float) -> np.ndarray:
    """Labels (1, 2, ...; 0 = none) of the regions of planar cells joined across cell sides without a jump.

    A cell is planar when its residual is at most *planarity*; two planar
    neighbours (4-connected) join when their heights differ by at most *step*.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    planar = residual <= planarity  # NaN: not planar
    rows, cols = top.shape
    index = np.arange(rows * cols).reshape(rows, cols)
    pairs = []
    for a, b, ta, tb, pa, pb in (
        (index[:, :-1], index[:, 1:], top[:, :-1], top[:, 1:], planar[:, :-1], planar[:, 1:]),
        (index[:-1, :], index[1:, :], top[:-1, :], top[1:, :], planar[:-1, :], planar[1:, :]),
    ):
        joined = pa & pb & (np.abs(ta - tb) <= step)
        pairs.append((a[joined], b[joined]))
    i = np.concatenate([p[0] for p in pairs])
    j = np.concatenate([p[1] for p in pairs])
    graph = coo_matrix((np.ones(len(i), np.int8), (i, j)), shape=(rows * cols, rows * cols))
    _, component = connected_components(graph, directed=False)
    members = planar.ravel()
    labels = np.zeros(rows * cols, dtype=np.int64)
    _, labels[members] = np.unique(component[members], return_inverse=True)
    labels[members] += 1
    return labels.reshape(rows, cols)


def neighbour_views(shape: tuple[int, int], reach: int = 1):
    """For each offset (dr, dc) within *reach* (not 0, 0): the slices of the cells and of their neighbours.

    Yields ``(here, there, r0, c0)``: ``array[there]`` holds, at each cell of
    ``array[here]``, its neighbour (r + dr, c + dc); ``r0, c0`` is the first
    cell of *here*.
    """
    rows, cols = shape
    for dr in range(-reach, reach + 1):
        for dc in range(-reach, reach + 1):
            if dr == 0 and dc == 0:
                continue
            r0, r1 = max(0, -dr), rows - max(0, dr)
            c0, c1 = max(0, -dc), cols - max(0, dc)
            yield (slice(r0, r1), slice(c0, c1)), (slice(r0 + dr, r1 + dr), slice(c0 + dc, c1 + dc)), r0, c0


def wall_shares(labels: np.ndarray, top: np.ndarray, bottom: np.ndarray, min_height: float, n: int) -> np.ndarray:
    """Per label (index = label): the share of the cells within ``RING`` cells of it that lie below it.

    A cell around a region (not in it, holding points) lies below it when its
    lowest point is at least *min_height* below the highest top of the
    region's cells within ``RING`` cells of it.  Empty cells (voids, the
    survey's edge) do not count.  Regions with no cell around: share 0.
    *n*: the number of labels plus one (the length of the result).
    """
    rows, cols = labels.shape
    cells, owners, heights = [], [], []
    for here, there, r0, c0 in neighbour_views(labels.shape, RING):
        lab = labels[there]
        take = (lab > 0) & (lab != labels[here]) & np.isfinite(bottom[here])
        rr, cc = np.nonzero(take)
        cells.append((rr + r0) * cols + (cc + c0))
        owners.append(lab[take])
        heights.append(top[there][take])
    cell = np.concatenate(cells)
    owner = np.concatenate(owners)
    height = np.concatenate(heights)
    if len(cell) == 0:
        return np.zeros(n)
    key = owner * (rows * cols) + cell
    order = np.lexsort((height, key))
    last = np.r_[key[order][1:] != key[order][:-1], True]  # the highest roof top of each (region, cell)
    key, height = key[order][last], height[order][last]
    owner, cell = key // (rows * cols), key % (rows * cols)
    below = bottom.ravel()[cell] <= height - min_height
    around = np.bincount(owner, minlength=n)
    down = np.bincount(owner, weights=below.astype(np.float64), minlength=n)
    return np.divide(down, around, out=np.zeros(n), where=around > 0)


def grown(labels: np.ndarray, top: np.ndarray, bottom: np.ndarray, step: float) -> np.ndarray:
    """*labels* grown by one cell into unlabelled cells whose every point lies within *step* of a region's top.

    A roof's eaves and its ridge are not planar, but they are the roof's,
    not what stands around it; a cell holding a wall's foot, or the bend at
    the top of a slope, has points farther down and stays out.  A cell next
    to two regions joins the larger label.
    """
    out = labels.copy()
    free = (labels == 0) & np.isfinite(top)
    for here, there, _, _ in neighbour_views(labels.shape):
        lab = labels[there]
        level = (np.abs(top[here] - top[there]) <= step) & (np.abs(bottom[here] - top[there]) <= step)
        join = free[here] & (lab > 0) & level
        out[here] = np.where(join, np.maximum(out[here], lab), out[here])
    return out


def seen_below(bottom: np.ndarray, roofs: np.ndarray, reach_cells: int) -> np.ndarray:
    """*bottom* with its empty cells filled with the lowest point seen around them outside *roofs*.

    An empty cell beside a roof is, in airborne data, mostly the shadow of
    its wall (or a window, a dark or wet surface): it takes the lowest
    *bottom* of the cells outside *roofs* within *reach_cells* cells (a
    square); NaN where there is none.
    """
    from scipy import ndimage

    outside = np.where(roofs | np.isnan(bottom), np.inf, bottom)
    low = ndimage.minimum_filter(outside, size=2 * reach_cells + 1, mode="constant", cval=np.inf)
    low[np.isinf(low)] = np.nan
    return np.where(np.isnan(bottom) & ~roofs, low, bottom)


def building_cells(s: Surface, params) -> np.ndarray:
    """The cells of buildings (bool grid): roof regions passing every test of ``params`` (:class:`BuildingParams`)."""
    from scipy import ndimage

    cell = s.grid.resolution
    step = max(0.5 * params.min_height, cell)
    labels = planar_segments(s.top, s.residual, params.planarity, step)
    n = int(labels.max()) + 1
    if n == 1:
        return np.zeros(labels.shape, dtype=bool)
    area = np.bincount(labels.ravel(), minlength=n) * cell * cell
    points = np.bincount(labels.ravel(), weights=s.count.ravel(), minlength=n)
    singles = np.bincount(labels.ravel(), weights=s.single.ravel(), minlength=n)
    extent = np.zeros(n)
    for i, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is not None:
            extent[i] = max(box[0].stop - box[0].start, box[1].stop - box[1].start) * cell
    ok = (area >= params.min_area) & (extent <= params.max_size)
    ok &= singles >= params.single_returns * np.maximum(points, 1)
    ok[0] = False
    if ok.any():
        candidates = grown(np.where(ok[labels], labels, 0), s.top, s.bottom, step)
        bottom = seen_below(s.bottom, candidates > 0, int(np.ceil(SHADOW / cell)))
        ok &= wall_shares(candidates, s.top, bottom, params.min_height, n) >= params.wall_share
    return ok[labels]


def ground_under(xyz: np.ndarray, ground: np.ndarray, s: Surface, away: np.ndarray, reach_cells: float) -> np.ndarray:
    """The ground height of each cell: mean of its *ground* points outside the cells *away*, gaps filled.

    A gap takes the value of the nearest cell with ground, up to
    *reach_cells* cells away (NaN farther).
    """
    k = s.row * s.grid.cols + s.col
    use = ground & ~away.ravel()[k]
    size = s.grid.rows * s.grid.cols
    n = np.bincount(k[use], minlength=size)
    total = np.bincount(k[use], weights=xyz[use, 2], minlength=size)
    mean = np.divide(total, n, out=np.full(size, np.nan), where=n > 0).reshape(s.grid.rows, s.grid.cols)
    return fill_nearest(mean, max_cells=reach_cells)


def object_classes(
    xyz: np.ndarray,
    classification: np.ndarray,
    number_of_returns: np.ndarray,
    usable: np.ndarray,
    params,
    cell: float,
    multi_echo: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """New classes of the points, and the building cells' grid mask's cell per point (True: in a building cell).

    *xyz* in metres; *usable*: the points that are neither noise nor
    withheld; *params*: :class:`~dtm.stages.classify_objects.params.ClassifyObjectsParams`;
    *cell*: the grid's cell (m); *multi_echo*: whether the survey records
    several returns per pulse (then vegetation is told by them, else by
    roughness).  Points of class 1 or 2 may become 6 or 17 (bridge decks,
    :mod:`dtm.stages.classify_objects.bridges`); of class 1, 3, 4 or 5;
    every other class stays.
    """
    out = np.asarray(classification, dtype=np.uint8).copy()
    in_building = np.zeros(len(out), dtype=bool)
    if not usable.any():
        return out, in_building
    pts = xyz[usable]
    s = surface(pts, np.asarray(number_of_returns)[usable] <= 1, cell)
    from scipy import ndimage

    b = params.buildings
    roofs = building_cells(s, b) if b.enabled else np.zeros(s.top.shape, dtype=bool)
    decks = np.zeros(s.top.shape, dtype=bool)
    if params.bridges.enabled:
        from dtm.stages.classify_objects.bridges import deck_cells

        decks = deck_cells(s, params.bridges, b.planarity, b.min_area)
        roofs &= ~decks
    rings = max(1, round(WALLS / cell))
    edges = ndimage.binary_dilation(roofs, np.ones((3, 3), bool), iterations=rings) if roofs.any() else roofs
    cls = out[usable]
    ground = ground_under(pts, cls == glossary.GROUND, s, edges | decks, b.max_size / cell)
    k = (s.row, s.col)
    height = pts[:, 2] - ground[k]
    # a roof's own cells take ground points too (a roof the filter took for ground); the cells at its edge
    # (eaves, walls) take the single returns the filter left above a wall's foot, and its ground points
    # min_height up (a tree beside a wall returns several times)
    single = np.asarray(number_of_returns)[usable] <= 1
    wall = edges[k] & np.isin(cls, CANDIDATES) & ~(height < WALL_FOOT) & single
    may = np.where(roofs[k], np.isin(cls, CANDIDATES), wall)
    building = may & ~(height < WALL_FOOT)  # NaN height (no ground near): the roof decides
    new = cls.copy()
    new[building] = BUILDING
    if decks.any():  # the deck's points, not what lies under it: near its top
        deck_top = ndimage.maximum_filter(np.where(decks, s.top, -np.inf), size=3)[k]
        near_top = pts[:, 2] >= deck_top - 0.5 * params.bridges.clearance
        on_deck = decks[k] & np.isin(cls, CANDIDATES) & near_top
        new[on_deck] = BRIDGE
        building &= ~on_deck
    v = params.vegetation
    if v.enabled:
        if multi_echo:  # a canopy: a share of the pulses around returned more than once
            several = np.where(s.count > 0, 1.0 - s.single / np.maximum(s.count, 1), 0.0)  # a void is no canopy
            rough = (
                ndimage.uniform_filter(several, 3, mode="constant")
                * 9
                / np.maximum(ndimage.uniform_filter((s.count > 0).astype(float), 3, mode="constant") * 9, 1)
                >= v.multiple_returns
            )
            rough = rough[k]
        else:  # single-echo sensors: a rough surface, or points seen at every height down a cell (a crown)
            rough = ~(s.residual[k] <= v.roughness) | (s.top - s.bottom >= v.breaks[1])[k]
        rough |= np.asarray(number_of_returns)[usable] > 1
        veg = (new == glossary.UNCLASSIFIED) & rough & (height >= v.breaks[0])
        new[veg] = np.where(
            height[veg] >= v.breaks[2],
            HIGH_VEGETATION,
            np.where(height[veg] >= v.breaks[1], MEDIUM_VEGETATION, LOW_VEGETATION),
        )
    out[usable] = new
    in_building[usable] = building
    return out, in_building
