"""Stage ``classify_water``: water (ASPRS class 9) found in the ground points and given by a polygon layer.

Runs after ``classify_ground``: level, flat bodies of ground points of a
minimum area are water (:func:`stages.classify_water.water.water_from_points`);
with ``polygons`` (a GeoPackage or shapefile in the points' CRS), points
inside them near the water level there are water too
(:func:`stages.classify_water.water.water_from_polygons`).  Water points
are never ground.  After the tiles, bodies whose banks do not rise above
them give their points' classes back; the others, one level each, go to
``water.gpkg`` (:mod:`lidar.water_bodies`), where ``rasterize``
flattens the DTM.  The run service decides how it runs
(:func:`lidar.gridrun.service.run_grid_stage`; the buffer
:func:`stages.classify_water.kernel.reach`).  Method, thresholds and where
each comes from: docs/stages/classify_water.md.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from lidar.clouds import cloud_info
from lidar.crs import horizontal_crs_matches
from lidar.gridrun.service import run_grid_stage
from lidar.vectors import read_polygons
from lidar.water_bodies import write_breaklines, write_water_bodies
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext, StageIO
from stages.classify_water.bodies import BODY_PASSES, bodies_of, ignore_near_shores, settle
from stages.classify_water.kernel import WaterKernel, reach
from stages.classify_water.params import ClassifyWaterParams


class ClassifyWater(Stage, name="classify_water", version="7", params=ClassifyWaterParams):
    """water (class 9) from the points and from polygons."""

    inputs = ("points_classified",)
    outputs: ClassVar = {"points_water": "points.las", "water_bodies": "water.gpkg", "breaklines": "breaklines.gpkg"}
    products: ClassVar = {"water_bodies": "water.gpkg", "breaklines": "breaklines.gpkg"}
    passthrough: ClassVar = {"points_water": "points_classified"}
    config_keys = ("tiling.buffer",)

    def declare(self, params: ClassifyWaterParams, config: BaseModel) -> StageIO:
        if params.bodies.enabled:
            return StageIO(tuple(self.inputs), dict(self.outputs), dict(self.products))
        return StageIO(tuple(self.inputs), {"points_water": "points.las"}, {})

    def tile_buffer(self, params: ClassifyWaterParams) -> float:
        return reach(params)

    def external_files(self, params: ClassifyWaterParams, config: BaseModel) -> list[Path]:
        return layer_files(params.polygons) if params.polygons is not None else []

    def run(self, ctx: StageContext[ClassifyWaterParams]) -> None:
        src = ctx.inputs["points_classified"]
        polygons = _polygon_params(ctx, src) if ctx.params.polygons is not None else {}
        kernel = WaterKernel(ctx.params.model_dump(mode="json"), **polygons)
        counts = run_grid_stage(
            ctx, kernel, src, ctx.outputs["points_water"], one_grid_cells=ctx.params.one_grid_cells, what="water"
        )
        _survey_steps(ctx, src, counts)
        ctx.metrics.update(counts)
        ctx.log.info(
            "%d of %d points became water (%d found in the points, %d from the polygons; %d were ground); "
            "the input's own water (class 9) stays and is not counted",
            counts["water"],
            counts["points"],
            counts["from_points"],
            counts["from_polygons"],
            counts["ground_to_water"],
        )


def _survey_steps(ctx: StageContext[ClassifyWaterParams], src: Path, counts: dict) -> None:
    """The water bodies of the whole survey: those whose banks do not rise given back, the others to water.gpkg."""

    dst = ctx.outputs["points_water"]
    info = cloud_info(dst)
    with ctx.progress(
        BODY_PASSES * info.count, f"water bodies, up to {BODY_PASSES} passes over the points", "pt"
    ) as bar:
        bodies, refused, grown = bodies_of(dst, info.units, ctx.params, bar.update)
    back = ground = unseen = 0
    if refused.mask.any() or np.isfinite(grown.level).any():
        polygons = _polygons_in_metres(ctx.params, info.units)
        with ctx.progress(info.count, "refused water given back, water seen through dropouts", unit="pt") as bar:
            back, ground, unseen = settle(src, dst, refused, grown, info.units, polygons, bar.update)
    if refused.mask.any():
        ctx.log.info("%d water points given their class back: their body's banks do not rise above it", back)
    if unseen:
        ctx.log.info(
            "%d ground points became water: at the level of a body seen through dropouts, within %g m (or its "
            "waves' reach), beside it",
            unseen,
            ctx.params.detect.tolerance,
        )
    counts.update(
        water=counts["water"] - back + unseen,
        from_points=counts["from_points"] - back + unseen,
        ground_to_water=counts["ground_to_water"] - ground + unseen,
        given_back=back,
        unseen_water=unseen,
    )
    if "water_bodies" in ctx.outputs:
        write_water_bodies(ctx.outputs["water_bodies"], bodies, crs=info.crs, units=info.units)
    if "breaklines" in ctx.outputs:
        write_breaklines(ctx.outputs["breaklines"], bodies, crs=info.crs, units=info.units)
        flat = [b for b in bodies if b.flat]
        with ctx.progress(info.count, "ignored ground near the shores", unit="pt") as bar:
            counts["ignored_ground"] = ignore_near_shores(
                dst, flat, ctx.params.bodies.ignored_ground, info.units, bar.update
            )
        ctx.metrics["bodies"] = {
            "polygons": len(bodies),
            "flattened": len(flat),
            "refused_cells": int(refused.mask.sum()),
            "area_m2": round(sum(b.area for b in bodies), 1),
            "levels_m": sorted({round(b.level, 3) for b in flat}),
        }


def _polygons_in_metres(params: ClassifyWaterParams, units) -> list | None:

    if params.polygons is None:
        return None
    return [[ring * units.horizontal for ring in rings] for rings in read_polygons(params.polygons)[0]]


def _polygon_params(ctx: StageContext[ClassifyWaterParams], src: Path) -> dict:
    """The polygons' scale to metres and digest for the tiles, once their layer is read and its CRS checked."""

    path = ctx.params.polygons
    try:
        polygons, crs = read_polygons(path)
    except ValueError as exc:
        raise InputDataError(f"stages.classify_water.polygons: {path}: {exc}.") from None
    info = cloud_info(src)
    match = horizontal_crs_matches(crs, info.crs)
    if match is not None:
        raise InputDataError(f"stages.classify_water.polygons: {path}: {match}.")
    ctx.log.info("%d water polygons from %s", len(polygons), Path(path).name)
    digest = hashlib.sha256(b"".join(f.read_bytes() for f in layer_files(path))).hexdigest()
    return {"polygon_scale": info.units.horizontal, "polygons_sha256": digest}


def layer_files(path: Path) -> list[Path]:
    """The files of a vector layer: a shapefile's siblings (.shx, .dbf, .prj, .cpg) with it, else the one file."""
    path = Path(path)
    if path.suffix.lower() != ".shp":
        return [path]
    return [path] + [s for s in (path.with_suffix(e) for e in (".shx", ".dbf", ".prj", ".cpg")) if s.is_file()]
