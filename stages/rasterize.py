"""Stage ``rasterize``: ground points to the bare-earth DTM (``dtm.tif``).

The grid covers all points of the survey (not only the ground), cell-aligned
to multiples of ``resolution``.  Cells under buildings are interpolated from
the surrounding ground; cells farther than ``nodata_distance`` from every
ground point (water, gaps) are nodata.  Method in this version: ``tin``
(linear on the Delaunay triangulation); IDW, nearest, the DSM and the other
products come with the products issue.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageParams
from stages import glossary
from stages.grid.interpolate import Grid, tin
from stages.io import NODATA, read_cloud, write_cog, xyz


class RasterizeParams(StageParams):
    resolution: float = glossary.resolution(1.0)
    method: Literal["tin"] = Field("tin", description="interpolation: tin (linear on a Delaunay triangulation)")
    nodata_distance: float = glossary.nodata_distance(50.0)


class Rasterize(Stage):
    name = "rasterize"
    version = "1"
    Params = RasterizeParams
    description = "ground points to the DTM GeoTIFF"
    inputs = ("points_classified",)
    outputs: ClassVar = {"dtm": "dtm.tif"}
    products: ClassVar = {"dtm": "dtm.tif"}

    def run(self, ctx) -> None:
        p = ctx.params
        las = read_cloud(ctx.inputs["points_classified"])
        crs = las.header.parse_crs()
        pts = xyz(las)
        if len(pts) == 0:
            raise InputDataError("the point cloud is empty: there is nothing to grid.")
        ground = pts[np.asarray(las.classification) == glossary.GROUND]
        if len(ground) < 3:
            raise InputDataError(
                f"only {len(ground)} ground points (class 2): a DTM needs at least 3; "
                "check the ground classification or enable classify_ground."
            )
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        grid = Grid.covering(lo[0], lo[1], hi[0], hi[1], p.resolution)
        ctx.log.info("triangulating %d ground points", len(ground))
        with ctx.progress(grid.rows, f"TIN {grid.cols}x{grid.rows} cells", unit="row") as bar:
            dtm = tin(ground, grid, nodata_distance=p.nodata_distance, nodata=NODATA, progress=bar)
        empty = int((dtm == NODATA).sum())
        ctx.metrics.update(
            method=p.method,
            resolution=p.resolution,
            cols=grid.cols,
            rows=grid.rows,
            origin=[grid.xmin, grid.ymax],
            ground_points=int(len(ground)),
            nodata_cells=empty,
            nodata_fraction=round(empty / dtm.size, 4),
        )
        ctx.log.info("DTM %d x %d cells at %g m, %d nodata", grid.cols, grid.rows, p.resolution, empty)
        write_cog(ctx.outputs["dtm"], dtm, transform=grid.transform, crs=crs, nodata=NODATA)
