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
from scipy import ndimage

from lidar import glossary
from lidar.arrays import add_counts
from lidar.grid import Grid, cell_of, fill_nearest
from stages.classify_objects.bridges import deck_cells
from stages.classify_objects.regions import (
    SHADOW,
    Surface,
    grown,
    planar_segments,
    seen_below,
    wall_shares,
)

#: The classes this stage may change: what the ground filter left (1) and took for ground (2).
CANDIDATES = (glossary.UNCLASSIFIED, glossary.GROUND)
BUILDING, LOW_VEGETATION, MEDIUM_VEGETATION, HIGH_VEGETATION, BRIDGE = 6, 3, 4, 5, 17

#: A building point stands at least this high (m) above the ground under it (the foot of a wall stays).
WALL_FOOT = 0.5

#: A wall whose roof was not seen is a face at least this long (m) of cells that are each such a wall.
FACE = 3.0
#: Walls are told from slopes on cells of at most this (m): on a sparse survey's wider cells a 2 m span is any
#: slope or tree.  So only there are lone walls looked for, and only there do decks take points the ground
#: filter called ground: on wider cells a plateau, a terrace or an embankment over an underpass has the same
#: "walls", and the ground filter's judgement stands (:data:`TERRAIN_SHARE` for roofs).
FACE_CELL = 1.0

#: On cells wider than :data:`FACE_CELL`, a planar region more than this share of whose points the ground
#: filter called ground is terrain it judged (a plateau, a terrace), not a roof: a building's roof stands
#: above the filter's surface, so at most a minority of its points (a roof wider than the filter's window)
#: are called ground.  On narrower cells its walls tell it, whatever the filter said.
TERRAIN_SHARE = 0.5

#: How far (m) around a roof's planar cells its walls and eaves may lie: its planar cells stop a cell
#: short of its edge, and on cells of a metre or less its wall's points lie in the edge cell or the one beyond.
WALLS = 2.0


#: The statistics of each cell a :class:`Surface` is made of, in its order (:func:`cell_sums`, :func:`add_sums`).
SUMS = ("top", "bottom", "count", "single", "ground_sum", "ground_count", "last_top", "last_count")


def cell_sums(size: int) -> dict[str, np.ndarray]:
    """Empty statistics of *size* cells: :data:`SUMS` as flat arrays (counts as int32: 12 bytes a cell fewer)."""
    return {
        "top": np.full(size, -np.inf),
        "bottom": np.full(size, np.inf),
        "count": np.zeros(size, np.int32),  # a cell of 2**31 points is no survey's
        "single": np.zeros(size, np.int32),
        "ground_sum": np.zeros(size),
        "ground_count": np.zeros(size, np.int32),
        "last_top": np.full(size, -np.inf),
        "last_count": np.zeros(size, np.int32),
    }


def add_sums(
    sums: dict[str, np.ndarray],
    k: np.ndarray,
    z: np.ndarray,
    single: np.ndarray,
    ground: np.ndarray,
    last: np.ndarray | None = None,
) -> None:
    """Points with flat cell indices *k* (:func:`cell_index`), heights *z*, single-return, ground and last-return
    masks (*last* None: every point is a last return), added.

    Maxima, minima and counts do not depend on the order; the ground
    points' z are added one by one (``np.add.at``), as ``np.bincount`` adds
    them: the sums of the survey in chunks (in file order) are those of the
    survey at once, bit for bit.
    """
    np.maximum.at(sums["top"], k, z)
    np.minimum.at(sums["bottom"], k, z)
    add_counts(sums["count"], k)
    add_counts(sums["single"], k[single])
    k_ground = k[ground]
    np.add.at(sums["ground_sum"], k_ground, z[ground])
    add_counts(sums["ground_count"], k_ground)
    k_last, z_last = (k, z) if last is None or last.all() else (k[last], z[last])  # no copy: one return a pulse
    np.maximum.at(sums["last_top"], k_last, z_last)
    add_counts(sums["last_count"], k_last)


