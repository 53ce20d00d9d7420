"""Stage ``denoise``: isolated points and low outliers -> classes 18 and 7.

Runs before ground classification, which leaves these classes alone.  Points
already classified as noise or flagged withheld are not tested again.
Isolated points (judged in 3-D against the point spacing around them,
:func:`stages.denoise.outliers.isolated_points`) above the median height of their
neighbours become high noise (18), the others low noise (7).  The extended
local minimum test (low outliers, class 7,
:func:`stages.denoise.outliers.low_outliers`) is off by default: on steep
ground under canopy it takes real ground for noise.  Method and departures:
docs/stages/denoise.md.
"""

from __future__ import annotations

from typing import ClassVar

from pipeline.stage import Stage, StageContext
from stages.denoise.noise_classes import denoise_columns, denoise_tile, reach
from stages.denoise.params import DenoiseParams


class Denoise(Stage, name="denoise", version="3", params=DenoiseParams):
    """isolated points and low outliers to noise classes 18/7."""

    inputs = ("points_adjusted",)
    outputs: ClassVar = {"points_denoised": "points.las"}
    passthrough: ClassVar = {"points_denoised": "points_adjusted"}
    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params: DenoiseParams) -> float:
        return reach(params)

    def run(self, ctx: StageContext[DenoiseParams]) -> None:
        from lidar.tile_classes import classes_by_tile

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
