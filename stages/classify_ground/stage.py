"""Stage ``classify_ground``: split points into ground (class 2) and the rest (class 1).

The driver does the shared work; the algorithm (``algorithm.name``) is one
of the registered filters (:data:`stages.classify_ground.filters.GROUND_FILTERS`:
``smrf``, the default, Pingel et al. 2013; ``pmf``, Zhang et al. 2003;
``csf``, Zhang W. et al. 2016), a pure function on coordinates returning a
ground mask.  Noise (7, 18), withheld and, with ``keep_water``, water (9)
points keep their class; with ``last_returns``, only last or single returns
may become ground.  The run service (:func:`lidar.gridrun.service.run_grid_stage`)
runs the filter on the survey's grid where it has a grid form (SMRF), else on
tiles of points with its reach as buffer.  Method, departures from the
papers and why SMRF is the default: docs/stages/classify_ground.md.
"""

from __future__ import annotations

from typing import ClassVar

from lidar import glossary
from lidar.clouds import cloud_info
from lidar.gridrun.service import run_grid_stage
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext
from stages.classify_ground.filters import grid_cell, reach
from stages.classify_ground.ground_classes import SPARSE_SPACINGS, for_spacing, nominal_spacing
from stages.classify_ground.kernel import GroundKernel
from stages.classify_ground.params import ClassifyGroundParams


class ClassifyGround(Stage, name="classify_ground", version="9", params=ClassifyGroundParams):
    """ground / non-ground classification."""

    inputs = ("points_denoised",)
    outputs: ClassVar = {"points_classified": "points.las"}
    passthrough: ClassVar = {"points_classified": "points_denoised"}

    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params: ClassifyGroundParams) -> float:
        return reach(params.algorithm)

    def run(self, ctx: StageContext[ClassifyGroundParams]) -> None:
        src, dst = ctx.inputs["points_denoised"], ctx.outputs["points_classified"]
        spacing = nominal_spacing(src, grid_cell(ctx.params.algorithm), cloud_info(src))
        params = _for_spacing(ctx, spacing)
        counts = run_grid_stage(
            ctx, GroundKernel.of(params), src, dst, one_grid_cells=params.one_grid_cells, what="filtering"
        )
        _check_last_returns(ctx, params, counts)
        n, ground, other = counts["points"], counts["ground"], counts["non_ground"]
        ctx.metrics.update(
            algorithm=params.algorithm.model_dump(),
            nominal_spacing_m=round(spacing, 3) if spacing is not None else None,
            grid_cell_m=grid_cell(params.algorithm),
            points=int(n),
            ground=ground,
            non_ground=other,
            noise_or_withheld=int(n - ground - other),
            ground_fraction=round(ground / n, 4) if n else 0.0,
        )
        ctx.log.info("%d of %d points are ground (%.1f %%)", ground, n, 100.0 * ground / max(n, 1))


def _for_spacing(ctx: StageContext[ClassifyGroundParams], spacing: float | None) -> ClassifyGroundParams:
    """The stage's parameters, the grid cell raised to the point *spacing* of a sparse survey (with a warning)."""
    params = ctx.params
    used = for_spacing(params.algorithm, spacing)
    if used is params.algorithm:
        return params
    ctx.log.warning(
        "sparse survey: the points lie %.1f m apart, more than %g cells of %g m; %s runs on cells of %g m "
        "(windows and thresholds unchanged, in metres)",
        spacing,
        SPARSE_SPACINGS,
        grid_cell(params.algorithm),
        used.name,
        grid_cell(used),
    )
    return params.model_copy(update={"algorithm": used})


def _check_last_returns(ctx: StageContext[ClassifyGroundParams], params: ClassifyGroundParams, counts: dict) -> None:
    """Refuse a survey whose points could not be ground because none is a last return (wrong return numbers)."""
    n = counts["points"]
    if n and counts["ground"] == 0 and params.last_returns and counts["last_returns"] == 0:
        raise InputDataError(
            f"{glossary.input_names(ctx.config)}: none of its {n:,} points is a last or single return (return number = number of "
            "returns), so none can be ground; if the file's return numbers are wrong, set "
            "stages.classify_ground.last_returns: false."
        )