def surface_of(
    grid: Grid,
    top: np.ndarray,
    bottom: np.ndarray,
    count: np.ndarray,
    single: np.ndarray,
    ground_sum: np.ndarray,
    ground_count: np.ndarray,
    last_top: np.ndarray,
    last_count: np.ndarray,
) -> Surface:
    """The :class:`Surface` of :func:`cell_sums`' grids of *grid* (its shape); *top*, *bottom* and *last_top* made
    NaN, in place, where a cell holds no point (no last return)."""
    empty = count == 0
    top[empty] = np.nan
    bottom[empty] = np.nan
    last_top[last_count == 0] = np.nan
    # a survey of one return per pulse: the last returns' surface is the surface
    last_residual = banded_residual(last_top) if (last_count != count).any() else None
    return Surface(
        grid,
        top,
        bottom,
        count,
        single.astype(np.float64),
        banded_residual(top),
        ground_sum,
        ground_count,
        last_top,
        last_count,
        last_residual,
    )


#: Rows of the grid :func:`banded_residual` computes at a time.
BAND_ROWS = 256


def banded_residual(top: np.ndarray, rows: int = BAND_ROWS) -> np.ndarray:
    """:func:`plane_residual` of *top*, *rows* rows at a time (each band read with a row on either side).

    The same values (each depends on its 3 x 3 cells only); its temporaries,
    about 200 bytes a cell, take a band's size instead of the grid's.
    """
    out = np.empty(top.shape)
    for r0 in range(0, top.shape[0], rows):
        r1 = min(r0 + rows, top.shape[0])
        a, b = max(r0 - 1, 0), min(r1 + 1, top.shape[0])
        out[r0:r1] = plane_residual(top[a:b])[r0 - a : r0 - a + r1 - r0]
    return out


def cell_index(xyz: np.ndarray, grid: Grid) -> np.ndarray:
    """The flat index (``row * cols + col``) of the cell of *grid* holding each point; negative outside."""
    row, col = cell_of(xyz, grid)
    return row * grid.cols + col


def surface(
    xyz: np.ndarray, single: np.ndarray, ground: np.ndarray, cell: float, last: np.ndarray | None = None
) -> tuple[Surface, np.ndarray]:
    """The :class:`Surface` of points *xyz* (metres) on cells of *cell* m anchored at whole multiples of it.

    *single*, *ground*, *last*: masks of the single returns, of the ground
    (2) points and of the last returns (None: every point is).  Returns the
    surface and each point's flat cell index.
    """
    lo, hi = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
    grid = Grid.covering(lo[0], lo[1], hi[0], hi[1], cell)
    k = cell_index(xyz, grid)
    sums = cell_sums(grid.rows * grid.cols)
    add_sums(sums, k, xyz[:, 2], single, ground, last)
    return surface_of(grid, **{name: a.reshape(grid.rows, grid.cols) for name, a in sums.items()}), k


def plane_residual(top: np.ndarray) -> np.ndarray:
    """RMS (m) of each cell's 3 x 3 neighbourhood of *top* about its least-squares plane.

    NaN where the cell is empty or fewer than 6 of the 9 cells hold a value.
    Each value depends only on its 9 cells: a window of the grid gives the
    same values as the whole grid.

    >>> z = np.add.outer(np.arange(4.0), 0.5 * np.arange(4.0))
    >>> float(np.nanmax(plane_residual(z))) < 1e-6
    True
    """

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


def building_cells(s: Surface, params) -> tuple[np.ndarray, np.ndarray]:
    """The cells of buildings (bool grid): roof regions passing every test of ``params`` (:class:`BuildingParams`),
    on the surface of every return and on that of the last returns; and which of them only the last returns show
    (a roof under a crown: the crown's echoes left out, the roof's are planar)."""

    roofs = _roof_cells(s, s.top, s.residual, s.count, params)
    if s.last_residual is None:  # one return per pulse: the same surface
        return roofs, np.zeros(roofs.shape, dtype=bool)
    under = _roof_cells(s, s.last_top, s.last_residual, s.last_count, params) & ~roofs
    return roofs | under, under


