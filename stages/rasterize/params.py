"""Parameters of ``rasterize``: the grid, the DTM's interpolation method and each method's parameters.

``method`` names one of the registered methods (:data:`stages.rasterize.interpolators.INTERPOLATORS`);
:class:`RasterizeParams` has a block for each method that has parameters, named as the method.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field, create_model

from lidar import glossary
from pipeline.stage import StageParams
from stages.rasterize.interpolators import INTERPOLATORS


class GridParams(StageParams):
    """``rasterize``'s own parameters; :class:`RasterizeParams` adds the methods' blocks."""

    resolution: float = glossary.resolution(1.0)
    method: Annotated[str, INTERPOLATORS.name()] = Field("tin", description="DTM interpolation method")
    nodata_distance: float = glossary.nodata_distance(50.0)
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
    floor_tolerance: float | None = Field(
        0.15,
        ge=0,
        description="under vegetation (a return more than 2 m above), ground points more than this (m) above the "
        "floor's lower envelope are left out of the DTM (understory echoes the ground filter admits; their class "
        "stays ground); none: every ground point (docs/stages/rasterize.md)",
    )
    floor_cell: float = Field(
        2.0,
        gt=0,
        description="cell (m) of the floor's lower envelope: the TIN of the lowest ground point of each",
    )
    hydro_flatten: bool = Field(
        True,
        description="DTM cells whose centre lies in a flat water body of classify_water's water.gpkg take the "
        "body's level (hydro-flattening), and the bodies' shores (breaklines.gpkg) are enforced in the interpolation",
    )


#: The stage's parameters: :class:`GridParams` and, for each registered method with parameters, its block.
RasterizeParams = create_model(
    "RasterizeParams",
    __base__=GridParams,
    __module__=__name__,
    __doc__="The parameters of ``rasterize``: the grid's, and each interpolation method's block.",
    **{
        m.name: (m.params, Field(default_factory=m.params, description=f"parameters of method {m.name}: {m.summary}"))
        for m in INTERPOLATORS
        if m.params is not None
    },
)
