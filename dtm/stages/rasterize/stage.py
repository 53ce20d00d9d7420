"""Stage ``rasterize``: the elevation rasters of the survey.

- ``dtm.tif``: bare earth from the ground points (class 2) by ``method``:
  ``tin`` (linear on a Delaunay triangulation, default), ``idw`` (inverse
  distance weighting) or ``nearest``.  Cells under buildings are interpolated
  from the surrounding ground; cells farther than ``nodata_distance`` from
  every ground point (water, gaps) are nodata.
- ``dsm.tif``: the highest non-noise return per cell; empty cells take the
  value of the nearest full cell within ``nodata_distance``.
- ``ndsm.tif``: DSM - DTM (height above ground), negatives set to 0.
- ``density.tif``: points per cell (all points but noise and withheld).
- ``dtm_uncertainty.tif`` (when the points carry ``sigma_vertical``, i.e.
  ``stages.georeference.uncertainty`` is set): the mean propagated vertical
  sigma of the ground points in each cell, cells without one taking the
  nearest value within ``nodata_distance``.  Not divided by the square root
  of the point count: the navigation errors that dominate it are shared by
  neighbouring points, so averaging them does not shrink them.

The grid covers all points of the survey, cell-aligned to multiples of
``resolution``.  All rasters are Cloud Optimized GeoTIFF, float32, with the
nodata value -9999.  Parameters are in metres; the rasters are in the CRS's
units (cells and height values: a 1 m grid of a survey in US survey feet has
cells of 3.2808 ftUS and heights in ftUS; :mod:`dtm.common.units`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from dtm.common import glossary
from dtm.common.grid import Grid, cell_max_count, cell_mean, check_grid_size, fill_nearest
from dtm.common.rasters import HEIGHT, NODATA
from dtm.stages.rasterize.interpolate import idw, nearest, tin
from pipeline.config import StrictModel
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext, StageParams


class IdwParams(StrictModel):
    neighbors: int = Field(8, ge=1, description="nearest ground points averaged per cell")
    power: float = Field(2.0, gt=0, description="weights are 1 / distance**power")


class TinParams(StrictModel):
    thin: bool = Field(
        True,
        description="in cells with more than 4 ground points, triangulate one per half cell (the nearest to its "
        "centre); false: every ground point",
    )


class RasterizeParams(StageParams):
    resolution: float = glossary.resolution(1.0)
    method: Literal["tin", "idw", "nearest"] = Field("tin", description="DTM interpolation: tin | idw | nearest")
    nodata_distance: float = glossary.nodata_distance(50.0)
    idw: IdwParams = Field(default_factory=IdwParams, description="parameters of method idw")
    tin: TinParams = Field(default_factory=TinParams, description="parameters of method tin")


def interpolate_dtm(ground: np.ndarray, grid: Grid, params: RasterizeParams, progress=None) -> np.ndarray:
    """The DTM of *ground* points on *grid* by the configured method (NaN = nodata)."""
    if params.method == "tin":
        return tin(ground, grid, nodata_distance=params.nodata_distance, thin=params.tin.thin, progress=progress)
    if params.method == "idw":
        return idw(
            ground,
            grid,
            nodata_distance=params.nodata_distance,
            neighbors=params.idw.neighbors,
            power=params.idw.power,
            progress=progress,
        )
    return nearest(ground, grid, nodata_distance=params.nodata_distance, progress=progress)


class Rasterize(Stage):
    name = "rasterize"
    version = "5"
    Params = RasterizeParams
    description = "DTM, DSM, nDSM and density rasters"
    inputs = ("points_classified",)
    outputs: ClassVar = {"dtm": "dtm.tif", "dsm": "dsm.tif", "ndsm": "ndsm.tif", "density": "density.tif"}
    products: ClassVar = {"dtm": "dtm.tif", "dsm": "dsm.tif", "ndsm": "ndsm.tif", "density": "density.tif"}

    def declare(self, params, config):
        from pipeline.stage import StageIO

        outputs, products = dict(self.outputs), dict(self.products)
        geo = getattr(config.stages, "georeference", None)
        if config.input.format != "las" and geo is not None and geo.uncertainty is not None:
            outputs["dtm_uncertainty"] = products["dtm_uncertainty"] = "dtm_uncertainty.tif"
        return StageIO(tuple(self.inputs), outputs, products)

    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params) -> float:
        return reach(params)

    def run(self, ctx: StageContext[RasterizeParams]) -> None:
        from dtm.common.clouds import cloud_info
        from dtm.common.mosaic import core_window
        from dtm.common.tile_points import cleanup, split_cloud, task_folder
        from pipeline.tiling import run_tiled

        p = ctx.params
        src = ctx.inputs["points_classified"]
        info = cloud_info(src)
        units, crs = info.units, info.crs
        if info.count == 0:
            raise InputDataError(
                f"{glossary.input_names(ctx.config)}: the point cloud is empty: there is nothing to grid."
            )
        if "dtm_uncertainty" in ctx.outputs and "sigma_vertical" not in info.dimensions:
            raise InputDataError("the points carry no sigma_vertical: the uncertainty was not propagated.")
        names = [n for n in ("dtm", "dsm", "ndsm", "density", "dtm_uncertainty") if n in ctx.outputs]
        work = task_folder(ctx.workdir, self.name)
        params = p.model_dump(mode="json")
        grid = None  # sized by the usable points once they are split (not by the header: stray points)
        ground = 0
        columns = partial(raster_columns, sigma="dtm_uncertainty" in ctx.outputs)

        def split(layout):
            nonlocal ground, grid
            with ctx.progress(info.count, "tiling", unit="pt") as bar:
                rows, usable = split_cloud(
                    src,
                    layout,
                    work / "in",
                    columns,
                    progress=bar,
                    count=Usable.of,
                    index=False,
                    executor=ctx.executor if len(layout) > 1 else None,
                )
            per_class = usable.classes
            ground = int(per_class[glossary.GROUND])
            if ground < 3:
                classes = ", ".join(f"class {c}: {per_class[c]:,}" for c in np.flatnonzero(per_class))
                raise InputDataError(
                    f"{glossary.input_names(ctx.config)}: only {ground} ground points (class 2) among {info.count:,} points ({classes}): a DTM needs "
                    "at least 3, so no DTM can be made (a survey of water only, or a ground classification to check)."
                )
            grid = Grid.covering(*usable.box(), p.resolution)  # in metres, written in CRS units
            check_grid_size(grid, usable.box(), units, source=glossary.input_names(ctx.config))
            grid_args = dict(xmin=grid.xmin, ymax=grid.ymax, resolution=grid.resolution, cols=grid.cols, rows=grid.rows)
            ctx.log.info("%s DTM from %d ground points on %d x %d cells", p.method, ground, grid.cols, grid.rows)
            return [
                {
                    "tile": tile.index,
                    "window": core_window(grid, tile, layout),
                    "weight": rows[tile.index][0],
                    "source": str(work / "in" / str(tile.index)),
                    "result": str(work / "out" / str(tile.index)),
                    "grid": grid_args,
                    "params": params,
                    "buffer": layout.buffer,
                    "vertical": units.vertical,
                    "outputs": names,
                }
                for tile in layout.tiles
                if tile.index in rows
            ]

        def merge(layout, tasks, results):
            transform = units.transform_from_metres(grid.transform)
            done = {t["tile"] for t in tasks}
            jobs = [
                {
                    "path": str(ctx.outputs[n]),
                    "rows": grid.rows,
                    "cols": grid.cols,
                    "transform": transform,
                    "crs": crs,
                    "fill": 0.0 if n == "density" else NODATA,
                    "unit": None if n == "density" else HEIGHT,
                    "windows": [(t["window"], str(Path(t["result"]) / f"{n}.npy")) for t in tasks],
                    "empty": [core_window(grid, tile, layout) for tile in layout.tiles if tile.index not in done],
                    "cache_mb": 64 // (ctx.executor.workers if len(layout) > 1 else 1),
                }
                for n in names
            ]
            if len(layout) > 1:  # the rasters assembled and compressed on the workers, side by side
                ctx.executor.map(mosaic_raster, jobs, what="rasters")
            else:
                for job in jobs:
                    mosaic_raster(job)
            return results, transform

        try:
            results, transform = run_tiled(
                ctx, extent=info.extent, buffer=self.tile_buffer(p), split=split, task=rasterize_tile, merge=merge
            )
        finally:
            cleanup(work)
        cells = grid.rows * grid.cols
        empty = sum(r["nodata_cells"] for r in results) + (cells - sum(r["cells"] for r in results))
        if empty == cells:
            raise InputDataError(
                f"{glossary.input_names(ctx.config)}: the DTM has no valid cell: its {ground} ground points make no surface "
                f"on {grid.cols} x {grid.rows} cells of {p.resolution:g} m (collinear or too few points; "
                "check the ground classification, or use stages.rasterize.method: nearest)."
            )
        mins = [r["dtm_min"] for r in results if r["dtm_min"] is not None]
        maxs = [r["dtm_max"] for r in results if r["dtm_max"] is not None]
        ndsm = [r["ndsm_max"] for r in results if r["ndsm_max"] is not None]
        if "dtm_uncertainty" in ctx.outputs:
            from dtm.common.rasters import read_raster

            unc = read_raster(ctx.outputs["dtm_uncertainty"])[0] * units.vertical
            ctx.metrics.update(dtm_sigma_median_m=float(np.nanmedian(unc)) if np.isfinite(unc).any() else None)
        ctx.metrics.update(
            method=p.method,
            resolution=p.resolution,
            cols=grid.cols,
            rows=grid.rows,
            origin=[transform.c, transform.f],
            units=units.describe(),
            ground_points=ground,
            nodata_cells=int(empty),
            nodata_fraction=round(empty / cells, 4),
            dtm_min=float(min(mins)) if mins else None,
            dtm_max=float(max(maxs)) if maxs else None,
            density_mean=round(sum(r["density_sum"] for r in results) / cells, 3),
            ndsm_max=float(max(ndsm)) if ndsm else None,
        )
        ctx.log.info("DTM %d x %d cells at %g m, %d nodata", grid.cols, grid.rows, p.resolution, empty)


def raster_columns(chunk, *, sigma: bool = False) -> dict[str, np.ndarray]:
    """The columns the tiles need besides x, y, z (:func:`dtm.common.tile_points.split_cloud`): classes, withheld, sigma."""
    cols = {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }
    if sigma:
        cols["sigma_vertical"] = np.asarray(chunk["sigma_vertical"], dtype=np.float64)
    return cols


@dataclass(frozen=True)
class Usable:
    """The class histogram of some points, and the box (metres) of the usable ones: all but noise (7, 18) and withheld.

    :meth:`of` is :func:`dtm.common.tile_points.split_cloud`'s ``count``; the sum of
    two is the histogram and box of both (the grid is sized by the box).
    """

    classes: np.ndarray  # points per class 0..255
    lo: np.ndarray  # xmin, ymin (inf: none usable)
    hi: np.ndarray  # xmax, ymax

    @classmethod
    def of(cls, cols: dict[str, np.ndarray]) -> Usable:
        usable = glossary.usable(cols["classification"], cols["withheld"])
        lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
        if usable.any():
            x, y = cols["x"][usable], cols["y"][usable]
            lo, hi = np.array([x.min(), y.min()]), np.array([x.max(), y.max()])
        return cls(np.bincount(cols["classification"], minlength=256), lo, hi)

    def __add__(self, other: Usable) -> Usable:
        return Usable(self.classes + other.classes, np.minimum(self.lo, other.lo), np.maximum(self.hi, other.hi))

    def box(self) -> tuple[float, float, float, float]:
        if not np.isfinite(self.lo).all():
            raise InputDataError("every point is noise or withheld: there is nothing to grid.")
        return (float(self.lo[0]), float(self.lo[1]), float(self.hi[0]), float(self.hi[1]))


def reach(params: RasterizeParams) -> float:
    """The buffer (metres) a tile needs for its cells to equal the untiled ones.

    IDW and nearest use points within ``nodata_distance`` of a cell centre,
    as does the DSM's gap filling: ``nodata_distance`` plus a cell.  A TIN
    triangle covering a cell may reach farther (across a gap up to
    ``nodata_distance`` from both sides): twice ``nodata_distance``.
    """
    far = 2.0 if params.method == "tin" else 1.0
    return far * params.nodata_distance + 2.0 * params.resolution


def mosaic_raster(job: dict) -> None:
    """Assemble one raster of the survey from its tiles' windows and write it as a COG (runs in a worker).

    *job*: ``path``, ``rows``, ``cols``, ``transform``, ``crs``, ``fill``,
    ``unit`` (:class:`dtm.common.mosaic.RasterMosaic`), ``windows`` (each
    ``((r0, r1, c0, c1), npy file)``), ``empty`` (windows no tile wrote)
    and ``cache_mb`` (GDAL's block cache).
    """
    import rasterio

    from dtm.common.mosaic import RasterMosaic

    # GDAL's block cache, 64 MB for all the workers at once: its default, 5 % of the RAM, would grow with the grid
    with rasterio.Env(GDAL_CACHEMAX=job["cache_mb"]):
        mosaic = RasterMosaic(
            Path(job["path"]),
            rows=job["rows"],
            cols=job["cols"],
            transform=job["transform"],
            crs=job["crs"],
            nodata=NODATA,
            fill=job["fill"],
            unit=job["unit"],
        )
        try:
            for (r0, _, c0, _), values in job["windows"]:
                mosaic.write(r0, c0, np.load(values))
            for window in job["empty"]:
                mosaic.write_fill(*window)
            mosaic.finish()
        except BaseException:
            mosaic.abort()
            raise


def rasterize_tile(task: dict) -> dict:
    """The rasters of one tile's core cells, from its points (core plus buffer).

    Runs in a worker process; writes one ``.npy`` per raster (in the CRS's
    height unit, NaN = nodata) to ``task["result"]`` and returns figures.
    """

    from dtm.common.tile_points import tile_parts

    p = RasterizeParams.model_validate(task["params"])
    g = task["grid"]
    grid = Grid(g["xmin"], g["ymax"], g["resolution"], g["cols"], g["rows"])
    r0, r1, c0, c1 = task["window"]
    core = grid.window(r0, r1, c0, c1)
    pad = int(math.ceil(task["buffer"] / grid.resolution))
    br0, br1 = max(r0 - pad, 0), min(r1 + pad, grid.rows)
    bc0, bc1 = max(c0 - pad, 0), min(c1 + pad, grid.cols)
    wide = grid.window(br0, br1, bc0, bc1)
    crop = (slice(r0 - br0, r1 - br0), slice(c0 - bc0, c1 - bc0))
    parts = tile_parts(Path(task["source"]))  # the tile's points in file order, a range of records each
    masks = []
    for part in parts:
        cls = np.load(part / "classification.npy")
        masks.append((cls == glossary.GROUND, glossary.usable(cls, np.load(part / "withheld.npy"))))
    del cls
    n_ground = sum(int(is_ground.sum()) for is_ground, _ in masks)
    ground = np.empty((n_ground, 3))
    highest = count = None
    sigma_parts = []
    at = 0
    for part, (is_ground, usable) in zip(parts, masks, strict=True):
        # The columns mapped, not read: only the rows each raster needs are in memory.
        xyz = [np.load(part / f"{a}.npy", mmap_mode="r") for a in "xyz"]
        # core cells are wide cells; every point usable (the usual case): the mapped columns as they are
        high, n = cell_max_count(xyz if usable.all() else [a[usable] for a in xyz], wide)
        highest, count = (high, n) if highest is None else (np.fmax(highest, high), count + n)
        k = int(is_ground.sum())
        for i, a in enumerate(xyz):
            ground[at : at + k, i] = a[is_ground]
        at += k
        if "dtm_uncertainty" in task["outputs"]:
            sigma_parts.append(np.load(part / "sigma_vertical.npy", mmap_mode="r")[is_ground])
        del xyz, high, n
    del masks
    max_cells = p.nodata_distance / p.resolution
    dsm = fill_nearest(highest, max_cells=max_cells)[crop]
    dtm = np.full((core.rows, core.cols), np.nan)
    if core.rows and core.cols and n_ground >= (3 if p.method == "tin" else 1):
        if p.method == "tin" and "dtm_uncertainty" not in task["outputs"]:
            ground = [ground]  # handed over: the TIN frees the points once it has what it needs
        dtm = interpolate_dtm(ground, core, p)  # collinear or coincident ground points: all nodata
    dsm = np.where(np.isnan(dsm), dtm, dsm)  # no return at all: the surface is the ground
    ndsm = np.where(np.isnan(dsm) | np.isnan(dtm), np.nan, np.maximum(dsm - dtm, 0.0))
    density = count[crop].astype(np.float64)
    out = {"dtm": dtm, "dsm": dsm, "ndsm": ndsm, "density": density}
    if "dtm_uncertainty" in task["outputs"]:
        sigma = sigma_parts[0] if len(sigma_parts) == 1 else np.concatenate(sigma_parts)
        unc = fill_nearest(cell_mean(ground, sigma, wide), max_cells=max_cells)[crop]
        out["dtm_uncertainty"] = np.where(np.isnan(dtm), np.nan, unc)
    vertical = task["vertical"]
    folder = Path(task["result"])
    folder.mkdir(parents=True, exist_ok=True)
    for name in task["outputs"]:
        values = out[name] if name == "density" else out[name] / vertical
        np.save(folder / f"{name}.npy", np.where(np.isnan(values), NODATA, values).astype(np.float32))
    finite = np.isfinite(dtm)
    return {
        "tile": task["tile"],
        "cells": int(dtm.size),
        "nodata_cells": int((~finite).sum()),
        "dtm_min": float(dtm[finite].min()) / vertical if finite.any() else None,
        "dtm_max": float(dtm[finite].max()) / vertical if finite.any() else None,
        "density_sum": int(density.sum()),
        "ndsm_max": float(np.nanmax(ndsm)) / vertical if np.isfinite(ndsm).any() else None,
    }
