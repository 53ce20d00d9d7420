"""Bridge decks (17) on the grid of the surface: pure functions of the cells' heights.

A deck is a planar surface standing over a gap: along a row or a column
of cells, lower ground or water on both of its sides within
``max_width``; its side edges drop at least ``clearance`` within a cell
(open air under the deck, where an embankment slopes down); and, unlike
a roof, it continues level into the ground at both of its ends (its
approaches).  After Sithole, G., Vosselman, G. (2006), Bridge detection
in airborne laser scanner data, ISPRS J. Photogramm. Remote Sens. 61(1),
33-46, doi:10.1016/j.isprsjprs.2006.07.004 (a bridge is raised above the
terrain on both sides of a profile across it and joined to it along it);
departs from it in testing two profiles per cell (rows and columns) on a
grid rather than profiles of points in many directions, and in asking
for a drop at the deck's side edges.  Method and limits:
docs/stages/classify_objects.md.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from lidar.grid import step_labels
from stages.classify_objects.regions import (
    SHADOW,
    Surface,
    grown,
    neighbour_views,
    planar_segments,
    seen_below,
    wall_shares,
)

#: Cells a deck's pieces are grown along the level cells over the gap.  What parts them is a railing or a bank's
#: drop inside the 3 x 3 windows of the planarity test, so the breaks span cells, not metres (IGN pont: up to
#: 5 cells between the deck's last planar piece and its road).
REACH = 5


def _lowest_beyond(low: np.ndarray, reach: int, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """The lowest of *low* within *reach* cells before and after each cell along *axis* (the cell itself not)."""

    ahead = ndimage.minimum_filter1d(low, reach, axis=axis, origin=-(reach // 2), mode="constant", cval=np.inf)
    behind = ndimage.minimum_filter1d(low, reach, axis=axis, origin=(reach - 1) // 2, mode="constant", cval=np.inf)
    after, before = np.full(low.shape, np.inf), np.full(low.shape, np.inf)
    if axis == 0:
        after[:-1], before[1:] = ahead[1:], behind[:-1]
    else:
        after[:, :-1], before[:, 1:] = ahead[:, 1:], behind[:, :-1]
    return before, after


def over_gap(s: Surface, clearance: float, reach: int) -> np.ndarray:
    """Cells whose top stands *clearance* m or more above the foot of a drop on both sides along a row or a column.

    The foot of a drop: a cell whose lowest point lies *clearance* m or more
    below the top of one of its 8 neighbours (what lies under a deck's edge,
    where a ridge's or a hill's flanks slope down and have none).  Both sides
    are looked at within *reach* cells; empty cells do not count.
    """

    above = ndimage.maximum_filter(np.where(np.isfinite(s.top), s.top, -np.inf), size=3, mode="nearest")
    foot = np.isfinite(s.bottom) & (above >= s.bottom + clearance)
    low = np.where(foot, s.bottom, np.inf)
    gap = np.zeros(s.top.shape, dtype=bool)
    for axis in (0, 1):
        before, after = _lowest_beyond(low, reach, axis)
        gap |= (before <= s.top - clearance) & (after <= s.top - clearance)
    return gap


def approach_ends(
    labels: np.ndarray, top: np.ndarray, gap: np.ndarray, step: float, n: int, height: np.ndarray | None = None
) -> np.ndarray:
    """Per label: whether level cells outside the gap touch the region at both ends of its longer axis.

    A cell touches a region when it is one of its 8 neighbours, holds points,
    is not over a gap, and its top lies within *step* of the region's cell
    next to it.  The ends: the first and last quarter of the region's extent
    along the axis of its cells' largest spread.  *height*: the height a
    touching cell is compared at (None: its top).
    """
    height = top if height is None else height
    found_r, found_c, owners = [], [], []
    for here, there, r0, c0 in neighbour_views(labels.shape):
        lab = labels[there]
        level = (lab > 0) & (labels[here] == 0) & ~gap[here] & (np.abs(height[here] - top[there]) <= step)
        rr, cc = np.nonzero(level)
        found_r.append(rr + r0)
        found_c.append(cc + c0)
        owners.append(lab[level])
    r, c, owner = (np.concatenate(v) for v in (found_r, found_c, owners))
    cells_r, cells_c = np.nonzero(labels)
    cell_owner = labels[cells_r, cells_c]
    # each region's axis from its cells' moments (per label, one pass: not a pass over the cells per region)
    size = np.maximum(np.bincount(cell_owner, minlength=n), 1)
    mean_r = np.bincount(cell_owner, cells_r, minlength=n) / size
    mean_c = np.bincount(cell_owner, cells_c, minlength=n) / size
    dr, dc = cells_r - mean_r[cell_owner], cells_c - mean_c[cell_owner]
    var_r, var_c = np.bincount(cell_owner, dr * dr, minlength=n), np.bincount(cell_owner, dc * dc, minlength=n)
    cov = np.bincount(cell_owner, dr * dc, minlength=n)
    angle = 0.5 * np.arctan2(2.0 * cov, var_r - var_c)
    angle[(var_r == var_c) & (cov == 0)] = 0.5 * np.pi  # no direction: along the columns
    axis_r, axis_c = np.cos(angle), np.sin(angle)
    along = cells_r * axis_r[cell_owner] + cells_c * axis_c[cell_owner]
    lo, hi = np.full(n, np.inf), np.full(n, -np.inf)
    np.minimum.at(lo, cell_owner, along)
    np.maximum.at(hi, cell_owner, along)
    quarter = np.maximum((hi - lo) / 4.0, 1.0)
    ends = r * axis_r[owner] + c * axis_c[owner]
    first = np.bincount(owner, ends <= lo[owner] + quarter[owner], minlength=n) > 0
    last = np.bincount(owner, ends >= hi[owner] - quarter[owner], minlength=n) > 0
    ok = first & last
    ok[0] = False
    return ok


def _joined_along(labels: np.ndarray, top: np.ndarray, gap: np.ndarray, step: float, reach: int) -> np.ndarray:
    """The regions of *labels* grown *reach* cells into the cells over the *gap* whose top lies within *step* of
    their neighbour's (a deck is level; a tree beside it is not), then joined (8-connected, without a jump) and
    numbered afresh.

    A deck's railings or a bank's edge put a drop into some 3 x 3 windows: its planar cells break into
    pieces, and its last cells before the road are not planar.  Grown along the level cells over the gap,
    the pieces join and reach their approaches.
    """
    over = np.where(gap, top, np.nan)  # cells off the gap are never free to grow into
    out = labels
    for _ in range(reach):
        out, before = grown(out, over, over, step), out
        if np.array_equal(out, before):
            break
    return step_labels(out > 0, top, step, corners=True)


def _beside_level_land(cells: np.ndarray, top: np.ndarray, gap: np.ndarray, step: float) -> np.ndarray:
    """Which of *cells* have a side neighbour not over the *gap* whose top lies within *step* of theirs."""
    out = np.zeros(cells.shape, dtype=bool)
    land = ~gap & np.isfinite(top)
    for here, there, _, _ in neighbour_views(cells.shape, corners=False):
        with np.errstate(invalid="ignore"):
            out[here] |= cells[here] & land[there] & (np.abs(top[here] - top[there]) <= step)
    return out


def deck_cells(s: Surface, params, min_area: float) -> np.ndarray:
    """The cells of bridge decks (bool grid); *params*: :class:`~stages.classify_objects.params.BridgeParams`.

    Regions of cells over a gap (:func:`over_gap`) within ``planarity`` of
    their 3 x 3 cells' plane, joined without a jump, of *min_area* m² or
    more, whose side edges drop ``clearance`` m (at least half of the cells
    around them, :func:`wall_shares`) and that, with the pieces joined to
    them along the deck (:func:`_joined_along`), continue level into the
    ground at both ends (:func:`approach_ends`: cells not over a gap, or
    holding ground at that level); with the cells of their side edges (their neighbours over the gap that
    are not planar, unless level with a side neighbour not over it: the bank beyond an end).
    """

    cell = s.grid.resolution
    planarity = params.planarity
    step = max(0.5 * params.clearance, cell)
    gap = over_gap(s, params.clearance, max(int(np.ceil(params.max_width / cell)), 1))
    labels = planar_segments(s.top, np.where(gap, s.residual, np.nan), planarity, step)
    n = int(labels.max()) + 1
    if n == 1:
        return np.zeros(labels.shape, dtype=bool)
    area = np.bincount(labels.ravel(), minlength=n) * cell * cell
    ok = area >= min_area
    ok[0] = False
    if ok.any():
        candidates = grown(np.where(ok[labels], labels, 0), s.top, s.bottom, step)
        bottom = seen_below(s.bottom, candidates > 0, int(np.ceil(SHADOW / cell)))
        ok &= wall_shares(candidates, s.top, bottom, params.clearance, n) >= 0.5
        labels = np.where(ok[labels], labels, 0)
        # the pieces a railing or a bank's edge leaves, joined along the deck, reach its approaches
        joined = _joined_along(labels, s.top, gap, planarity, REACH)
        # an approach on an embankment, between the river and a lower road, is over a gap too: a cell holding
        # ground counts at its ground's height (a wall's cell holds ground at its foot, a deck's level)
        has_ground = s.ground_count > 0
        with np.errstate(invalid="ignore", divide="ignore"):
            height = np.where(has_ground, s.ground_sum / s.ground_count, s.top)
        reached = approach_ends(joined, s.top, gap & ~has_ground, step, int(joined.max()) + 1, height)
        region = np.zeros(n, dtype=np.int64)  # each piece's joined region (it holds all of its cells)
        region[labels[labels > 0]] = joined[labels > 0]
        ok &= reached[region]
    decks = ok[labels]
    # with their side edges (not planar: the drop is in their 3 x 3 cells), not their approaches (not over a gap)
    # nor the cells beside an approach (a bank beyond the deck's end: level with a cell not over the gap)
    edges = ndimage.binary_dilation(decks, np.ones((3, 3), bool)) & gap & ~(s.residual <= planarity)
    return decks | (edges & ~_beside_level_land(edges, s.top, gap, step))
