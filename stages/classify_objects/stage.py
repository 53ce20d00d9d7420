"""Stage ``classify_objects``: buildings (6), bridge decks (17) and vegetation (3, 4, 5) above the ground.

After ``classify_ground`` and ``classify_water``: on a grid of the surface (the highest point per
cell), roofs are planar regions with a step down (walls) along most of
their edge, large enough and of single returns
(:func:`stages.classify_objects.objects.building_cells`); their points
become 6, even those the ground filter took for ground (a roof wider than
its window), so the DTM is interpolated across the footprint.  Planar
surfaces over a gap, open beneath their sides and joined level to the
ground at both ends are bridge decks (17,
:func:`stages.classify_objects.bridges.deck_cells`).  The other
points above the ground where pulses return several times (or, in a
single-return survey, the surface is rough) become vegetation 3 / 4 / 5 by
their height above the ground; the rest stays 1.  On the
survey's grid, or tile by tile with a buffer wider than the widest
building, as the run service decides (:func:`lidar.gridrun.service.run_grid_stage`).
Method and departures: docs/stages/classify_objects.md.
"""

from __future__ import annotations

from typing import ClassVar

from lidar.clouds import cloud_info
from lidar.gridrun.service import run_grid_stage
from pipeline.stage import Stage, StageContext
from stages.classify_objects.kernel import ObjectsKernel, reach, several_returns, survey_cell
from stages.classify_objects.params import ClassifyObjectsParams


class ClassifyObjects(Stage, name="classify_objects", version="8", params=ClassifyObjectsParams):
    """buildings (6), bridge decks (17) and vegetation (3, 4, 5) above the ground."""

    inputs = ("points_water",)
    outputs: ClassVar = {"points_objects": "points.las"}
    passthrough: ClassVar = {"points_objects": "points_water"}
    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params: ClassifyObjectsParams) -> float:
        return reach(params)

    def run(self, ctx: StageContext[ClassifyObjectsParams]) -> None:
        src, dst = ctx.inputs["points_water"], ctx.outputs["points_objects"]
        cell, multi = survey_cell(ctx.params, cloud_info(src)), several_returns(src)
        kernel = ObjectsKernel(ctx.params.model_dump(mode="json"), cell, multi)
        counts = run_grid_stage(ctx, kernel, src, dst, one_grid_cells=ctx.params.one_grid_cells, what="classifying")
        ctx.metrics.update(cell_m=cell, several_returns=multi, **counts)
        ctx.log.info(
            "%d building, %d bridge-deck and %d vegetation points of %d (%d roof points taken from the ground)",
            counts["buildings"],
            counts["bridge_decks"],
            counts["low_vegetation"] + counts["medium_vegetation"] + counts["high_vegetation"],
            counts["points"],
            counts["roof_was_ground"],
        )
