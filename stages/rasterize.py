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
cells of 3.2808 ftUS and heights in ftUS; :mod:`stages.units`).
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from pipeline.config import StrictModel
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageParams
from stages import glossary
from stages.grid.interpolate import Grid, cell_count, cell_max, cell_mean, idw, nearest, tin
from stages.ground.surface import fill_nearest
from stages.io import NODATA, read_cloud, write_cog, xyz_metres


class IdwParams(StrictModel):
    neighbors: int = Field(8, ge=1, description="nearest ground points averaged per cell")
    power: float = Field(2.0, gt=0, description="weights are 1 / distance**power")


class RasterizeParams(StageParams):
    resolution: float = glossary.resolution(1.0)
    method: Literal["tin", "idw", "nearest"] = Field("tin", description="DTM interpolation: tin | idw | nearest")
    nodata_distance: float = glossary.nodata_distance(50.0)
    idw: IdwParams = Field(default_factory=IdwParams, description="parameters of method idw")


def interpolate_dtm(ground: np.ndarray, grid: Grid, params: RasterizeParams, progress=None) -> np.ndarray:
    """The DTM of *ground* points on *grid* by the configured method (NaN = nodata)."""
    if params.method == "tin":
        return tin(ground, grid, nodata_distance=params.nodata_distance, progress=progress)
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
    version = "4"  # 4: units in the metrics
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

    def run(self, ctx) -> None:
        p = ctx.params
        las = read_cloud(ctx.inputs["points_classified"])
        crs = las.header.parse_crs()
        pts, units = xyz_metres(las)  # gridded in metres (resolution, nodata_distance); written in CRS units
        if len(pts) == 0:
            raise InputDataError("the point cloud is empty: there is nothing to grid.")
        cls = np.asarray(las.classification)
        ground = pts[cls == glossary.GROUND]
        if len(ground) < 3:
            values, counts = np.unique(cls, return_counts=True)
            classes = ", ".join(f"class {v}: {c:,}" for v, c in zip(values, counts, strict=True))
            raise InputDataError(
                f"only {len(ground)} ground points (class 2) among {len(pts):,} points ({classes}): a DTM needs "
                "at least 3, so no DTM can be made (a survey of water only, or a ground classification to check)."
            )
        usable = ~np.isin(cls, (glossary.LOW_NOISE, glossary.HIGH_NOISE)) & ~np.asarray(las.withheld, dtype=bool)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        grid = Grid.covering(lo[0], lo[1], hi[0], hi[1], p.resolution)
        ctx.log.info("%s DTM from %d ground points on %d x %d cells", p.method, len(ground), grid.cols, grid.rows)
        with ctx.progress(grid.rows, f"{p.method} DTM", unit="row") as bar:
            dtm = interpolate_dtm(ground, grid, p, progress=bar)
        dsm = fill_nearest(cell_max(pts[usable], grid), max_cells=p.nodata_distance / p.resolution)
        dsm = np.where(np.isnan(dsm), dtm, dsm)  # no return at all: the surface is the ground
        ndsm = np.where(np.isnan(dsm) | np.isnan(dtm), np.nan, np.maximum(dsm - dtm, 0.0))
        density = cell_count(pts[usable], grid).astype(np.float64)
        transform = units.transform_from_metres(grid.transform)
        dtm, dsm, ndsm = dtm / units.vertical, dsm / units.vertical, ndsm / units.vertical
        for name, array in (("dtm", dtm), ("dsm", dsm), ("ndsm", ndsm)):
            write_cog(ctx.outputs[name], np.where(np.isnan(array), NODATA, array), transform=transform, crs=crs)
        write_cog(ctx.outputs["density"], density, transform=transform, crs=crs)
        if "dtm_uncertainty" in ctx.outputs:
            if "sigma_vertical" not in las.point_format.dimension_names:
                raise InputDataError("the points carry no sigma_vertical: the uncertainty was not propagated.")
            sv = np.asarray(las["sigma_vertical"], dtype=np.float64)[cls == glossary.GROUND]
            unc = fill_nearest(cell_mean(ground, sv, grid), max_cells=p.nodata_distance / p.resolution)
            unc = np.where(np.isnan(dtm), np.nan, unc)
            ctx.metrics.update(dtm_sigma_median_m=float(np.nanmedian(unc)) if np.isfinite(unc).any() else None)
            unc = unc / units.vertical
            write_cog(
                ctx.outputs["dtm_uncertainty"], np.where(np.isnan(unc), NODATA, unc), transform=transform, crs=crs
            )
        empty = int(np.isnan(dtm).sum())
        ctx.metrics.update(
            method=p.method,
            resolution=p.resolution,
            cols=grid.cols,
            rows=grid.rows,
            origin=[transform.c, transform.f],
            units=units.describe(),
            ground_points=int(len(ground)),
            nodata_cells=empty,
            nodata_fraction=round(empty / dtm.size, 4),
            dtm_min=float(np.nanmin(dtm)) if empty < dtm.size else None,
            dtm_max=float(np.nanmax(dtm)) if empty < dtm.size else None,
            density_mean=round(float(density.mean()), 3),
            ndsm_max=float(np.nanmax(ndsm)) if np.isfinite(ndsm).any() else None,
        )
        ctx.log.info("DTM %d x %d cells at %g m, %d nodata", grid.cols, grid.rows, p.resolution, empty)
