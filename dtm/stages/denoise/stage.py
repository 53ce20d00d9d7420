"""Stage ``denoise``: isolated points and low outliers -> classes 18 and 7.

Runs before ground classification, which leaves these classes alone.  Points
already classified as noise or flagged withheld are not tested again.
Isolated points (judged in 3-D against the point spacing around them,
:func:`dtm.stages.denoise.outliers.isolated_points`) above the median height of their
neighbours become high noise (18), the others low noise (7).  The extended
local minimum test (low outliers, class 7) is off by default: on steep
ground under canopy it takes real ground for noise (Megaplot: 23 provider
ground points, autzen: 34); deep echoes are isolated and found by the first
test.
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field

from dtm.common import glossary
from dtm.common.tile_classes import PointTask
from dtm.stages.denoise.outliers import isolated_points, low_outliers
from pipeline.config import StrictModel
from pipeline.stage import Stage, StageContext, StageParams


class IsolatedParams(StrictModel):
    """Isolation in 3-D at the local point spacing (:func:`dtm.stages.denoise.outliers.isolated_points`)."""

    enabled: bool = Field(True, description="look for isolated points")
    neighbors: int = Field(
        2, ge=1, description="the test looks at the distance (3-D) to this nearest point (2: pairs are found too)"
    )
    spacing_neighbors: int = Field(
        8, ge=1, description="the local point spacing is the distance (plan) to this nearest point"
    )
    multiplier: float = Field(10.0, gt=0, description="isolated: farther than this many local spacings")
    min_distance: float = Field(2.0, ge=0, description="and farther than this (m): closer is never isolated")
    radius: float = Field(
        30.0, gt=0, description="distances are counted up to this (m); it bounds how far the test looks"
    )


class LowParams(StrictModel):
    """Extended local minimum test (:func:`dtm.stages.denoise.outliers.low_outliers`)."""

    enabled: bool = Field(
        False, description="look for low outliers (off: on steep ground under canopy it flags real ground)"
    )
    cell_size: float = glossary.cell_size(10.0)
    elevation_threshold: float = Field(
        2.0, gt=0, description="height gap (m) between a low outlier and the points above it in its cell"
    )


class DenoiseParams(StageParams):
    isolated: IsolatedParams = Field(default_factory=IsolatedParams, description="isolated points")
    low: LowParams = Field(default_factory=LowParams, description="low outliers (multipath, below-ground echoes)")


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
    (:func:`dtm.stages.denoise.outliers.low_outliers`, when enabled) are low noise.
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
            from scipy.spatial import cKDTree

            from dtm.common.neighbours import canonical_neighbours

            rest = points[~iso]
            high = np.ones(int(iso.sum()), dtype=bool)
            if len(rest):
                anchor = np.floor(points[:, :2].min(axis=0))  # whole metres: exact, tile or not
                tree = cKDTree(rest[:, :2] - anchor, balanced_tree=False, compact_nodes=False)
                k = min(p.spacing_neighbors, len(rest))
                dist, nb = canonical_neighbours(tree, points[iso, :2] - anchor, k, p.radius)
                found = np.isfinite(dist)
                z = np.where(found, np.append(rest[:, 2], np.nan)[nb], np.nan)
                has = found.any(axis=1)
                local = np.full(len(z), np.nan)
                local[has] = np.nanmedian(z[has], axis=1)
                high = ~has | (points[iso, 2] > local)
            out[iso] = np.where(high, glossary.HIGH_NOISE, glossary.LOW_NOISE)
    if params.low.enabled:
        low = low_outliers(points, cell_size=params.low.cell_size, elevation_threshold=params.low.elevation_threshold)
        out[low & (out == 0)] = glossary.LOW_NOISE
    return out


class Denoise(Stage):
    name = "denoise"
    version = "3"
    Params = DenoiseParams
    description = "isolated points and low outliers to noise classes 18/7"
    inputs = ("points_adjusted",)
    outputs: ClassVar = {"points_denoised": "points.las"}
    passthrough: ClassVar = {"points_denoised": "points_adjusted"}
    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params) -> float:
        return reach(params)

    def run(self, ctx: StageContext[DenoiseParams]) -> None:
        from dtm.common.tile_classes import classes_by_tile

        results = classes_by_tile(
            ctx,
            ctx.inputs["points_adjusted"],
            ctx.outputs["points_denoised"],
            buffer=self.tile_buffer(ctx.params),
            columns=denoise_columns,
            task=denoise_tile,
            params=ctx.params.model_dump(mode="json"),
        )
        counts = {k: sum(r[k] for r in results) for k in ("points", "low", "high", "done")}
        ctx.metrics.update(
            points=int(counts["points"]),
            low_noise=int(counts["low"]),
            high_noise=int(counts["high"]),
            already_noise_or_withheld=int(counts["done"]),
        )
        ctx.log.info("%d low and %d high noise points of %d", counts["low"], counts["high"], counts["points"])


def denoise_columns(chunk) -> dict[str, np.ndarray]:
    """The columns the noise tests need besides x, y, z (:func:`dtm.common.tile_points.split_cloud`)."""
    return {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }


def denoise_tile(task: PointTask) -> dict:
    """One tile of the noise tests (runs in a worker process).

    Writes ``idx`` and ``classification`` of the core points and returns counts.
    """
    from dtm.common.tile_points import read_column, read_xyz, write_result

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
    }
