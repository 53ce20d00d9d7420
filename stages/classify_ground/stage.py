"""Stage ``classify_ground``: split points into ground (class 2) and the rest (class 1).

The driver does the shared work; the algorithm (``algorithm.name``) is a pure
function on coordinates returning a ground mask: ``smrf`` (default; Pingel et
al. 2013, :mod:`stages.classify_ground.smrf`), ``pmf`` (Zhang et al. 2003,
:mod:`stages.classify_ground.pmf`) or ``csf`` (Zhang W. et al. 2016,
:mod:`stages.classify_ground.csf`).  Noise (7, 18), withheld and, with
``keep_water``, water (9) points keep their class; with ``last_returns``, only
last or single returns may become ground.  SMRF filters the whole survey on
one grid when it fits (:mod:`stages.classify_ground.streaming`); otherwise
the survey is cut into tiles with the algorithm's buffer.  Method, departures
from the papers and why SMRF is the default: docs/stages/classify_ground.md,
docs/GROUND.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from lidar import glossary
from lidar.grid_windows import note_windows, run_tile_cells
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext
from stages.classify_ground.ground_classes import (
    SPARSE_SPACINGS,
    classify_columns,
    classify_tile,
    for_spacing,
    grid_cell,
    nominal_spacing,
    reach,
)
from stages.classify_ground.params import ClassifyGroundParams
from stages.classify_ground.streaming import COUNTS, smrf_one_grid


class ClassifyGround(Stage, name="classify_ground", version="8", params=ClassifyGroundParams):
    """ground / non-ground classification."""

    inputs = ("points_denoised",)
    outputs: ClassVar = {"points_classified": "points.las"}
    passthrough: ClassVar = {"points_classified": "points_denoised"}

    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params: ClassifyGroundParams) -> float:
        return reach(params.algorithm)

    def run(self, ctx: StageContext[ClassifyGroundParams]) -> None:
        from lidar.clouds import cloud_info
        from lidar.tile_classes import classes_by_tile

        src, dst = ctx.inputs["points_denoised"], ctx.outputs["points_classified"]
        spacing = nominal_spacing(src, grid_cell(ctx.params.algorithm), cloud_info(src))
        params = _for_spacing(ctx, spacing)
        results = _on_one_grid(ctx, src, dst, params)
        if results is None:
            results = classes_by_tile(
                ctx,
                src,
                dst,
                buffer=self.tile_buffer(params),
                columns=classify_columns,
                task=classify_tile,
                params=params.model_dump(mode="json"),
            )
        counts = {k: sum(r[k] for r in results) for k in COUNTS}
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


def _on_one_grid(
    ctx: StageContext[ClassifyGroundParams], src: Path, dst: Path, params: ClassifyGroundParams
) -> list[dict] | None:
    """SMRF on one grid of the whole survey (:func:`smrf_one_grid`): the counts; None when it is left to the tiles."""
    from lidar.clouds import cloud_info

    if params.algorithm.name != "smrf" or params.one_grid_cells <= 0:
        return None
    cell = grid_cell(params.algorithm)
    tiles = run_tile_cells(ctx.config, reach(params.algorithm), cell)
    with ctx.progress(2 * cloud_info(src).count, "filtering", unit="pt") as bar:
        whole = smrf_one_grid(
            src,
            dst,
            params,
            threads=ctx.workers,
            progress=bar,
            executor=ctx.executor,
            workdir=ctx.workdir,
            tiles=tiles,
        )
    if whole is None:
        return None
    if whole["windows"]:
        note_windows(ctx, "SMRF", whole, tiles, cell)
        return [whole]
    ctx.metrics["tiling"] = {  # no tile, no buffer
        "tiles": 1,
        "size": None,
        "buffer": 0.0,
        "executor": "one grid, this process",
        "grid": list(whole["grid"]),
    }
    ctx.log.info("SMRF on one grid of %d x %d cells of %g m", *whole["grid"], cell)
    return [whole]


def _check_last_returns(ctx: StageContext[ClassifyGroundParams], params: ClassifyGroundParams, counts: dict) -> None:
    """Refuse a survey whose points could not be ground because none is a last return (wrong return numbers)."""
    n = counts["points"]
    if n and counts["ground"] == 0 and params.last_returns and counts["last_returns"] == 0:
        raise InputDataError(
            f"{glossary.input_names(ctx.config)}: none of its {n:,} points is a last or single return (return number = number of "
            "returns), so none can be ground; if the file's return numbers are wrong, set "
            "stages.classify_ground.last_returns: false."
        )
