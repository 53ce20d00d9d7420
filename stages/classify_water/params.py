"""Parameters of ``classify_water``: detection from the points, and the optional polygon layer."""

from __future__ import annotations

from pydantic import Field

from lidar import glossary
from pipeline.config import InputFile, StrictModel
from pipeline.stage import StageParams


class DetectParams(StrictModel):
    """Water found in the ground points (:func:`stages.classify_water.water.water_from_points`)."""

    enabled: bool = Field(True, description="look for water in the ground points")
    cell_size: float = glossary.cell_size(1.0)
    window: float = Field(
        3.0, gt=0, description="half-width (m) of the square window of cells a plane is fitted to around each cell"
    )
    min_points: int = Field(10, ge=3, description="fewest ground points in a window for its plane to count")
    max_slope: float = Field(0.008, ge=0, description="steepest fitted plane (rise over run) that can be water")
    max_rms: float = Field(0.1, gt=0, description="largest RMS (m) of the ground points about their plane")
    step: float = Field(0.1, ge=0, description="largest height step (m) between neighbouring cells of one water body")
    min_area: float = Field(70.0, ge=0, description="smallest water body (m2) kept")
    grow: float = Field(
        4.0, ge=0, description="points this far (m) beyond a water body's cells, at its level, are water too"
    )
    tolerance: float = Field(0.15, ge=0, description="a water point lies within this height (m) of the water level")
    min_bank: float = Field(
        0.15,
        description="a water body whose banks (the ground around it) rise less than this (m, their median) above its "
        "level is no water: its points get their class back",
    )


class BodiesParams(StrictModel):
    """Water bodies: the outlines of the water points, one level each (:func:`lidar.water_bodies.water_bodies`)."""

    enabled: bool = Field(
        True, description="outline the water bodies in water.gpkg; rasterize flattens the DTM in them"
    )
    cell_size: float = glossary.cell_size(1.0)
    close: int = Field(
        2, ge=0, description="cells of a morphological closing that join a body's water points across dropouts"
    )
    min_area: float = Field(200.0, ge=0, description="smallest water body (m2) outlined")
    max_spread: float = Field(
        0.3,
        ge=0,
        description="a body whose water heights spread more (m, 5th to 95th percentile) is flattened as a river "
        "when it falls along its axis within this of a monotone profile, else outlined but not flattened",
    )
    ignored_ground: float = Field(
        0.7,
        ge=0,
        description="ground points within this distance (m) of a flattened body's outline (a hydro breakline) become "
        "class 20, ignored ground, and stay out of the DTM (USGS LBS); default: the largest nominal pulse spacing "
        "of quality level 2 (0.71 m); 0: none",
    )


class ClassifyWaterParams(StageParams):
    detect: DetectParams = Field(default_factory=DetectParams, description="water found in the ground points")
    bodies: BodiesParams = Field(default_factory=BodiesParams, description="water bodies and hydro-flattening")
    polygons: InputFile | None = Field(
        None,
        description="GeoPackage or shapefile of water polygons (e.g. a hydrography layer), in the points' CRS; "
        "none = no polygons",
    )
    polygon_height: float = Field(
        0.3, ge=0, description="inside a polygon, points within this height (m) of the water level become water"
    )
    polygon_window: float = Field(
        10.0, gt=0, description="inside a polygon, the water level is the lowest ground within this distance (m)"
    )
    one_grid_cells: int = Field(
        2_000_000,
        ge=0,
        description="the whole survey is worked on one grid, in three passes over the points, when the grid has at "
        "most this many cells (2 km2 of 1 m cells; about 300 bytes a cell at the peak: 0.6 GB); a grid up to 4 "
        "times larger is worked in the tiles' windows (88 bytes a cell held), larger surveys are cut into tiles "
        "of points with the buffer; 0: always tiles of points",
    )
