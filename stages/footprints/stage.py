"""Stage ``footprints``: ``buildings.gpkg`` (one outline a building) and ``canopy_height.tif``.

After ``rasterize``: the classified cloud (``classify_objects``' classes) is
read in chunks onto the DTM's grid (:mod:`stages.footprints.outlines`).
``buildings.gpkg`` (GeoPackage 1.2, layer ``buildings``, MultiPolygon in the
CRS): per building its ``ground_z`` (median DTM under it), ``roof_z`` (median
of its cells' highest points), ``highest_z``, ``height`` (roof − ground),
``points`` and ``area`` (CRS units); an empty layer when there is none.
``canopy_height.tif`` (when ``classify_objects`` classifies vegetation): the
highest vegetation point above the DTM per cell, a COG like the DTM.
``survey.gpkg``: the survey's boundary and its input files' tile index
(:mod:`stages.footprints.survey_index`).
docs/stages/footprints.md.
"""

from __future__ import annotations

from typing import ClassVar

import laspy
import numpy as np
import rasterio

from lidar.clouds import progress_chunk
from lidar.rasters import read_raster, write_cog
from lidar.vectors import write_gpkg
from pipeline.stage import Stage, StageContext, StageIO, StageParams, get_dotted
from stages.footprints.outlines import CellTally, building_labels, building_rows, canopy_height, flat_cells
from stages.footprints.survey_index import write_survey_index


class FootprintsParams(StageParams):
    pass


def _vegetation(config) -> bool:
    objects = get_dotted(config, "stages.classify_objects")
    return objects is not None and objects.enabled and objects.vegetation.enabled


class Footprints(Stage, name="footprints", version="3", params=FootprintsParams):
    """building outlines (buildings.gpkg), canopy height (canopy_height.tif), boundary and tile index (survey.gpkg)."""

    inputs = ("dtm", "points_objects")
    outputs: ClassVar = {"buildings": "buildings.gpkg", "survey_index": "survey.gpkg"}
    products: ClassVar = {"buildings": "buildings.gpkg", "survey_index": "survey.gpkg"}

    def declare(self, params, config) -> StageIO:
        outputs, products = dict(self.outputs), dict(self.products)
        if _vegetation(config):
            outputs["canopy_height"] = products["canopy_height"] = "canopy_height.tif"
        inputs = tuple(self.inputs) + (("input_files",) if config.input.format == "las" else ())
        return StageIO(inputs, outputs, products)

    def run(self, ctx: StageContext[FootprintsParams]) -> None:
        dtm, transform, crs, _ = read_raster(ctx.inputs["dtm"])
        with rasterio.open(ctx.inputs["dtm"]) as ds:
            nodata = ds.nodata
        tally = CellTally.empty(dtm.shape)
        with (
            laspy.open(str(ctx.inputs["points_objects"])) as reader,
            ctx.progress(reader.header.point_count, "points tallied on the DTM's cells", unit="pt") as bar,
        ):
            for chunk in reader.chunk_iterator(progress_chunk(reader.header.point_count)):  # any chunks: max, counts
                cell = flat_cells(np.asarray(chunk.x), np.asarray(chunk.y), transform, dtm.shape)
                tally.add(cell, np.asarray(chunk.z), np.asarray(chunk.classification))
                bar.update(len(chunk))
        area, skipped = write_survey_index(
            ctx.outputs["survey_index"], dtm, transform, crs, ctx.inputs.get("input_files")
        )
        ctx.metrics.update(boundary_area=area)
        if skipped:
            ctx.log.warning(
                "survey.gpkg: %d input files left out of the tile index, their CRS's name cannot be read back "
                "(%s); qc/input_files.csv lists their bounds",
                len(skipped),
                ", ".join(skipped[:3]),
            )
        count = _buildings(ctx, tally, dtm, transform, crs)
        tally.roof_count = tally.roof_top = None  # the buildings' grids: not held while the canopy is written
        if "canopy_height" in ctx.outputs:
            chm = canopy_height(tally, dtm, in_place=True)
            ctx.metrics.update(canopy_cells=int(np.isfinite(chm).sum()))
            chm[np.isnan(chm)] = nodata
            write_cog(
                ctx.outputs["canopy_height"],
                chm,
                transform=transform,
                crs=crs,
                nodata=nodata,
                description="vegetation height above the bare earth (canopy height model)",
            )
        ctx.log.info("%d building outlines", count)


def _buildings(ctx: StageContext[FootprintsParams], tally, dtm: np.ndarray, transform, crs) -> int:
    """buildings.gpkg from the tally (:func:`~stages.footprints.outlines.building_rows`); the buildings."""
    labels, count = building_labels(tally.roof_count.reshape(dtm.shape))
    rows = building_rows(labels, count, tally, dtm, transform)
    write_gpkg(
        ctx.outputs["buildings"],
        rows["geometry"],
        rows["fields"],
        crs=crs,
        layer="buildings",
        geometry_type="MultiPolygon",
    )
    ctx.metrics.update(buildings=count, building_points=int(tally.roof_count.sum()))
    return count
