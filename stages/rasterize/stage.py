"""Stage ``rasterize``: the elevation rasters of the survey.

``dtm.tif`` (bare earth from the ground and water points, classes 2 and 9, by ``method``: ``tin``,
``idw`` or ``nearest``), ``dsm.tif`` (the highest non-noise return per
cell), ``ndsm.tif`` (DSM - DTM, at least 0), ``density.tif`` (points per
cell) and, when the points carry ``sigma_vertical``, ``dtm_uncertainty.tif``.
The grid covers all usable points, cell-aligned to multiples of
``resolution``; the rasters are Cloud Optimized GeoTIFF, float32, nodata
-999999 under a USGS LBS specification (else -9999; ``nodata``), in the CRS's units (parameters in metres; :mod:`lidar.units`).
The survey is rasterized tile by tile (:mod:`stages.rasterize.tile_rasters`),
each tile's cells bit for bit those of an untiled run.  Each raster in
detail: docs/stages/rasterize.md.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from lidar import glossary
from lidar.clouds import cloud_info
from lidar.crs import HEIGHTS_KEYS, heights_of_run, state_heights
from lidar.grid import Grid, check_grid_size
from lidar.rasters import VERTICAL_DATUM, dem_nodata, read_raster
from lidar.tile_points import cleanup, split_cloud, task_folder
from lidar.water_bodies import read_breaklines, read_water_bodies
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext, StageIO
from pipeline.tiling import run_tiled
from stages.rasterize.kept_tiles import MEMO
from stages.rasterize.outline import survey_outline
from stages.rasterize.params import RasterizeParams
from stages.rasterize.products import survey_figures
from stages.rasterize.tile_rasters import (
    RASTERS,
    RasterTask,
    Usable,
    check_tile_memory,
    has_decks,
    mosaic_jobs,
    mosaic_raster,
    raster_columns,
    raster_tasks,
    rasterize_tile,
    reach,
    tile_windows,
)

if TYPE_CHECKING:
    from pydantic import BaseModel

    from lidar.clouds import CloudInfo
    from lidar.units import Units
    from pipeline.tiling import Layout


class Rasterize(Stage, name="rasterize", version="14", params=RasterizeParams):
    """DTM, DSM, nDSM and density rasters."""

    inputs = ("points_objects",)
    outputs: ClassVar = {"dtm": "dtm.tif", "dsm": "dsm.tif", "ndsm": "ndsm.tif", "density": "density.tif"}
    products: ClassVar = {"dtm": "dtm.tif", "dsm": "dsm.tif", "ndsm": "ndsm.tif", "density": "density.tif"}

    def declare(self, params: RasterizeParams, config: BaseModel) -> StageIO:
        outputs, products = dict(self.outputs), dict(self.products)
        inputs = tuple(self.inputs) + (("water_bodies", "breaklines") if _flattens(params, config) else ())
        geo = getattr(config.stages, "georeference", None)
        if config.input.format != "las" and geo is not None and geo.uncertainty is not None:
            outputs["dtm_uncertainty"] = products["dtm_uncertainty"] = "dtm_uncertainty.tif"
        return StageIO(inputs, outputs, products)

    config_keys = ("tiling.buffer", "stages.report.specification", *HEIGHTS_KEYS)

    def tile_buffer(self, params: RasterizeParams) -> float:
        return reach(params)

    def run(self, ctx: StageContext[RasterizeParams]) -> None:

        p = ctx.params
        src = ctx.inputs["points_objects"]
        info = cloud_info(src)
        _check_points(ctx, info)
        tiles = _Tiles(ctx, src, info, task_folder(ctx.workdir, self.name))
        try:
            results = run_tiled(
                ctx,
                extent=info.extent,
                buffer=reach(p, decks=has_decks(src)),  # the margin for bridge decks only where there are some
                split=tiles.split,
                task=rasterize_tile,
                merge=tiles.merge,
                weight=info.count,
                memo=MEMO,
            )
        finally:
            cleanup(tiles.work)
        grid = tiles.grid
        figures = survey_figures(results, grid.rows * grid.cols)
        if figures["nodata_cells"] == grid.rows * grid.cols:
            raise InputDataError(
                f"{glossary.input_names(ctx.config)}: the DTM has no valid cell: its {tiles.ground} ground points make no surface "
                f"on {grid.cols} x {grid.rows} cells of {p.resolution:g} m (collinear or too few points; "
                "check the ground classification, or use stages.rasterize.method: nearest)."
            )
        if "dtm_uncertainty" in ctx.outputs:
            ctx.metrics.update(dtm_sigma_median_m=_median_sigma(ctx.outputs["dtm_uncertainty"], info.units))
        ctx.metrics.update(
            method=p.method,
            resolution=p.resolution,
            nodata=tiles.nodata,
            cols=grid.cols,
            rows=grid.rows,
            origin=[tiles.transform.c, tiles.transform.f],
            units=info.units.describe(),
            ground_points=tiles.ground,
            **figures,
        )
        ctx.log.info(
            "DTM %d x %d cells at %g m, %d nodata", grid.cols, grid.rows, p.resolution, figures["nodata_cells"]
        )
        state_heights(ctx, tiles.heights, warn=True)


def _flattens(params: RasterizeParams, config: BaseModel) -> bool:
    """Whether the DTM is flattened in ``classify_water``'s water bodies (that stage and its bodies enabled)."""
    water = getattr(config.stages, "classify_water", None)
    return params.hydro_flatten and water is not None and water.enabled and water.bodies.enabled


