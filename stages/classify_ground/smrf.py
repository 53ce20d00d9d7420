"""Simple morphological filter (SMRF) for ground points.

Pingel, T. J., Clarke, K. C., McBride, W. A. (2013).  An improved simple
morphological filter for the terrain classification of airborne LIDAR data.
ISPRS J. Photogramm. Remote Sens. 77, 21-30.
doi:10.1016/j.isprsjprs.2012.12.002

:func:`smrf` on points; :func:`provisional_dem` (the grid steps) and
:func:`point_test` apart, for the survey filtered on one grid.  The method
and our departures from the paper: docs/stages/classify_ground.md.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from pydantic import Field
from scipy import ndimage

from lidar import glossary
from pipeline.config import StrictModel
from pipeline.executor import release_freed_memory, thread_map
from stages.classify_ground.surface import (
    CellIndex,
    as_xyz,
    index_points,
    inpaint,
    min_grid,
    pad_linear,
    sample_bilinear_all,
    slope_grid,
)

#: Points tested against the provisional DEM at a time.
_BLOCK = 1 << 18
_CROSS = ndimage.generate_binary_structure(2, 1)
_SQUARE = ndimage.generate_binary_structure(2, 2)


class SmrfParams(StrictModel):
    """The parameters of :func:`smrf` (Pingel et al. 2013)."""

    name: Literal["smrf"] = Field(description="the ground algorithm: smrf")
    cell_size: float = glossary.cell_size(1.0)
    slope: float = glossary.slope(0.15)
    max_window_size: float = Field(18.0, gt=0, description="w_max: largest window radius, metres")
    elevation_threshold: float = Field(0.5, ge=0, description="et: base height threshold of the point test, metres")
    elevation_scalar: float = Field(1.25, ge=0, description="es: threshold added per unit of local DEM slope, metres")
    floor_window: float = Field(
        3.0,
        ge=0,
        description="objects flagged by an opening of radius up to this (metres) bound the provisional DEM under "
        "them by that opening (bridge decks; 0: off; docs/GROUND.md)",
    )
    wall_height: float = Field(
        2.0,
        ge=0,
        description="rise (metres) that walls in a plateau: walled plateaus wider than w_max inside the survey "
        "are objects (buildings wider than the window; 0: off; docs/GROUND.md)",
    )


def reach(params: SmrfParams) -> float:
    """How far (m) SMRF looks from a point: the buffer a tile needs.

    An opening of radius ``w_max`` reads ``2 w_max`` around a cell, and a
    gap it fills (a building, at most ``2 w_max`` wide by the parameter's
    definition) takes its values from cells that far again, so ``4 w_max``
    plus two cells for the provisional DEM; the second pass (low cells below
    that DEM left out of the openings, :func:`smrf`) opens and fills again
    around cells decided by it: ``8 w_max`` plus two cells.
    """
    return 8.0 * params.max_window_size + 2.0 * params.cell_size


def _element(step: int) -> np.ndarray:
    # Alternating a cross and a square: their Minkowski sum over r steps is
    # an octagon of radius r, a close, cheap stand-in for a disk.
    return _CROSS if step % 2 == 1 else _SQUARE


def _dilate_octagon(grid: np.ndarray, radius: int) -> np.ndarray:
    """Grey dilation by the octagon of *radius* (the sum of ``_element(1..radius)``), in a few passes.

    The octagon is the sum of ``radius // 2`` 3x3 squares, one square of side
    ``2 (radius // 2) + 1`` (two separable 1-D passes), and ``c = ceil(radius / 2)``
    crosses, a diamond of radius ``c``.  A diamond of radius ``2a + 1`` is a
    cross plus the diagonal and anti-diagonal segments of ``2a + 1`` cells
    (those two give the cells of even parity within ``2a``; the cross reaches
    the odd ones); one of radius ``2a`` is one more cross.  Cells at least
    *radius* from the grid's edge get exactly the value of the octagon's
    dilation (the callers pad the grid by the largest radius).
    """
    out = ndimage.maximum_filter(grid, size=2 * (radius // 2) + 1, mode="nearest")
    crosses = (radius + 1) // 2
    a = (crosses - 1) // 2
    if a > 0:
        out = ndimage.maximum_filter(out, footprint=np.eye(2 * a + 1, dtype=bool), mode="nearest")
        out = ndimage.maximum_filter(out, footprint=np.eye(2 * a + 1, dtype=bool)[::-1], mode="nearest")
    for _ in range(crosses - 2 * a):
        out = ndimage.grey_dilation(out, footprint=_CROSS, mode="nearest")
    return out


def progressive_filter(
    surface: np.ndarray, *, cell_size: float, slope: float, max_radius: int, threads: int = 1
) -> np.ndarray:
    """Flag cells that an opening of growing radius lowers by more than the slope allows: True for objects.

    *surface* is a filled minimum surface (no NaN); the threshold at radius
    ``r`` cells (1 to *max_radius*) is ``slope * r * cell_size`` (m).
    *threads* bands of rows are filtered at once (SciPy's filters release
    the interpreter lock); the result does not depend on it.  Departures
    from Pingel et al. (2013): the opening uses an octagon instead of a disk
    (:func:`_dilate_octagon`), and the surface is padded by continuing its
    slopes (:func:`pad_linear`), so that uphill survey edges are not taken
    for objects (docs/stages/classify_ground.md).
    """
    return object_filter(surface, cell_size=cell_size, slope=slope, max_radius=max_radius, threads=threads)[0]


def object_filter(
    surface: np.ndarray, *, cell_size: float, slope: float, max_radius: int, floor_radius: int = 0, threads: int = 1
) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`progressive_filter`, and the openings that flagged the narrow objects.

    Returns the object cells and, when *floor_radius* > 0, the *floor*: at
    each cell first flagged by an opening of radius ``r <= floor_radius``
    (cells), the value of that opening; NaN elsewhere (None when
    *floor_radius* is 0).  The other parameters are those of
    :func:`progressive_filter`; neither result depends on *threads*.
    """
    pad = max_radius
    surface = pad_linear(surface, pad)
    rows = surface.shape[0]
    # An opening of radius r reads 2 r cells around a cell (r erosions, a dilation of r), so a band of
    # rows filtered with 2 max_radius rows more on each side gives its own rows exactly.
    reach = 2 * max_radius
    bands = max(1, min(threads, rows // max(4 * reach, 64)))
    inner = np.s_[pad:-pad, pad:-pad]
    if bands == 1:
        objects, floor = _flag(surface, cell_size, slope, max_radius, floor_radius)
        return objects[inner], None if floor is None else floor[inner]
    cuts = np.linspace(0, rows, bands + 1).round().astype(int)
    spans = [(max(a - reach, 0), min(b + reach, rows), a, b) for a, b in zip(cuts[:-1], cuts[1:], strict=True)]

    parts = thread_map(lambda s: _flag(surface[s[0] : s[1]], cell_size, slope, max_radius, floor_radius), spans, bands)
    objects = np.empty(surface.shape, dtype=bool)
    floor = np.empty(surface.shape) if floor_radius > 0 else None
    for (lo, _, a, b), (part, part_floor) in zip(spans, parts, strict=True):
        objects[a:b] = part[a - lo : b - lo]
        if floor is not None:
            floor[a:b] = part_floor[a - lo : b - lo]
    # the bands were allocated in the threads' arenas: hand their pages back now they are freed
    del parts
    release_freed_memory()
    return objects[inner], None if floor is None else floor[inner]


def _flag(
    surface: np.ndarray, cell_size: float, slope: float, max_radius: int, floor_radius: int = 0
) -> tuple[np.ndarray, np.ndarray | None]:
    """The object cells of a padded surface and their floor (the loop of :func:`object_filter`)."""
    objects = np.zeros(surface.shape, dtype=bool)
    floor = np.full(surface.shape, np.nan) if floor_radius > 0 else None
    previous = surface
    eroded = surface
    for radius in range(1, max_radius + 1):
        eroded = ndimage.grey_erosion(eroded, footprint=_element(radius), mode="nearest")
        opened = _dilate_octagon(eroded, radius)
        flagged = (previous - opened) > slope * radius * cell_size
        if radius <= floor_radius:
            new = flagged & ~objects
            floor[new] = opened[new]
        objects |= flagged
        previous = opened
    return objects, floor


#: Share of a plateau's boundary (with cells that hold points) that must step down by more than the
#: wall height for :func:`walled_plateaus` to call it raised.
_WALLED_SHARE = 0.8


def walled_plateaus(zmin: np.ndarray, *, wall: float, min_width: int) -> np.ndarray:
    """The cells of wide plateaus that stand above everything around them: buildings wider than the window.

    A plateau is a group of cells with points (*zmin*: lowest *z* per cell,
    NaN where empty) joined through neighbours (4-connected) whose lowest
    points differ by at most *wall* (m).  It is walled when, along at least
    80 % of its boundary with other cells that hold points, it stands more
    than *wall* above them; it must not touch the survey's outer boundary
    (the grid's edge, or empty cells connected to it), and it must hold a
    square of ``2 min_width + 1`` cells (empty cells inside it count as its
    own).  Returns True for the cells of walled plateaus.  A departure from
    Pingel et al. (2013): docs/stages/classify_ground.md.
    """
    rows, cols = zmin.shape
    has = np.isfinite(zmin)
    if not has.any():
        return np.zeros(zmin.shape, dtype=bool)
    # Plateaus as connected components: the cells on the even rows and columns of a grid twice as fine,
    # joined through the odd cells between two neighbours whose heights differ by at most *wall*.
    # (One labelling in C, where a graph of the cells' pairs would hold two indices per pair.)
    fine = np.zeros((2 * rows - 1, 2 * cols - 1), dtype=bool)
    fine[::2, ::2] = has
    with np.errstate(invalid="ignore"):
        fine[::2, 1::2] = np.abs(np.diff(zmin, axis=1)) <= wall
        fine[1::2, ::2] = np.abs(np.diff(zmin, axis=0)) <= wall
    labels, count = ndimage.label(fine, output=np.int32)
    del fine
    label = labels[::2, ::2].copy()
    del labels
    # the outside: empty cells connected to the grid's edge, and the edge itself
    empty, _ = ndimage.label(~has, output=np.int32)
    border = np.unique(np.concatenate((empty[0], empty[-1], empty[:, 0], empty[:, -1])))
    outside = np.isin(empty, border[border > 0])
    del empty
    cut = np.zeros(count + 1, dtype=bool)
    cut[np.concatenate((label[0], label[-1], label[:, 0], label[:, -1]))] = True
    down = np.zeros(count + 1)
    total = np.zeros(count + 1)
    for a, b in (
        (np.s_[:, :-1], np.s_[:, 1:]),
        (np.s_[:, 1:], np.s_[:, :-1]),
        (np.s_[:-1, :], np.s_[1:, :]),
        (np.s_[1:, :], np.s_[:-1, :]),
    ):
        cut[label[a][outside[b]]] = True
        cross = has[a] & has[b] & (label[a] != label[b])
        total += np.bincount(label[a][cross], minlength=count + 1)
        down += np.bincount(label[a][cross], weights=zmin[a][cross] - zmin[b][cross] > wall, minlength=count + 1)
    walled = ~cut & (total > 0) & (down >= _WALLED_SHARE * total)
    walled[0] = False
    if not walled.any():
        return np.zeros(zmin.shape, dtype=bool)
    cells = walled[label]
    side = 2 * min_width + 1
    core = ndimage.minimum_filter(cells | ~has, size=side, mode="constant", cval=False) & cells
    wide = np.zeros(count + 1, dtype=bool)
    wide[label[core]] = True
    wide[0] = False
    return wide[label]


def _provisional(zmin: np.ndarray, objects: np.ndarray, floor: np.ndarray | None = None) -> np.ndarray | None:
    """The provisional DEM: the minimum surface without its object cells, inpainted; None when nothing is left.

    Where *floor* has a value (narrow objects, :func:`object_filter`), the
    DEM is the lower of the inpainted surface and the floor.
    """
    provisional = zmin.copy()
    provisional[objects] = np.nan
    if np.isnan(provisional).all():
        return None
    dem = inpaint(provisional)
    if floor is not None:
        np.fmin(dem, floor, out=dem)  # fmin: NaN (no floor) keeps the inpainted value
    return dem


#: The parameters at their defaults: the function's defaults are the configuration's.
_DEFAULT = SmrfParams(name="smrf")


def smrf(
    xyz: np.ndarray,
    *,
    cell_size: float = _DEFAULT.cell_size,
    slope: float = _DEFAULT.slope,
    max_window_size: float = _DEFAULT.max_window_size,
    elevation_threshold: float = _DEFAULT.elevation_threshold,
    elevation_scalar: float = _DEFAULT.elevation_scalar,
    floor_window: float = _DEFAULT.floor_window,
    wall_height: float = _DEFAULT.wall_height,
) -> np.ndarray:
    """Classify ground points with the simple morphological filter (SMRF): True where a point is ground.

    *xyz*: (n, 3) coordinates (m).  Pingel et al. (2013,
    doi:10.1016/j.isprsjprs.2012.12.002): the minimum surface of cells of
    *cell_size* (m) is opened with radii up to *max_window_size* (m) and a
    threshold of *slope* times the radius; the cells it lowers, and the low
    outliers, leave the provisional DEM; a point is ground within
    ``elevation_threshold + elevation_scalar * slope(DEM)`` of it.  We depart
    from the paper with a second look at the low cells, a floor under narrow
    objects (*floor_window*, m), walled plateaus as buildings (*wall_height*,
    m), octagonal openings and sloped edge padding (docs/stages/classify_ground.md).

    >>> rng = np.random.default_rng(0)
    >>> bool(smrf(np.column_stack([rng.uniform(0, 50, (2000, 2)), np.zeros(2000)])).all())
    True
    """
    xyz = as_xyz(xyz)
    if len(xyz) == 0:
        return np.zeros(0, dtype=bool)
    idx = index_points(xyz[:, :2], cell_size)
    surfaces = provisional_dem(
        min_grid(xyz[:, 2], idx),
        cell_size=cell_size,
        slope=slope,
        max_window_size=max_window_size,
        elevation_threshold=elevation_threshold,
        elevation_scalar=elevation_scalar,
        floor_window=floor_window,
        wall_height=wall_height,
    )
    if surfaces is None:
        return np.zeros(len(xyz), dtype=bool)
    return point_test(xyz, idx, *surfaces, elevation_threshold=elevation_threshold, elevation_scalar=elevation_scalar)


def provisional_dem(
    zmin: np.ndarray,
    *,
    cell_size: float,
    slope: float,
    max_window_size: float,
    elevation_threshold: float,
    elevation_scalar: float,
    floor_window: float,
    wall_height: float,
    threads: int = 1,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Steps 1-4 of :func:`smrf` on a minimum surface: the provisional DEM and its slope; None without one.

    *zmin* is the lowest *z* per cell (NaN where a cell holds no point) on
    the grid of the points' bounding box (:func:`stages.classify_ground.surface.index_points`):
    this is all of SMRF that needs no point, so a survey's grid can be
    made in one streaming pass over its points and filtered whole.
    *floor_window*, *wall_height*: see :func:`smrf`; *threads*: see :func:`progressive_filter`.
    """
    surface = inpaint(zmin)
    # Low outliers: a separate fork, as in the paper; they leave only the provisional DEM (docs/stages/classify_ground.md).
    low = progressive_filter(-surface, cell_size=cell_size, slope=5.0, max_radius=1)
    max_radius = max(1, int(math.ceil(max_window_size / cell_size)))
    filters = {
        "cell_size": cell_size,
        "slope": slope,
        "max_radius": max_radius,
        "floor_radius": min(max_radius, int(math.floor(floor_window / cell_size + 1e-9))),
        "threads": threads,
    }
    objects, floor = object_filter(surface, **filters)
    del surface
    # out of the provisional DEM whatever the openings say: the low cells, and buildings wider than the window
    left_out = low
    if wall_height > 0:
        left_out = low | walled_plateaus(zmin, wall=wall_height, min_width=(max_radius + 1) // 2)
    dem = _provisional(zmin, objects | left_out, floor)
    if dem is None:
        return None
    tolerance = elevation_threshold + elevation_scalar * slope_grid(dem, cell_size)
    deep = low & (zmin < dem - tolerance)  # empty cells (NaN) compare False: not outliers
    if deep.any():  # the low cells that are below the terrain, not below a canopy: out of the object filter too
        cleaned = zmin.copy()
        cleaned[deep] = np.nan
        objects, floor = object_filter(inpaint(cleaned), **filters)
        del cleaned
        dem = _provisional(zmin, objects | left_out, floor)
        if dem is None:  # pragma: no cover - defensive: every cell an object or low
            return None
    return dem, slope_grid(dem, cell_size)


def point_test(
    xyz: np.ndarray,
    idx: CellIndex,
    dem: np.ndarray,
    slope_dem: np.ndarray,
    *,
    elevation_threshold: float,
    elevation_scalar: float,
) -> np.ndarray:
    """Step 5 of :func:`smrf`: True where ``|z - DEM| <= et + es * slope(DEM)``, both sampled bilinearly.

    Only ``idx``'s grid (corner and cell) is used, not its points: any
    points on that grid can be tested, a chunk at a time.
    """
    ground = np.empty(len(xyz), dtype=bool)
    for a in range(0, len(xyz), _BLOCK):  # in blocks: bilinear sampling makes ten temporaries per point
        x, y, z = xyz[a : a + _BLOCK, 0], xyz[a : a + _BLOCK, 1], xyz[a : a + _BLOCK, 2]
        at, grad = sample_bilinear_all((dem, slope_dem), idx, x, y)
        ground[a : a + _BLOCK] = np.abs(z - at) <= elevation_threshold + elevation_scalar * grad
    return ground