def _roof_cells(s: Surface, top: np.ndarray, residual: np.ndarray, count: np.ndarray, params) -> np.ndarray:
    """:func:`building_cells` on the surface *top* (its *residual* and points per cell *count*)."""

    cell = s.grid.resolution
    step = max(0.5 * params.min_height, cell)
    labels = planar_segments(top, residual, params.planarity, step)
    n = int(labels.max()) + 1
    if n == 1:
        return np.zeros(labels.shape, dtype=bool)
    area = np.bincount(labels.ravel(), minlength=n) * cell * cell
    points = np.bincount(labels.ravel(), weights=count.ravel(), minlength=n)
    singles = np.bincount(labels.ravel(), weights=s.single.ravel(), minlength=n)
    extent = np.zeros(n)
    for i, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is not None:
            extent[i] = max(box[0].stop - box[0].start, box[1].stop - box[1].start) * cell
    ok = (area >= params.min_area) & (extent <= params.max_size)
    ok &= singles >= params.single_returns * np.maximum(points, 1)
    if cell > FACE_CELL:
        ok &= np.bincount(labels.ravel(), weights=s.ground_count.ravel(), minlength=n) <= TERRAIN_SHARE * points
    ok[0] = False
    if ok.any():
        candidates = grown(np.where(ok[labels], labels, 0), top, s.bottom, step)
        bottom = seen_below(s.bottom, candidates > 0, int(np.ceil(SHADOW / cell)))
        ok &= wall_shares(candidates, top, bottom, params.min_height, n) >= params.wall_share
    return ok[labels]


def lone_walls(s: Surface, params, rings: int) -> np.ndarray:
    """Cells of walls whose roof was not seen (bool grid): a storey-high face of single returns with a void beside it.

    A cell is a wall when its three or more points span ``min_height`` or
    more and at least ``single_returns`` of them are single returns.  It
    stands alone when, within *rings* cells, no cell that is not a wall
    reaches within half ``min_height`` of its top (no roof or upper terrace
    seen) and some cell is empty (the side the scanner could not see: the
    survey's edge, or a roof in a shadow) while at least half of them hold
    points; and it is one of ``FACE`` metres of such cells joined.
    """

    span = s.top - s.bottom
    wall = (span >= params.min_height) & (s.count >= 3) & (s.single >= params.single_returns * s.count)
    if not wall.any():
        return wall
    # the (2 rings + 1)^2 cells around each wall cell, gathered for the wall cells only (a few in a hundred)
    r, c = np.nonzero(wall)
    rows, cols = wall.shape
    held = np.zeros(len(r))  # cells holding points; beyond the grid holds none and is void: a tile's grid
    void = np.zeros(len(r), dtype=bool)  # reaches its buffer's edge, one grid's the survey's
    beside = np.full(len(r), -np.inf)  # the highest top of a cell that is not a wall
    for dr in range(-rings, rings + 1):
        for dc in range(-rings, rings + 1):
            rr, cc = r + dr, c + dc
            inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
            rr, cc = np.clip(rr, 0, rows - 1), np.clip(cc, 0, cols - 1)
            occupied = inside & (s.count[rr, cc] > 0)
            held += occupied
            void |= ~occupied
            beside = np.where(occupied & ~wall[rr, cc], np.maximum(beside, s.top[rr, cc]), beside)
    # ... with at least half of the cells holding points: in a sparse survey every cell is alone among voids
    alone = void & (held >= 0.5 * (2 * rings + 1) ** 2) & ~(beside >= s.top[r, c] - 0.5 * params.min_height)
    lone = np.zeros(wall.shape, dtype=bool)
    lone[r[alone], c[alone]] = True
    # a face, not a cell
    labels, n = ndimage.label(lone, np.ones((3, 3), bool))
    cells = np.bincount(labels.ravel(), minlength=n + 1)
    cells[0] = 0
    return cells[labels] * s.grid.resolution >= FACE


def ground_under(s: Surface, away: np.ndarray, reach_cells: float) -> np.ndarray:
    """The ground height of each cell: mean of its ground points, but NaN in the cells *away*, gaps filled.

    A gap takes the value of the nearest cell with ground, up to
    *reach_cells* cells away (NaN farther).
    """
    n = np.where(away, 0, s.ground_count)
    mean = np.divide(s.ground_sum, n, out=np.full(n.shape, np.nan), where=n > 0)
    return fill_nearest(mean, max_cells=reach_cells)


@dataclass(frozen=True)
class ObjectCells:
    """Every grid of cells the point rule (:func:`point_classes`) needs, made by :func:`object_cells`.

    One boolean grid per kind of object: a detector adds its grid here,
    makes it in :func:`object_cells` and gives its points their class in
    :func:`point_classes`.
    """

    grid: Grid
    roofs: np.ndarray  # bool: the cells of buildings
    edges: np.ndarray  # bool: the roofs and the rings of cells around them (eaves, walls)
    ground: np.ndarray  # ground height (m) under each cell (NaN: no ground within max_size)
    rough: np.ndarray  # bool: vegetation cells (several returns around, or a rough or deep surface)
    decks: np.ndarray  # bool: the cells of bridge decks (:mod:`stages.classify_objects.bridges`)
    deck_top: np.ndarray  # the deck's surface at each deck cell: the median deck top of its 3 x 3 (inf: none)
    roof_top: np.ndarray  # the highest building point of a roof under a crown (inf: any height)
    eave: np.ndarray  # the highest roof top among each cell's 3 x 3 outside the roofs (NaN: none)


