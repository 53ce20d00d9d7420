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

from lidar.gridrun.service import run_grid_stage
from pipeline.stage import Stage, StageContext
from stages.denoise.noise_classes import DenoiseKernel, reach
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
        kernel = DenoiseKernel(ctx.params.model_dump(mode="json"))
        src, dst = ctx.inputs["points_adjusted"], ctx.outputs["points_denoised"]
        counts = run_grid_stage(ctx, kernel, src, dst, one_grid_cells=0, what="denoising")
        ctx.metrics.update(
            points=int(counts["points"]),
            low_noise=int(counts["low"]),
            high_noise=int(counts["high"]),
            already_noise_or_withheld=int(counts["done"]),
        )
        ctx.log.info("%d low and %d high noise points of %d", counts["low"], counts["high"], counts["points"])
