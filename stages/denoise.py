"""Stage ``denoise``: isolated points and low outliers -> classes 18 and 7.

Runs before ground classification, which leaves these classes alone.  Points
already classified as noise or flagged withheld are not tested again.
Isolated points above the median height of their neighbours become high
noise (18), the others low noise (7); low outliers become low noise (7).
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field

from pipeline.config import StrictModel
from pipeline.stage import Stage, StageParams
from stages import glossary
from stages.noise import exact_mean_std, low_outliers, neighbour_distance


class IsolatedParams(StrictModel):
    """Statistical outlier test (:func:`stages.noise.isolated_points`)."""

    enabled: bool = Field(True, description="look for isolated points")
    neighbors: int = Field(8, ge=1, description="k: neighbours per point")
    multiplier: float = Field(5.0, gt=0, description="standard deviations above the mean neighbour distance")
    radius: float = Field(
        20.0, gt=0, description="neighbour distances are counted up to this (m); it bounds how far the test looks"
    )


class LowParams(StrictModel):
    """Extended local minimum test (:func:`stages.noise.low_outliers`)."""

    enabled: bool = Field(True, description="look for low outliers")
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
    """ASPRS noise class per point: 0 (not noise), 7 (low) or 18 (high)."""
    distance = None
    threshold = np.inf
    if params.isolated.enabled and len(points) > params.isolated.neighbors:
        p = params.isolated
        distance = neighbour_distance(points, neighbors=p.neighbors, radius=p.radius)
        mean, std, _ = exact_mean_std(lambda: [distance])
        threshold = mean + p.multiplier * std
    return classes_given(points, distance, threshold, params)


def classes_given(points: np.ndarray, distance, threshold: float, params: DenoiseParams) -> np.ndarray:
    """Noise classes once the isolation threshold (over the whole survey) is known.

    An isolated point (``distance > threshold``) above the median height of
    the non-isolated points among its ``neighbors`` nearest within
    ``radius`` (in plan) is high noise (18), otherwise low noise (7); one
    with no such point within ``radius`` is high noise (a bird, a cloud).
    Low outliers (:func:`stages.noise.low_outliers`) are low noise.
    """
    out = np.zeros(len(points), dtype=np.uint8)
    if len(points) == 0:
        return out
    if distance is not None:
        iso = distance > threshold
        if iso.any():
            from scipy.spatial import cKDTree

            from stages.grid.interpolate import canonical_neighbours

            rest = points[~iso]
            high = np.ones(int(iso.sum()), dtype=bool)
            if len(rest):
                anchor = np.floor(points[:, :2].min(axis=0))  # whole metres: exact, tile or not
                tree = cKDTree(rest[:, :2] - anchor, balanced_tree=False, compact_nodes=False)
                k = min(params.isolated.neighbors, len(rest))
                dist, nb = canonical_neighbours(tree, points[iso, :2] - anchor, k, params.isolated.radius)
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
    version = "2"  # 2: distances counted up to a radius, exact statistics, tiles
    Params = DenoiseParams
    description = "isolated points and low outliers to noise classes 18/7"
    inputs = ("points_adjusted",)
    outputs: ClassVar = {"points_denoised": "points.las"}
    passthrough: ClassVar = {"points_denoised": "points_adjusted"}
    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params) -> float:
        return reach(params)

    def run(self, ctx) -> None:
        from pipeline.tiling import map_largest_first
        from stages.tiles import classes_by_tile

        def between(tasks, results):
            # The isolation threshold is a statistic of the whole survey: the tiles'
            # distances (core points), summed exactly; then the tiles classify.
            threshold = np.inf
            if ctx.params.isolated.enabled:

                def parts():
                    for t in tasks:
                        yield np.load(Path(t["result"]) / "distance.npy")

                mean, std, n = exact_mean_std(parts)
                if n > ctx.params.isolated.neighbors:
                    threshold = mean + ctx.params.isolated.multiplier * std
                ctx.metrics.update(isolation_threshold_m=round(float(threshold), 4) if n else None)
            second = [{**t, "threshold": float(threshold)} for t in tasks]
            return map_largest_first(ctx, denoise_tile, second, "noise tiles")

        def columns(chunk):
            return {
                "classification": np.asarray(chunk.classification, dtype=np.uint8),
                "withheld": np.asarray(chunk.withheld, dtype=bool),
            }

        results = classes_by_tile(
            ctx,
            ctx.inputs["points_adjusted"],
            ctx.outputs["points_denoised"],
            buffer=self.tile_buffer(ctx.params),
            columns=columns,
            task=denoise_tile,
            extra={"params": ctx.params.model_dump(mode="json"), "threshold": None},
            between=between,
        )
        counts = {k: sum(r[k] for r in results) for k in ("points", "low", "high", "done")}
        ctx.metrics.update(
            points=int(counts["points"]),
            low_noise=int(counts["low"]),
            high_noise=int(counts["high"]),
            already_noise_or_withheld=int(counts["done"]),
        )
        ctx.log.info("%d low and %d high noise points of %d", counts["low"], counts["high"], counts["points"])


def denoise_tile(task: dict) -> dict:
    """One tile of the noise tests (runs in a worker process).

    Without ``task["threshold"]``: writes the neighbour distance of the core
    points (``distance.npy``) for the survey-wide statistic.  With it: writes
    ``idx`` and ``classification`` of the core points and returns counts.
    """
    from stages.tiles import read_tile, write_result

    cols = read_tile(Path(task["source"]))
    params = DenoiseParams.model_validate(task["params"])
    points = cols["xyz"]
    cls = cols["classification"].copy()
    done = np.isin(cls, (glossary.LOW_NOISE, glossary.HIGH_NOISE)) | cols["withheld"]
    todo = points[~done]
    core = cols["core"]
    distance = None
    if params.isolated.enabled:
        p = params.isolated
        distance = neighbour_distance(todo, neighbors=p.neighbors, radius=p.radius)
    if task["threshold"] is None:
        result = Path(task["result"])
        result.mkdir(parents=True, exist_ok=True)
        np.save(result / "distance.npy", distance[core[~done]] if distance is not None else np.zeros(0))
        return {"tile": task["tile"]}
    found = np.zeros(len(cls), dtype=np.uint8)
    found[~done] = classes_given(todo, distance, task["threshold"], params)
    cls[found > 0] = found[found > 0]
    write_result(Path(task["result"]), idx=cols["idx"][core], classification=cls[core])
    return {
        "tile": task["tile"],
        "points": int(core.sum()),
        "low": int((found[core] == glossary.LOW_NOISE).sum()),
        "high": int((found[core] == glossary.HIGH_NOISE).sum()),
        "done": int(done[core].sum()),
    }