def vegetation_cells(s: Surface, params, multi_echo: bool) -> np.ndarray:
    """The cells where points above the ground are vegetation (bool), by *params* (:class:`VegetationParams`).

    With several returns per pulse (*multi_echo*): a share of at least
    ``multiple_returns`` of the returns of the 3 x 3 cells are of
    multiple-return pulses; else the surface is rough, or the cell's points
    span the medium-vegetation break (a crown).
    """

    if multi_echo:  # a canopy: a share of the pulses around returned more than once
        several = np.where(s.count > 0, 1.0 - s.single / np.maximum(s.count, 1), 0.0)  # a void is no canopy
        return (
            ndimage.uniform_filter(several, 3, mode="constant")
            * 9
            / np.maximum(ndimage.uniform_filter((s.count > 0).astype(float), 3, mode="constant") * 9, 1)
            >= params.multiple_returns
        )
    # single-echo sensors: a rough surface, or points seen at every height down a cell (a crown)
    return ~(s.residual <= params.roughness) | (s.top - s.bottom >= params.breaks[1])


def _deck_surface(decks: np.ndarray, top: np.ndarray) -> np.ndarray:
    """The height of the deck's surface at each deck cell: the median top of the deck cells among its 3 x 3 (inf
    elsewhere).  A railing's cell tops the deck by a metre, an approach's end cell lies below it: the median is
    the surface's."""
    out = np.full(decks.shape, np.inf)
    r, c = np.nonzero(decks)
    if len(r) == 0:
        return out
    rows, cols = decks.shape
    around = np.full((len(r), 9), np.nan)
    for i, (dr, dc) in enumerate((dr, dc) for dr in (-1, 0, 1) for dc in (-1, 0, 1)):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < rows) & (cc >= 0) & (cc < cols)
        rr, cc = rr.clip(0, rows - 1), cc.clip(0, cols - 1)
        take = inside & decks[rr, cc]
        around[take, i] = top[rr[take], cc[take]]
    out[r, c] = np.nanmedian(around, axis=1)  # the cell itself is a deck cell: never all NaN
    return out


def object_cells(s: Surface, params, multi_echo: bool = True) -> ObjectCells:
    """The cell grids of buildings, their edges, the ground and vegetation: part (a) of :func:`object_classes`.

    From the grid's statistics only (no point); *params*:
    :class:`~stages.classify_objects.params.ClassifyObjectsParams`.
    """

    cell = s.grid.resolution
    b = params.buildings
    roofs, under = building_cells(s, b) if b.enabled else (np.zeros(s.top.shape, dtype=bool),) * 2
    decks = np.zeros(s.top.shape, dtype=bool)
    if params.bridges.enabled:
        decks = deck_cells(s, params.bridges, b.min_area)
        roofs &= ~decks
    rings = max(1, round(WALLS / cell))
    edges = ndimage.binary_dilation(roofs, np.ones((3, 3), bool), iterations=rings) if roofs.any() else roofs
    if b.enabled and multi_echo and cell <= FACE_CELL:
        edges |= lone_walls(s, b, rings) & ~decks
    ground = ground_under(s, edges | decks, b.max_size / cell)
    v = params.vegetation
    rough = vegetation_cells(s, v, multi_echo) if v.enabled else np.zeros(s.top.shape, dtype=bool)
    deck_top = _deck_surface(decks, s.top)
    # a roof under a crown takes its points up to its last returns' top (the crown's above it are vegetation)
    roof_top = np.where(under & ~decks, s.last_top + b.planarity, np.inf)
    eave = ndimage.maximum_filter(np.where(roofs, s.top, -np.inf), size=3)
    eave = np.where(roofs | np.isinf(eave), np.nan, eave)
    return ObjectCells(s.grid, roofs, edges, ground, rough, decks, deck_top, roof_top, eave)