def _check_points(ctx: StageContext[RasterizeParams], info: CloudInfo) -> None:
    """Refuse an empty cloud, and points without the sigmas an uncertainty raster needs."""
    if info.count == 0:
        raise InputDataError(f"{glossary.input_names(ctx.config)}: the point cloud is empty: there is nothing to grid.")
    if "dtm_uncertainty" in ctx.outputs and "sigma_vertical" not in info.dimensions:
        raise InputDataError("the points carry no sigma_vertical: the uncertainty was not propagated.")


def _with_water(tasks: list[RasterTask], path: Path, lines_path: Path, units: Units) -> list[RasterTask]:
    """The tasks with the water bodies to flatten the DTM in and the breaklines to enforce; each kept tile's key
    holds the bodies and breaklines over its cells and its buffer."""

    bodies = [
        (np.concatenate(rings), b"".join(np.ascontiguousarray(r).tobytes() for r in rings), level)
        for rings, level in read_water_bodies(path, units)
    ]
    lines = [(line, line.tobytes(), 0.0) for line in read_breaklines(lines_path, units)]
    boxes = [(xyz.min(axis=0), xyz.max(axis=0), data, level) for xyz, data, level in bodies + lines]
    out = []
    for t in tasks:
        _, wide, _ = tile_windows(t.grid, t.window, t.buffer)
        res = wide.resolution
        x0, y1 = wide.xmin + wide.col0 * res, wide.ymax - wide.row0 * res
        x1, y0 = x0 + wide.cols * res, y1 - wide.rows * res
        digest = hashlib.sha256()
        for lo, hi, data, level in boxes:
            if lo[0] <= x1 and hi[0] >= x0 and lo[1] <= y1 and hi[1] >= y0:
                digest.update(np.float64(level).tobytes() + data)
        units_pair = (units.horizontal, units.vertical)
        out.append(
            replace(
                t, water=str(path), breaklines=str(lines_path), water_digest=digest.hexdigest(), water_units=units_pair
            )
        )
    return out


def _median_sigma(path: Path, units: Units) -> float | None:
    """The median vertical sigma (metres) of the uncertainty raster's cells; None when it has none."""

    unc = read_raster(path)[0] * units.vertical
    return float(np.nanmedian(unc)) if np.isfinite(unc).any() else None


