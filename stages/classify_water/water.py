"""Water (ASPRS class 9) from the ground points: level, flat surfaces grown into bodies of a minimum area.

A still water surface is level, so the ground points over it fit a horizontal
plane to the range noise of the scanner; land rarely does over several
metres.  Following the geometric criterion of Song & Jung (2023, "connected
surface water remains flat", doi:10.48550/arXiv.2301.06567), with the height
and neighbourhood features of Brzank et al. (2008, doi:10.1016/j.isprsjprs.2008.02.002)
and the region growing of Höfle et al. (2009, doi:10.1002/esp.1853):

1. per cell of ``cell_size``, a plane is fitted to the ground points of the
   square window of cells within ``window`` (:func:`window_planes`);
2. a cell is *level* when its window holds ``min_points``, spreads in both
   directions, and its plane is flatter than ``max_slope`` with an RMS under
   ``max_rms`` (:func:`level_cells`);
3. level cells that touch (8 neighbours) with heights (their planes' at the
   cell's centre) within ``step`` form a body; bodies of ``min_area`` or more are water (:func:`water_bodies`);
4. points within ``tolerance`` of the level of a water cell, in it or within
   ``grow`` of it, become water (:func:`water_points`).

A fifth step, the banks of each body (water lies below them), needs whole
bodies and runs after the tiles (:mod:`stages.classify_water.bodies`).
Departures (docs/stages/classify_water.md): no intensity and no dropout
model (both tried on lidR's Topography.laz: water returns there are bright,
near-nadir specular echoes); cells instead of points; one pass of growth.
Every grid is anchored on whole multiples of its cell, so tiles give the
results of the whole survey when their buffer covers :func:`reach`.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import ndimage

from lidar import glossary
from lidar.grid import step_labels

#: Classes a point may have to become water: never classified, unclassified, ground.
CANDIDATES = (0, glossary.UNCLASSIFIED, glossary.GROUND)


def reach(cell_size: float, window: float, min_area: float, grow: float) -> float:
    """The buffer (m) a tile needs for the classes of its core points to equal the untiled ones.

    A core point looks ``grow`` far; a cell's plane, ``window`` plus a cell
    farther (a cell cut by the tile's edge); a body is kept when its area
    reaches ``min_area``, and a body that leaves the exact part of the tile
    holds a path of at least ``min_area / cell_size`` metres of cells, so
    it is kept both ways.
    """
    return grow + window + 2.0 * cell_size + min_area / cell_size + 1.0


def cells_of(xy: np.ndarray, cell: float) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """Each point's cell ``(col, row)`` on a grid anchored at whole multiples of *cell*, from the first occupied one.

    Returns ``(i, j, shape)``; the cell of a point is ``floor(x / cell)``,
    whatever the extent of the points given.  The indices are int32 when
    the grid's flat index ``i * shape[1] + j`` fits in it, else int64.
    """
    xy = np.asarray(xy, dtype=np.float64)
    if len(xy) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), (0, 0)
    out, shape = [], []
    for axis in range(2):  # one column at a time: no (n, 2) temporaries (a tile's largest)
        index = np.floor(xy[:, axis] / cell)
        index -= index.min()  # whole numbers: exact
        out.append(index)
        shape.append(int(index.max()) + 1)
    kind = np.int32 if shape[0] * shape[1] < 2**31 else np.int64  # a flat cell index fits: half the memory
    return out[0].astype(kind), out[1].astype(kind), (shape[0], shape[1])


def window_planes(
    i: np.ndarray, j: np.ndarray, shape: tuple[int, int], xy: np.ndarray, z: np.ndarray, cell: float, half: int
) -> dict[str, np.ndarray]:
    """Least-squares planes through the points of each cell's window of ``(2 half + 1)**2`` cells.

    *i*, *j*: each point's cell (:func:`cells_of`); *xy*, *z*: its position.
    Returns :func:`planes_of` the points' :func:`cell_moments`.
    """
    k = i * shape[1] + j
    # the arguments, often the caller's temporaries (a tile's ground points: 110 MB of 3.4 M), not held
    # through the window sums
    del i, j
    low = lowest(k, z, shape[0] * shape[1])
    m = cell_moments(k, xy, z, low, shape, cell)
    del k, xy, z
    return planes_of(m, low.reshape(shape), cell, half)


def lowest(k: np.ndarray, z: np.ndarray, size: int) -> np.ndarray:
    """The lowest *z* of each of *size* cells (flat cell indices *k*); inf where a cell holds none."""
    low = np.full(size, np.inf)
    np.minimum.at(low, k, z)
    return low


def cell_moments(
    k: np.ndarray, xy: np.ndarray, z: np.ndarray, low: np.ndarray, shape: tuple[int, int], cell: float
) -> dict[str, np.ndarray]:
    """Per cell (flat index *k* of each point), the count and the sums of x, y, z and their products.

    Each point's x, y is taken about its cell's centre and its z above the
    whole metre below its cell's lowest point (*low*, :func:`lowest`): the
    same in every tile, and no large numbers.
    """
    u, v = (in_cell(xy[:, axis], cell) for axis in range(2))  # position in its cell: the same in every tile
    base = np.floor(np.where(np.isfinite(low), low, 0.0))  # whole metres: exact differences
    r = base[k]
    np.subtract(z, r, out=r)
    return _cell_moments(k, u, v, r, shape)


def planes_of(m: dict[str, np.ndarray], low: np.ndarray, cell: float, half: int) -> dict[str, np.ndarray]:
    """The planes of each cell's window from the cells' moments *m* (:func:`cell_moments`) and lowest points *low*.

    Returns per cell ``count`` (points in the cell), ``window`` (in its
    window), ``mean`` (the window plane's height at the cell's centre), ``slope``
    (rise over run of the plane), ``rms`` (m, of the points about it) and
    ``spread`` (m, the standard deviation of the window's points along their
    narrowest direction); NaN where the window has fewer than 3 points.
    Moments are summed per cell about the cell's centre and the whole metre
    below its lowest point, then over the window in two passes
    (:func:`_window_pass`, along y then x) about the window's centre cell:
    no large numbers cancel, and a cell's figures depend only on its window.
    """

    held = np.isfinite(low)
    base = np.floor(np.where(held, low, 0.0))
    # The window's sums in two passes, along y then x: 2 (2 half + 1) shifted sums a cell, not (2 half + 1)**2.
    # Each pass moves its sums to a height of its own, the highest base within its reach (whole metres of the
    # terrain there): no large numbers cancel, and a cell's figures still depend only on its window, summed
    # in the same order in every tile.
    side = 2 * half + 1
    top = np.where(held, base, -np.inf)
    row_top = ndimage.maximum_filter1d(top, side, axis=1, mode="constant", cval=-np.inf)
    win_top = ndimage.maximum_filter1d(row_top, side, axis=0, mode="constant", cval=-np.inf)
    row_top, win_top = (np.where(np.isfinite(t), t, 0.0) for t in (row_top, win_top))
    w = _window_pass(_window_pass(m, base, row_top, half, cell, "y"), row_top, win_top, half, cell, "x")
    with np.errstate(invalid="ignore", divide="ignore"):
        cnt = np.where(w["n"] >= 3, w["n"], np.nan)
        mx, my, mz = w["x"] / cnt, w["y"] / cnt, w["z"] / cnt
        cxx, cyy, cxy = w["xx"] / cnt - mx * mx, w["yy"] / cnt - my * my, w["xy"] / cnt - mx * my
        cxz, cyz, czz = w["xz"] / cnt - mx * mz, w["yz"] / cnt - my * mz, w["zz"] / cnt - mz * mz
        det = cxx * cyy - cxy * cxy
        sa = (cxz * cyy - cyz * cxy) / det
        sb = (cyz * cxx - cxz * cxy) / det
        var = czz - sa * cxz - sb * cyz
        tr = cxx + cyy
        narrow = 0.5 * (tr - np.sqrt(np.maximum(tr * tr - 4.0 * det, 0.0)))
        centre = win_top + mz - sa * mx - sb * my
    return {
        "count": m["n"],
        "window": w["n"],
        "mean": centre,
        "slope": np.hypot(sa, sb),
        "rms": np.sqrt(np.maximum(var, 0.0)),
        "spread": np.sqrt(np.maximum(narrow, 0.0)),
    }


def _cell_moments(k: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray, shape) -> dict[str, np.ndarray]:
    """Per cell (flat index *k* of each point), the count and the sums of x, y, z and their products (u, v, r)."""
    size = shape[0] * shape[1]

    def per_cell(w=None):
        return np.bincount(k, weights=w, minlength=size).reshape(shape)

    m = {"n": per_cell(), "x": per_cell(u), "y": per_cell(v), "z": per_cell(r), "xx": per_cell(u * u)}
    m.update(yy=per_cell(v * v), xy=per_cell(u * v), xz=per_cell(u * r), yz=per_cell(v * r), zz=per_cell(r * r))
    return m


def in_cell(x: np.ndarray, cell: float) -> np.ndarray:
    """``x - (floor(x / cell) + 0.5) * cell``, one temporary array instead of four (a tile's largest)."""
    t = x / cell
    np.floor(t, out=t)
    t += 0.5
    t *= cell
    np.subtract(x, t, out=t)
    return t


def _window_pass(
    m: dict[str, np.ndarray], ref: np.ndarray, to: np.ndarray, half: int, cell: float, along: str
) -> dict[str, np.ndarray]:
    """Sums of the moments *m* (about heights *ref*) over the ``2 half + 1`` cells along *along*, about heights *to*.

    Each neighbour's moments move by its offset along *along* (``x``: the
    grid's first axis, ``y``: its second) and by the step from its height
    to the cell's; a moment of a neighbour beyond the grid is zero.
    """
    axis, p, q = (0, "x", "y") if along == "x" else (1, "y", "x")
    pq = "xy"
    pad = [(0, 0), (0, 0)]
    pad[axis] = (half, half)
    padded = {name: np.pad(a, pad) for name, a in m.items()}
    ref = np.pad(ref, pad)
    out = {name: np.zeros_like(to) for name in m}
    length = to.shape[axis]
    for o in range(-half, half + 1):
        cut = [slice(None), slice(None)]
        cut[axis] = slice(half + o, half + o + length)
        s = {name: a[tuple(cut)] for name, a in padded.items()}
        d = ref[tuple(cut)] - to  # the neighbour's height above the cell's
        t = o * cell
        dn = d * s["n"]
        out["n"] += s["n"]
        out[p] += s[p] + t * s["n"]
        out[q] += s[q]
        out["z"] += s["z"] + dn
        out[p + p] += s[p + p] + 2 * t * s[p] + t * t * s["n"]
        out[q + q] += s[q + q]
        out[pq] += s[pq] + t * s[q]
        out[p + "z"] += s[p + "z"] + d * s[p] + t * s["z"] + t * dn
        out[q + "z"] += s[q + "z"] + d * s[q]
        out["zz"] += s["zz"] + 2 * d * s["z"] + d * dn
    return out


#: Rows of a grid :func:`level_and_mean` fits at a time (each band read with the window's reach of rows either side).
BAND_ROWS = 256


def level_and_mean(
    m: dict[str, np.ndarray],
    low: np.ndarray,
    *,
    cell: float,
    half: int,
    min_points: int,
    max_slope: float,
    max_rms: float,
    rows: int = BAND_ROWS,
) -> tuple[np.ndarray, np.ndarray]:
    """The level cells (:func:`level_cells`) and each cell's height (its plane's), from the cells' moments *m* and
    lowest *low*.

    :func:`planes_of` *rows* rows at a time, each band read with *half*
    rows on either side: the same values (a cell's planes depend on its
    window only, summed in the same order), with a band's temporaries (about
    300 bytes a cell) instead of the grid's.
    """
    shape = low.shape
    level, mean = np.zeros(shape, dtype=bool), np.full(shape, np.nan)
    for r0 in range(0, shape[0], rows):
        r1 = min(r0 + rows, shape[0])
        a, b = max(r0 - half, 0), min(r1 + half, shape[0])
        planes = planes_of({name: v[a:b] for name, v in m.items()}, low[a:b], cell, half)
        own = slice(r0 - a, r1 - a)
        level[r0:r1] = level_cells(
            {name: v[own] for name, v in planes.items()},
            cell=cell,
            min_points=min_points,
            max_slope=max_slope,
            max_rms=max_rms,
        )
        mean[r0:r1] = planes["mean"][own]
    return level, mean


def could_be_level(
    i: np.ndarray, j: np.ndarray, shape: tuple[int, int], half: int, min_points: int, min_cells: float
) -> bool:
    """Whether *min_cells* cells or more have *min_points* ground points (at cells *i*, *j*) or more in their
    window of ``(2 half + 1)**2`` cells: the most :func:`level_cells` could find (:func:`could_hold_level`)."""
    count = np.bincount(i * shape[1] + j, minlength=shape[0] * shape[1]).reshape(shape)
    return could_hold_level(count, half, min_points, min_cells)


def could_hold_level(count: np.ndarray, half: int, min_points: int, min_cells: float) -> bool:
    """Whether *min_cells* cells or more of the grid of ground points per cell *count* have *min_points* or more in
    their window (a cell need not hold one: water returns few echoes) of ``(2 half + 1)**2`` cells.  When not, no body can reach its area and the planes are not fitted
    (a sparse survey: milliseconds, not seconds).
    """

    count = count.astype(np.float64)
    side = 2 * half + 1
    window = ndimage.uniform_filter(count, side, mode="constant") * side * side
    return int(np.count_nonzero(window >= min_points - 0.5)) >= min_cells


def level_cells(
    planes: dict[str, np.ndarray], *, cell: float, min_points: int, max_slope: float, max_rms: float
) -> np.ndarray:
    """Cells whose window's plane is level and tight: candidates for water (:func:`window_planes`'s figures).

    The window's points must spread at least half a cell across their
    narrowest direction (a single scan line fits any plane).  The cell
    itself need not hold a point: water returns few echoes, so a level
    window over a dropout is level water.
    """
    with np.errstate(invalid="ignore"):
        return (
            (planes["window"] >= min_points)
            & (planes["spread"] >= 0.5 * cell)
            & (planes["slope"] <= max_slope)
            & (planes["rms"] <= max_rms)
        )


def water_bodies(level: np.ndarray, mean: np.ndarray, *, step: float, min_cells: float) -> np.ndarray:
    """Level cells joined into bodies (8 neighbours, heights *mean* within *step*); those of *min_cells* or more.

    Returns a boolean grid: the cells of the bodies kept.
    """

    label = step_labels(level, mean, step)
    size = np.bincount(label[level], minlength=label.max() + 1)
    return level & (size[label] >= min_cells)


def near_level(
    i: np.ndarray, j: np.ndarray, z: np.ndarray, cells: np.ndarray, mean: np.ndarray, reach_cells: int, tolerance: float
) -> np.ndarray:
    """Points within *tolerance* of the height *mean* of a cell of *cells* within *reach_cells* (Chebyshev) of theirs."""
    out = np.zeros(len(z), dtype=bool)
    if not cells.any():
        return out
    levels = np.pad(np.where(cells, mean, np.nan), reach_cells, constant_values=np.nan)
    for a in range(-reach_cells, reach_cells + 1):
        for b in range(-reach_cells, reach_cells + 1):
            lv = levels[i + reach_cells + a, j + reach_cells + b]
            with np.errstate(invalid="ignore"):
                out |= np.abs(z - lv) <= tolerance
    return out


def water_from_points(
    xyz: np.ndarray,
    classification: np.ndarray,
    usable: np.ndarray,
    *,
    cell_size: float,
    window: float,
    min_points: int,
    max_slope: float,
    max_rms: float,
    step: float,
    min_area: float,
    grow: float,
    tolerance: float,
) -> np.ndarray:
    """Which points are water: level bodies of ground found in the points (module docstring, steps 1-4).

    *xyz* in metres; *classification* after ground classification (its class
    2 points are the low envelope the planes are fitted to); *usable*: not
    withheld.  Only points of :data:`CANDIDATES` may become water.
    """
    found = np.zeros(len(xyz), dtype=bool)
    ground = usable & (classification == glossary.GROUND)
    if ground.sum() < 3:
        return found
    i, j, shape = cells_of(xyz[:, :2], cell_size)
    half = max(1, math.ceil(window / cell_size - 1e-9))
    g = np.flatnonzero(ground)
    if not could_be_level(i[g], j[g], shape, half, min_points, min_area / cell_size**2):
        return found
    k = i[g] * shape[1] + j[g]
    low = lowest(k, xyz[g, 2], shape[0] * shape[1])
    m = cell_moments(k, xyz[g, :2], xyz[g, 2], low, shape, cell_size)
    del k, g
    level, mean = level_and_mean(
        m, low.reshape(shape), cell=cell_size, half=half, min_points=min_points, max_slope=max_slope, max_rms=max_rms
    )
    del m
    water = water_bodies(level, mean, step=step, min_cells=min_area / cell_size**2)
    candidate = usable & np.isin(classification, CANDIDATES)
    c = np.flatnonzero(candidate)
    grow_cells = math.ceil(grow / cell_size - 1e-9)
    found[c] = near_level(i[c], j[c], xyz[c, 2], water, mean, grow_cells, tolerance)
    return found


def inside_polygons(xy: np.ndarray, polygons: list[list[np.ndarray]]) -> np.ndarray:
    """Which points lie inside a polygon (its outer ring, not in one of its holes); rings as (n, 2) arrays."""
    # lazy: Matplotlib takes about 0.15 s to import, in every run; only a water polygon layer needs it
    from matplotlib.path import Path

    out = np.zeros(len(xy), dtype=bool)
    for rings in polygons:
        lo, hi = rings[0].min(axis=0), rings[0].max(axis=0)
        near = np.flatnonzero(np.all((xy >= lo) & (xy <= hi), axis=1) & ~out)
        if len(near) == 0:
            continue
        inside = Path(rings[0]).contains_points(xy[near])
        for hole in rings[1:]:
            inside &= ~Path(hole).contains_points(xy[near])
        out[near[inside]] = True
    return out


def water_from_polygons(
    xyz: np.ndarray,
    classification: np.ndarray,
    usable: np.ndarray,
    inside: np.ndarray,
    *,
    cell_size: float,
    window: float,
    height: float,
) -> np.ndarray:
    """Which points inside the water polygons lie within *height* of the water level there.

    The water level at a point is the lowest mean height of the ground
    points inside the polygons, per cell of *cell_size*, among the cells
    within *window* of its own: water is the low envelope of what a
    polygon holds (its banks rise above it).  Only points of
    :data:`CANDIDATES` inside the polygons may become water.
    """
    found = np.zeros(len(xyz), dtype=bool)
    ground = usable & inside & (classification == glossary.GROUND)
    if not ground.any():
        return found
    i, j, shape = cells_of(xyz[:, :2], cell_size)
    g = np.flatnonzero(ground)
    k = i[g] * shape[1] + j[g]
    n = np.bincount(k, minlength=shape[0] * shape[1]).reshape(shape)
    total = np.bincount(k, weights=xyz[g, 2], minlength=shape[0] * shape[1]).reshape(shape)
    mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    half = math.ceil(window / cell_size - 1e-9)
    padded = np.pad(mean, half, constant_values=np.nan)
    level = np.full(shape, np.nan)
    for a in range(2 * half + 1):
        for b in range(2 * half + 1):
            level = np.fmin(level, padded[a : a + shape[0], b : b + shape[1]])
    c = np.flatnonzero(usable & inside & np.isin(classification, CANDIDATES))
    with np.errstate(invalid="ignore"):
        found[c] = np.abs(xyz[c, 2] - level[i[c], j[c]]) <= height
    return found