def point_classes(
    cells: ObjectCells,
    k: np.ndarray,
    classification: np.ndarray,
    z: np.ndarray,
    number_of_returns: np.ndarray,
    params,
    return_number: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """New classes of usable points, and which are building points: part (b) of :func:`object_classes`.

    Each point by its own class, height *z*, return and number of returns
    and its cell's values (*k*: flat cell indices in *cells*' grids);
    *return_number* None: of the points of several-return pulses none is
    known to be the first.
    """
    cls = np.asarray(classification, dtype=np.uint8)
    roofs, edges = np.ravel(cells.roofs)[k], np.ravel(cells.edges)[k]
    height = z - np.ravel(cells.ground)[k]
    # a roof's own cells take ground points too (a roof the filter took for ground); the cells at its edge
    # (eaves, walls) take the single returns above a wall's foot, ground too (a tree beside a wall returns
    # several times)
    candidate = np.isin(cls, CANDIDATES)
    single = np.asarray(number_of_returns) <= 1
    # ... and a pulse split at the eave: its first return at the height of the roof beside it
    first = single if return_number is None else np.asarray(return_number) <= 1
    eave = first & (
        np.abs(z - np.ravel(cells.eave)[k]) <= max(0.5 * params.buildings.min_height, cells.grid.resolution)
    )
    may = np.where(
        roofs,
        candidate & (z <= np.ravel(cells.roof_top)[k]),
        edges & candidate & ~(height < WALL_FOOT) & (single | eave),
    )
    building = may & ~(height < WALL_FOOT)  # NaN height (no ground near): the roof decides
    new = cls.copy()
    new[building] = BUILDING
    if cells.decks.any():  # the deck's points, not what lies under it: near its top
        # on cells too wide to see a wall, the deck's ground stays (FACE_CELL)
        wide = cells.grid.resolution > FACE_CELL
        on_deck = np.ravel(cells.decks)[k] & (cls == glossary.UNCLASSIFIED if wide else candidate)
        on_deck &= z >= np.ravel(cells.deck_top)[k] - 0.5 * params.bridges.clearance
        new[on_deck] = BRIDGE
        building &= ~on_deck
    v = params.vegetation
    if v.enabled:
        rough = np.ravel(cells.rough)[k] | (np.asarray(number_of_returns) > 1)
        veg = (new == glossary.UNCLASSIFIED) & rough & (height >= v.breaks[0])
        new[veg] = np.where(
            height[veg] >= v.breaks[2],
            HIGH_VEGETATION,
            np.where(height[veg] >= v.breaks[1], MEDIUM_VEGETATION, LOW_VEGETATION),
        )
    return new, building


def object_classes(
    xyz: np.ndarray,
    classification: np.ndarray,
    number_of_returns: np.ndarray,
    usable: np.ndarray,
    params,
    cell: float,
    multi_echo: bool = True,
    return_number: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """New classes of the points, and the building cells' grid mask's cell per point (True: in a building cell).

    *xyz* in metres; *usable*: the points that are neither noise nor
    withheld; *params*: :class:`~stages.classify_objects.params.ClassifyObjectsParams`;
    *cell*: the grid's cell (m); *multi_echo*: whether the survey records
    several returns per pulse (then vegetation is told by them, else by
    roughness); *return_number*: with it, roofs are also looked for on the
    surface of the last returns (under a crown; None: every point is a last
    return).  Points of class 1 or 2 may become 6 or 17 (bridge decks,
    :mod:`stages.classify_objects.bridges`); of class 1, 3, 4 or 5;
    every other class stays.  The :func:`surface` of the usable points,
    then :func:`object_cells` and :func:`point_classes`.
    """
    out = np.asarray(classification, dtype=np.uint8).copy()
    in_building = np.zeros(len(out), dtype=bool)
    if not usable.any():
        return out, in_building
    if usable.all():  # the usual case: no copy of the points
        pts, cls, nret = xyz, out, np.asarray(number_of_returns)
        rn = None if return_number is None else np.asarray(return_number)
    else:
        pts, cls, nret = xyz[usable], out[usable], np.asarray(number_of_returns)[usable]
        rn = None if return_number is None else np.asarray(return_number)[usable]
    s, k = surface(pts, nret <= 1, cls == glossary.GROUND, cell, None if rn is None else rn >= nret)
    new, building = point_classes(object_cells(s, params, multi_echo), k, cls, pts[:, 2], nret, params, rn)
    out[usable] = new
    in_building[usable] = building
    return out, in_building
