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
their height above the ground; the rest stays 1.  On one grid of the
whole survey in two passes over its points when it has at most
``one_grid_cells`` cells (:mod:`stages.classify_objects.one_grid`),
else tile by tile with a buffer wider than the widest building.  Method and departures:
docs/stages/classify_objects.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from lidar.grid_windows import note_windows, run_tile_cells
from pipeline.stage import Stage, StageContext
from stages.classify_objects.object_tiles import (
    COUNTS,
    objects_columns,
    objects_tile,
    reach,
    several_returns,
    survey_cell,
)
from stages.classify_objects.one_grid import objects_one_grid
from stages.classify_objects.params import ClassifyObjectsParams


class ClassifyObjects(Stage, name="classify_objects", version="3", params=ClassifyObjectsParams):
    """buildings (6), bridge decks (17) and vegetation (3, 4, 5) above the ground."""

    inputs = ("points_water",)
    outputs: ClassVar = {"points_objects": "points.las"}
    passthrough: ClassVar = {"points_objects": "points_water"}
    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params: ClassifyObjectsParams) -> float:
        return reach(params)

    def run(self, ctx: StageContext[ClassifyObjectsParams]) -> None:
        from lidar.clouds import cloud_info
        from lidar.tile_classes import classes_by_tile

        src, dst = ctx.inputs["points_water"], ctx.outputs["points_objects"]
        cell, multi = survey_cell(ctx.params, cloud_info(src)), several_returns(src)
        results = _on_one_grid(ctx, src, dst, cell, multi)
        if results is None:
            results = classes_by_tile(
                ctx,
                src,
                dst,
                buffer=self.tile_buffer(ctx.params),
                columns=objects_columns,
                task=objects_tile,
                params={"params": ctx.params.model_dump(mode="json"), "cell": cell, "multi_echo": multi},
            )
        counts = {k: int(sum(r[k] for r in results)) for k in COUNTS}
        ctx.metrics.update(cell_m=cell, several_returns=multi, **counts)
        ctx.log.info(
            "%d building, %d bridge-deck and %d vegetation points of %d (%d roof points taken from the ground)",
            counts["buildings"],
            counts["bridge_decks"],
            counts["low_vegetation"] + counts["medium_vegetation"] + counts["high_vegetation"],
            counts["points"],
            counts["roof_was_ground"],
        )


def _on_one_grid(
    ctx: StageContext[ClassifyObjectsParams], src: Path, dst: Path, cell: float, multi: bool
) -> list[dict] | None:
    """The survey on one grid (:func:`objects_one_grid`): the counts; None when it is left to the tiles."""
    from lidar.clouds import cloud_info

    if ctx.params.one_grid_cells <= 0:
        return None
    tiles = run_tile_cells(ctx.config, reach(ctx.params), cell)
    with ctx.progress(2 * cloud_info(src).count, "classifying", unit="pt") as bar:
        whole = objects_one_grid(
            src, dst, ctx.params, cell, multi, progress=bar, executor=ctx.executor, workdir=ctx.workdir, tiles=tiles
        )
    if whole is None:
        return None
    if whole["windows"]:
        note_windows(ctx, "objects", whole, tiles, cell)
        return [whole]
    ctx.metrics["tiling"] = {
        "tiles": 1,
        "size": None,
        "buffer": 0.0,
        "executor": "one grid",
        "grid": list(whole["grid"]),
    }
    ctx.log.info("on one grid of %d x %d cells of %g m", *whole["grid"], cell)
    return [whole]