class _Tiles:
    """The ``split`` and ``merge`` of :func:`pipeline.tiling.run_tiled` for the rasters.

    The grid covers the usable points, so it is known once they are split
    (not from the header: stray points); ``grid``, ``ground`` (the ground
    points) and ``transform`` (the grid's, in the CRS's units) are set then.
    """

    def __init__(self, ctx: StageContext[RasterizeParams], src: Path, info: CloudInfo, work: Path):
        self.ctx, self.src, self.info, self.work = ctx, src, info, work
        self.names = [n for n in RASTERS if n in ctx.outputs]
        p = ctx.params
        self.nodata = dem_nodata(ctx.setting("stages.report.specification"), p.nodata)
        self.heights = heights_of_run(ctx.config, info.crs)  # the elevation rasters' vertical datum
        self.grid: Grid | None = None
        self.ground = 0
        self.transform = None

    def split(self, layout: Layout) -> list[RasterTask]:
        """Cut the points into the tiles, size the grid by the usable ones, and make the tiles' tasks."""

        ctx, info, p = self.ctx, self.info, self.ctx.params
        with ctx.progress(info.count, "tiling", unit="pt") as bar:
            rows, usable = split_cloud(
                self.src,
                layout,
                self.work / "in",
                partial(raster_columns, sigma="dtm_uncertainty" in ctx.outputs),
                progress=bar,
                count=Usable.of,
                index=False,
                executor=ctx.executor if len(layout) > 1 else None,
            )
        per_class = usable.classes
        self.ground = int(per_class[glossary.GROUND])
        if self.ground < 3:
            classes = ", ".join(f"class {c}: {per_class[c]:,}" for c in np.flatnonzero(per_class))
            raise InputDataError(
                f"{glossary.input_names(ctx.config)}: only {self.ground} ground points (class 2) among {info.count:,} points ({classes}): a DTM needs "
                "at least 3, so no DTM can be made (a survey of water only, or a ground classification to check)."
            )
        self.grid = Grid.covering(*usable.box(), p.resolution)  # in metres, written in CRS units
        check_grid_size(self.grid, usable.box(), info.units, source=glossary.input_names(ctx.config))
        ctx.log.info(
            "%s DTM from %d ground points on %d x %d cells", p.method, self.ground, self.grid.cols, self.grid.rows
        )
        params = p.model_dump(mode="json")
        params["nodata"] = self.nodata
        outline = survey_outline(usable.cells, p.outline_edge)
        self.work.mkdir(parents=True, exist_ok=True)
        outline.save(self.work / "outline.npy")
        where = (str(self.work / "outline.npy"), outline.ix0, outline.iy1)
        tasks = raster_tasks(layout, rows, self.grid, self.work, params, info.units.vertical, self.names, where)
        if "water_bodies" in ctx.inputs:
            tasks = _with_water(tasks, Path(ctx.inputs["water_bodies"]), Path(ctx.inputs["breaklines"]), info.units)
        if len(layout) == 1 or getattr(ctx.executor, "address", None) is None:  # not on a remote cluster
            check_tile_memory(tasks, p, ctx.executor.workers if len(layout) > 1 else 1)
        return tasks

    def merge(self, layout: Layout, tasks: list[RasterTask], results: list[dict]) -> list[dict]:
        """Assemble each raster from the tiles' windows, on the workers when there are tiles."""
        ctx = self.ctx
        self.transform = self.info.units.transform_from_metres(self.grid.transform)
        paths = {n: ctx.outputs[n] for n in self.names}
        cache_mb = 64 // (ctx.executor.workers if len(layout) > 1 else 1)
        datum = {VERTICAL_DATUM: self.heights.datum}
        jobs = mosaic_jobs(paths, self.grid, self.transform, self.info.crs, layout, tasks, cache_mb, self.nodata, datum)
        with ctx.progress(len(jobs), "rasters assembled and written", unit="rasters") as bar:
            if len(layout) > 1:  # the rasters assembled and compressed on the workers, side by side
                ctx.executor.map(mosaic_raster, jobs, what="rasters", done=lambda _: bar.update(1))
            else:
                for job in jobs:
                    mosaic_raster(job)
                    bar.update(1)
        return results
