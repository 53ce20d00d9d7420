"""Stage ``classify_ground``: split points into ground (class 2) and the rest (class 1).

The driver does the shared work; the algorithm (chosen by ``algorithm.name``)
is a pure function on coordinates returning a ground mask:

- ``smrf`` (default): simple morphological filter, Pingel et al. (2013),
  :func:`dtm.stages.classify_ground.smrf.smrf`, with the published parameters;
- ``pmf``: progressive morphological filter, Zhang et al. (2003), the seed's
  reference, :func:`dtm.stages.classify_ground.pmf.pmf`;
- ``csf``: cloth simulation filter, Zhang W. et al. (2016), through the
  ``cloth-simulation-filter`` package, :func:`dtm.stages.classify_ground.csf.csf`.

Points already classified as noise (7, 18) or flagged withheld keep their
class and are not given to the algorithm; so do points the input classified
as water (9), with ``keep_water`` (default): a water surface is not bare
earth (hydro-flattening is left to breaklines).  With ``last_returns`` (default),
only last (or single) returns may become ground: first and intermediate
returns of a multi-return pulse hit something above the ground.  Why SMRF is
the default, and how each algorithm scores: docs/GROUND.md.
"""

from __future__ import annotations

from typing import ClassVar

from dtm.common import glossary
from dtm.stages.classify_ground.classes import (
    SPARSE_SPACINGS,
    classify_columns,
    classify_tile,
    for_spacing,
    grid_cell,
    nominal_spacing,
    reach,
)
from dtm.stages.classify_ground.params import ClassifyGroundParams
from dtm.stages.classify_ground.streaming import smrf_one_grid
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext


class ClassifyGround(Stage):
    name = "classify_ground"
    version = "8"
    Params = ClassifyGroundParams
    description = "ground / non-ground classification"
    inputs = ("points_denoised",)
    outputs: ClassVar = {"points_classified": "points.las"}
    passthrough: ClassVar = {"points_classified": "points_denoised"}

    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params) -> float:
        return reach(params.algorithm)

    def run(self, ctx: StageContext[ClassifyGroundParams]) -> None:
        from dtm.common.clouds import cloud_info
        from dtm.common.tile_classes import classes_by_tile

        src = ctx.inputs["points_denoised"]
        params = ctx.params
        spacing = nominal_spacing(src, grid_cell(params.algorithm), cloud_info(src))
        used = for_spacing(params.algorithm, spacing)
        if used is not params.algorithm:
            ctx.log.warning(
                "sparse survey: the points lie %.1f m apart, more than %g cells of %g m; %s runs on cells of %g m "
                "(windows and thresholds unchanged, in metres)",
                spacing,
                SPARSE_SPACINGS,
                grid_cell(params.algorithm),
                used.name,
                grid_cell(used),
            )
            params = params.model_copy(update={"algorithm": used})
        whole = None
        if params.algorithm.name == "smrf" and params.one_grid_cells > 0:
            with ctx.progress(2 * cloud_info(src).count, "filtering", unit="pt") as bar:
                whole = smrf_one_grid(
                    src,
                    ctx.outputs["points_classified"],
                    params,
                    threads=ctx.workers,
                    progress=bar,
                    executor=ctx.executor,
                    workdir=ctx.workdir,
                )
        if whole is not None:  # SMRF on one grid of the whole survey: no tile, no buffer (see smrf_one_grid)
            ctx.metrics["tiling"] = {
                "tiles": 1,
                "size": None,
                "buffer": 0.0,
                "executor": "one grid, this process",
                "grid": list(whole["grid"]),
            }
            ctx.log.info("SMRF on one grid of %d x %d cells of %g m", *whole["grid"], grid_cell(params.algorithm))
            results = [whole]
        else:
            results = classes_by_tile(
                ctx,
                src,
                ctx.outputs["points_classified"],
                buffer=self.tile_buffer(params),
                columns=classify_columns,
                task=classify_tile,
                params=params.model_dump(mode="json"),
            )
        counts = {k: sum(r[k] for r in results) for k in ("points", "ground", "non_ground", "last_returns")}
        n, ground, other = counts["points"], counts["ground"], counts["non_ground"]
        if n and ground == 0 and params.last_returns and counts["last_returns"] == 0:
            raise InputDataError(
                f"{glossary.input_names(ctx.config)}: none of its {n:,} points is a last or single return (return number = number of "
                "returns), so none can be ground; if the file's return numbers are wrong, set "
                "stages.classify_ground.last_returns: false."
            )
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
