"""Noise classes: the tests of :mod:`stages.denoise.outliers` as ASPRS classes, for a set of points and for a tile."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.spatial import cKDTree

from lidar import glossary
from lidar.gridrun.kernel import StageKernel
from lidar.neighbours import canonical_neighbours
from stages.denoise.outliers import isolated_points, low_outliers, within_plan
from stages.denoise.params import DenoiseParams


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


@dataclass(frozen=True)
class DenoiseKernel(StageKernel):
    """The noise tests for the run service (*params*: the stage's dump): on tiles of points only.

    Values: each tested point's noise class (0: not noise).
    """

    params: dict

    Params: ClassVar = DenoiseParams
    counts: ClassVar = ("points", "low", "high", "done")
    grid_form: ClassVar = False  # the tests need the points around each point

    @property
    def cell(self) -> float:
        return self.model.low.cell_size

    @property
    def reach(self) -> float:
        return reach(self.model)

    def tested(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        """Points already classified as noise or withheld are not tested again."""
        return glossary.usable(cols["classification"], cols["withheld"])

    def tile(self, xyz: np.ndarray, cols: dict[str, np.ndarray], tested: np.ndarray) -> np.ndarray:
        return noise_classes(xyz if tested.all() else xyz[tested], self.model)  # all tested: no copy of the points

    def classes(
        self, cols: dict[str, np.ndarray], tested: np.ndarray, values: np.ndarray
    ) -> tuple[np.ndarray, tuple[int, ...]]:
        cls = cols["classification"].copy()
        found = np.zeros(len(cls), dtype=np.uint8)
        found[tested] = values
        cls[found > 0] = found[found > 0]
        low, high = int((found == glossary.LOW_NOISE).sum()), int((found == glossary.HIGH_NOISE).sum())
        return cls, (len(cls), low, high, int((~tested).sum()))
