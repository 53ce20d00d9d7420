"""SMRF under dense forest canopy and on the real Megaplot survey (issue 16).

Pingel et al. (2013), doi:10.1016/j.isprsjprs.2012.12.002, check the minimum
surface for low outliers "along a separate processing fork": the mask only
removes cells from the provisional DEM.  Under a closed canopy most cells'
lowest point is a crown, so a cell that holds a ground return is a pit of the
minimum surface far deeper than the low-outlier test's 5 m per cell; emptying
those cells before the object filter leaves a canopy surface wider than the
window, which the filter keeps as ground.
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest
from scipy.interpolate import LinearNDInterpolator

from stages.classify_ground.ground_classes import classify
from stages.classify_ground.params import ClassifyGroundParams
from stages.classify_ground.smrf import smrf
from tests.shared_data import REAL

MEGAPLOT = REAL / "lidR" / "Megaplot.laz"


def _forest(seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """120 m x 120 m of 8 % slope; an 80 m x 80 m closed canopy 12-25 m up, with one ground return in ~6 cells."""
    rng = np.random.default_rng(seed)

    def terrain(x, y):
        return 200.0 + 0.08 * x + 0.03 * y

    x, y = rng.uniform(0, 120, 28_800), rng.uniform(0, 120, 28_800)  # 2 points/m2 of open ground
    under = (np.abs(x - 60) < 40) & (np.abs(y - 60) < 40)
    x, y = x[~under], y[~under]
    gx, gy = rng.uniform(20, 100, 1_100), rng.uniform(20, 100, 1_100)  # ground under the canopy
    cx, cy = rng.uniform(20, 100, 12_800), rng.uniform(20, 100, 12_800)  # crowns: 2 last returns/m2
    crown = 12.0 + 13.0 * rng.random(len(cx))
    xyz = np.vstack(
        (
            np.column_stack((x, y, terrain(x, y) + rng.normal(0, 0.03, len(x)))),
            np.column_stack((gx, gy, terrain(gx, gy) + rng.normal(0, 0.03, len(gx)))),
            np.column_stack((cx, cy, terrain(cx, cy) + crown)),
        )
    )
    ground = np.r_[np.ones(len(x) + len(gx), bool), np.zeros(len(cx), bool)]
    return xyz, ground


def test_closed_canopy_wider_than_the_window_is_not_ground():
    """Every crown point is an object and the ground under the canopy stays ground (w_max 18 m < 40 m half-width)."""
    xyz, truth = _forest()
    ground = smrf(xyz)
    assert ground[~truth].mean() < 0.005, f"{ground[~truth].sum()} of {(~truth).sum()} canopy points called ground"
    assert ground[truth].mean() > 0.99


def _hillside(seed: int) -> tuple[np.ndarray, int]:
    """100 m x 100 m of steep, curved terrain (40 % mean slope, 2 points/m2) and 12 clusters of 6 echoes 6-12 m below it."""
    rng = np.random.default_rng(seed)

    def terrain(x, y):
        return 0.4 * x + 4.0 * np.sin(x / 9.0) + 3.0 * np.cos(y / 7.0)

    x, y = rng.uniform(0, 100, 20_000), rng.uniform(0, 100, 20_000)
    parts = [np.column_stack((x, y, terrain(x, y) + rng.normal(0, 0.02, len(x))))]
    for _ in range(12):
        cx, cy = rng.uniform(10, 88, 2)
        ex, ey = rng.uniform(cx, cx + 2, 6), rng.uniform(cy, cy + 2, 6)
        parts.append(np.column_stack((ex, ey, terrain(ex, ey) - rng.uniform(6, 12, 6))))
    return np.vstack(parts), len(x)


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_pits_of_low_echoes_on_a_hillside_do_not_cast_shadows_of_objects(seed):
    """Multipath echoes in 2 m clusters, on curved 40 % slopes: they are not ground, and the ground around them
    is classified as it is without them.

    An opening lowers a cell of a slope when every window that has the cell as its lowest point holds a
    deeper cell: a pit upslope of it.  Kept in the openings (the paper's order, a single pass), the pits
    turn ground around them into objects, which the provisional DEM then fills wrongly on curved ground
    (1,901 / 3,302 / 2,509 / 595 ground points rejected for these seeds in 2026-12-01's code); their cells
    lie far below the provisional DEM, so the second pass leaves them out of the openings.  A pit's cell
    re-enters them inpainted, not at the lowest ground point it hides, so the narrow objects' floor (an
    opening of up to 3 m) can move a few points near it: 1 / 1 / 0 / 3 of 20,000 (2026-12-03), all within
    5 m of a pit, against 237 / 188 / 183 / 158 rejected without the echoes.  (Two clusters that overlap
    into a wider pit escape the low-outlier test itself, with or without the second pass: seeds 0 and 5.)
    """
    pts, n = _hillside(seed)
    with_pits = smrf(pts)
    without = smrf(pts[:n])
    assert not with_pits[n:].any()
    moved = np.flatnonzero(with_pits[:n] != without)
    pits = pts[n:, :2]
    near = [np.hypot(*(pits - pts[i, :2]).T).min() for i in moved]
    assert len(moved) <= 5 and max(near, default=0.0) < 5.0, (
        f"{(~with_pits[:n]).sum()} ground points rejected beside the pits, {(~without).sum()} without them; "
        f"{len(moved)} differ, up to {max(near, default=0.0):.1f} m from a pit"
    )


def _tin_difference(xyz: np.ndarray, ours: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Our ground's TIN minus the reference ground's TIN at 1 m cell centres, where both are defined."""
    lo, hi = np.floor(xyz[:, :2].min(axis=0)), xyz[:, :2].max(axis=0)
    cx, cy = np.meshgrid(np.arange(lo[0] + 0.5, hi[0], 1.0), np.arange(lo[1] + 0.5, hi[1], 1.0))
    at = np.column_stack((cx.ravel(), cy.ravel()))
    ours_z, ref_z = (LinearNDInterpolator(xyz[m, :2], xyz[m, 2])(at) for m in (ours, reference))
    diff = ours_z - ref_z
    return diff[np.isfinite(diff)]


def test_megaplot_dtm_matches_the_provider_ground(need_data):
    """lidR's Megaplot (dense forest, 81,590 points): the DTM from our ground points against a TIN of the
    provider's ground (class 2) at 1 m cells — RMS <= 0.25 m and no cell more than 2 m above it (issue 16;
    before the low-outlier fix: RMS 2.7 m, 20 % of the cells more than 2 m above, +13.9 m at most)."""
    need_data(MEGAPLOT, what="lidR's Megaplot.laz")
    las = laspy.read(str(MEGAPLOT))
    xyz = np.column_stack((np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)))
    reference = np.asarray(las.classification) == 2
    cls = classify(
        xyz,
        np.zeros(len(xyz), np.uint8),
        np.asarray(las.return_number),
        np.asarray(las.number_of_returns),
        np.zeros(len(xyz), bool),
        ClassifyGroundParams(),
    )
    diff = _tin_difference(xyz, cls == 2, reference)
    assert diff.size > 45_000  # the plot's 1 m cells (227 m x 234 m, less the hull's corners)
    assert np.sqrt(np.mean(diff**2)) <= 0.25
    assert diff.max() <= 2.0
