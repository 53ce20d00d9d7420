"""Stage ``denoise``: isolated points and low outliers -> classes 18 and 7.

Runs before ground classification, which leaves these classes alone.  Points
already classified as noise or flagged withheld are not tested again.
Isolated points above the median height of their neighbours become high
noise (18), the others low noise (7); low outliers become low noise (7).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np
from pydantic import Field

from pipeline.config import StrictModel
from pipeline.stage import Stage, StageParams
from stages import glossary
from stages.io import read_cloud, write_cloud, xyz_metres
from stages.noise import isolated_points, low_outliers


class IsolatedParams(StrictModel):
    """Statistical outlier test (:func:`stages.noise.isolated_points`)."""

    enabled: bool = Field(True, description="look for isolated points")
    neighbors: int = Field(8, ge=1, description="k: neighbours per point")
    multiplier: float = Field(5.0, gt=0, description="standard deviations above the mean neighbour distance")


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


def noise_classes(points: np.ndarray, params: DenoiseParams) -> np.ndarray:
    """ASPRS noise class per point: 0 (not noise), 7 (low) or 18 (high)."""
    out = np.zeros(len(points), dtype=np.uint8)
    if len(points) == 0:
        return out
    if params.isolated.enabled:
        iso = isolated_points(points, neighbors=params.isolated.neighbors, multiplier=params.isolated.multiplier)
        if iso.any() and (~iso).sum() > 0:
            from scipy.spatial import cKDTree

            rest = points[~iso]
            k = min(params.isolated.neighbors, len(rest))
            _, nb = cKDTree(rest[:, :2] - rest[:, :2].min(axis=0)).query(points[iso, :2] - rest[:, :2].min(axis=0), k=k)
            nb = np.asarray(nb).reshape(int(iso.sum()), -1)  # (m,) when k == 1
            local = np.median(rest[nb, 2], axis=1)
            out[iso] = np.where(points[iso, 2] > local, glossary.HIGH_NOISE, glossary.LOW_NOISE)
    if params.low.enabled:
        low = low_outliers(points, cell_size=params.low.cell_size, elevation_threshold=params.low.elevation_threshold)
        out[low & (out == 0)] = glossary.LOW_NOISE
    return out


class Denoise(Stage):
    name = "denoise"
    version = "1"
    Params = DenoiseParams
    description = "isolated points and low outliers to noise classes 18/7"
    inputs = ("points_adjusted",)
    outputs: ClassVar = {"points_denoised": "points.las"}
    passthrough: ClassVar = {"points_denoised": "points_adjusted"}

    def run(self, ctx) -> None:
        las = read_cloud(ctx.inputs["points_adjusted"])
        cls = np.asarray(las.classification).copy()
        done = np.isin(cls, (glossary.LOW_NOISE, glossary.HIGH_NOISE)) | np.asarray(las.withheld, dtype=bool)
        found = np.zeros(len(cls), dtype=np.uint8)
        found[~done] = noise_classes(xyz_metres(las)[0][~done], ctx.params)  # parameters are in metres
        cls[found > 0] = found[found > 0]
        las.classification = cls
        ctx.metrics.update(
            points=int(len(cls)),
            low_noise=int((found == glossary.LOW_NOISE).sum()),
            high_noise=int((found == glossary.HIGH_NOISE).sum()),
            already_noise_or_withheld=int(done.sum()),
        )
        ctx.log.info(
            "%d low and %d high noise points of %d",
            ctx.metrics["low_noise"],
            ctx.metrics["high_noise"],
            len(cls),
        )
        write_cloud(las, ctx.outputs["points_denoised"])
