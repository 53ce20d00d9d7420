"""Noise classes: the tests of :mod:`stages.denoise.outliers` as ASPRS classes, for a set of points and for a tile."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar import glossary
from lidar.tile_classes import PointTask
from stages.denoise.outliers import isolated_points, low_outliers, within_plan
from stages.denoise.params import DenoiseParams

if TYPE_CHECKING:
    import laspy


def reach(params: DenoiseParams) -> float:
    """The buffer (metres) a tile needs for results equal to untiled ones.

    A point's neighbour distance depends on the points within ``radius``;
    whether an isolated point is high or low noise, on the non-isolated
    points within ``radius`` of it, whose own test looks ``radius`` farther:
    ``2 radius``.  A low-outlier cell must be whole: ``cell_size``.
    """
    return max(2.0 * params.isolated.radius, params.low.cell_size) + 1.0


def noise_classes(points: np.ndarray, params: DenoiseParams) -> np.ndarray:
    """ASPRS noise class per point: 0 (not noise), 7 (low) or 18 (high).

    An isolated point above the median height of the non-isolated points
    among its ``spacing_neighbors`` nearest within ``radius`` (in plan) is high
    noise (18), otherwise low noise (7); one with no such point within
    ``radius`` is high noise (a bird, a cloud).  Low outliers
    (:func:`stages.denoise.outliers.low_outliers`, when enabled) are low noise.
    """
    out = np.zeros(len(points), dtype=np.uint8)
    if len(points) == 0:
        return out
    p = params.isolated
    if p.enabled:
        iso = isolated_points(
            points,
            neighbors=p.neighbors,
            spacing_neighbors=p.spacing_neighbors,
            multiplier=p.multiplier,
            min_distance=p.min_distance,
            radius=p.radius,
        )
        if iso.any():
            high = above_neighbours(points, iso, neighbors=p.spacing_neighbors, radius=p.radius)
            out[iso] = np.where(high, glossary.HIGH_NOISE, glossary.LOW_NOISE)
    if params.low.enabled:
        low = low_outliers(points, cell_size=params.low.cell_size, elevation_threshold=params.low.elevation_threshold)
        out[low & (out == 0)] = glossary.LOW_NOISE
    return out


def above_neighbours(points: np.ndarray, iso: np.ndarray, *, neighbors: int, radius: float) -> np.ndarray:
    """Whether each point of ``points[iso]`` lies above its neighbours: high noise (True) or low noise.

    Above the median height of the points not in *iso* among its *neighbors*
    nearest within *radius* (in plan, ties by index); a point with none of
    them within *radius* is above (a bird, a cloud).
    """
    from scipy.spatial import cKDTree

    from lidar.neighbours import canonical_neighbours

    anchor = np.floor(points[:, :2].min(axis=0))  # whole metres: exact, tile or not
    # only the points that may lie within radius of an isolated one, in their order (ties go the same way)
    rest = points[~iso & within_plan(points[:, :2] - anchor, np.flatnonzero(iso), radius)]
    high = np.ones(int(iso.sum()), dtype=bool)
    if len(rest):
        tree = cKDTree(rest[:, :2] - anchor, balanced_tree=False, compact_nodes=False)
        k = min(neighbors, len(rest))
        dist, nb = canonical_neighbours(tree, points[iso, :2] - anchor, k, radius)
        found = np.isfinite(dist)
        z = np.where(found, np.append(rest[:, 2], np.nan)[nb], np.nan)
        has = found.any(axis=1)
        local = np.full(len(z), np.nan)
        local[has] = np.nanmedian(z[has], axis=1)
        high = ~has | (points[iso, 2] > local)
    return high


def denoise_columns(chunk: laspy.ScaleAwarePointRecord) -> dict[str, np.ndarray]:
    """The columns the noise tests need besides x, y, z (:func:`lidar.tile_points.split_cloud`)."""
    return {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }


def denoise_tile(task: PointTask) -> dict:
    """One tile of the noise tests (runs in a worker process).

    Writes ``idx`` and ``classification`` of the core points and returns counts.
    """
    from lidar.tile_points import read_column, read_xyz, write_result

    source = Path(task.source)
    params = DenoiseParams.model_validate(task.params)
    points = read_xyz(source)  # the columns mapped and stacked: no second copy of the coordinates in memory
    cls = read_column(source, "classification")
    done = ~glossary.usable(cls, read_column(source, "withheld"))
    core = read_column(source, "core")
    idx = read_column(source, "idx")
    found = np.zeros(len(cls), dtype=np.uint8)
    if done.any():
        found[~done] = noise_classes(points[~done], params)
    else:  # no copy of the points
        found = noise_classes(points, params)
    cls[found > 0] = found[found > 0]
    write_result(Path(task.result), idx=idx[core], classification=cls[core])
    return {
        "tile": task.tile,
        "points": int(core.sum()),
        "low": int((found[core] == glossary.LOW_NOISE).sum()),
        "high": int((found[core] == glossary.HIGH_NOISE).sum()),
        "done": int(done[core].sum()),
        "changed": int((found[core] > 0).sum()),
    }
