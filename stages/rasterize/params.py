"""Parameters of ``rasterize``: the grid, the DTM's interpolation method and each method's options."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from lidar import glossary
from pipeline.config import StrictModel
from pipeline.stage import StageParams

#: Most ``idw.neighbors``: each cell's search grows with it (1,000 take 30 s for the sample's 196,608 cells, 2 cores).
MAX_NEIGHBORS = 1_000


class IdwParams(StrictModel):
    neighbors: int = Field(
        8,
        ge=1,
        le=MAX_NEIGHBORS,
        description=f"nearest ground points averaged per cell (at most {MAX_NEIGHBORS:,}: each cell's cost grows "
        "with it; fewer when the tile has fewer ground points)",
    )
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
    outline_edge: float = Field(
        20.0,
        ge=0,
        description="the survey's outline (docs/stages/rasterize.md): cells outside the coverage's concave hull, "
        "peeled from outside along edges longer than this (metres; at least 4 x the median edge of 5-m occupied "
        "cells), are nodata in the DTM, DSM and nDSM; and the TIN's triangles with an edge this long on its hull are "
        "not drawn; 0: neither (the TIN fills the convex hull)",
    )
    nodata: float | None = Field(
        None,
        description="nodata value of the rasters; none: -999999 when stages.report.specification is a USGS LBS "
        "quality level (the LBS's DEM requirement), else -9999",
    )
    bridge_decks: bool = Field(
        True,
        description="DTM cells under a bridge deck (class 17 points) interpolated across the deck from the terrain "
        "either side of it, as the USGS LBS asks; false: the TIN of the ground around it",
    )
    max_deck_width: float = Field(
        40.0,
        gt=0,
        description="widest bridge deck (m): the terrain either side is looked for this far; widens the tiles' buffer "
        "when the points hold class 17",
    )
    hydro_flatten: bool = Field(
        True,
        description="DTM cells whose centre lies in a flat water body of classify_water's water.gpkg take the "
        "body's level (hydro-flattening), and the bodies' shores (breaklines.gpkg) are enforced in the interpolation",
    )
