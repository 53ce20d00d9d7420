"""What the delivery's QGIS layers are: each styled product, where it is published, its layers and their styles.

:data:`PRODUCT_PATHS` lists the styled artifacts in the project's order,
top to bottom (points above the vectors, the DTM over its hillshade at the
bottom); :func:`raster_layer`, :func:`vector_layers` and
:func:`point_layers` make their :class:`~stages.qgis.project.Layer` from
what the driver read (a raster's range, a GeoPackage's layers, the
per-input files).  Colours: the report's (:mod:`lidar.colormaps`, the ASPRS
class colours of :mod:`lidar.glossary`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import PurePosixPath

from lidar import glossary
from lidar.colormaps import table
from stages.qgis.project import Layer
from stages.qgis.styles import (
    BLEND_MULTIPLY,
    BLEND_NORMAL,
    fill_style,
    index_lines_style,
    line_style,
    multiple_of,
    point_classes_style,
    raster_grey_style,
    raster_ramp_style,
)

#: Each styled artifact's path in the output folder, in the project's layer order (top to bottom).  The merged
#: points are ``points.las`` when ``stages.export_las.compress`` is false (:func:`product_paths`).
PRODUCT_PATHS = {
    "points_export": "points.laz",
    "points_per_input": "points",
    "survey_index": "survey.gpkg",
    "trajectory_lines": "qc/trajectory.gpkg",
    "contours": "contours.gpkg",
    "breaklines": "breaklines.gpkg",
    "water_bodies": "water.gpkg",
    "buildings": "buildings.gpkg",
    "strip_difference_before": "strip_difference_before.tif",
    "strip_difference_after": "strip_difference_after.tif",
    "dtm_uncertainty": "dtm_uncertainty.tif",
    "density": "density.tif",
    "canopy_height": "canopy_height.tif",
    "ndsm": "ndsm.tif",
    "dsm": "dsm.tif",
    "dtm": "dtm.tif",
    "hillshade": "hillshade.tif",
}

#: Contour lines drawn thicker every this many intervals (index contours).
INDEX_EVERY = 5


def product_paths(compress: bool) -> dict[str, str]:
    """:data:`PRODUCT_PATHS` with the merged points' name as ``stages.export_las.compress`` makes it."""
    return {**PRODUCT_PATHS, "points_export": "points.laz" if compress else "points.las"}


def style_name(path: str) -> str:
    """The ``.qml`` QGIS loads as the default style of the product at *path*: beside it, the same stem.

    >>> style_name("qc/trajectory.gpkg")
    'qc/trajectory.qml'
    """
    return str(PurePosixPath(path).with_suffix(".qml"))


@dataclass(frozen=True)
class Ramp:
    """A raster's colour ramp: the colour map, whether it is centred on 0, shown at first, its blend mode."""

    colours: str
    symmetric: bool = False
    visible: bool = False
    blend: int = BLEND_NORMAL


#: The rasters drawn with a colour ramp over their values; the hillshade is grey (:func:`raster_layer`).
RAMPS = {
    "dtm": Ramp("relief", visible=True, blend=BLEND_MULTIPLY),  # multiplied with the hillshade below it
    "dsm": Ramp("relief"),
    "ndsm": Ramp("viridis"),
    "canopy_height": Ramp("viridis"),
    "density": Ramp("viridis"),
    "dtm_uncertainty": Ramp("viridis"),
    "strip_difference_before": Ramp("RdBu_r", symmetric=True),
    "strip_difference_after": Ramp("RdBu_r", symmetric=True),
}


def raster_layer(artifact: str, path: str, lo: float, hi: float) -> Layer:
    """The raster *artifact* published at *path*, its values from *lo* to *hi*."""
    if artifact == "hillshade":
        style = raster_grey_style(lo, hi)
        visible = True
    else:
        ramp = RAMPS[artifact]
        if ramp.symmetric:
            lo, hi = -max(abs(lo), abs(hi)), max(abs(lo), abs(hi))
        style = raster_ramp_style(lo, hi, table(ramp.colours), blend=ramp.blend)
        visible = ramp.visible
    stem = PurePosixPath(path).stem
    return Layer(stem, "raster", "gdal", path, style, visible=visible)


#: Water and buildings in their ASPRS class colours, a little transparent.
WATER_FILL = (*glossary.CLASS_COLOURS[glossary.WATER], 150)
BUILDING_FILL = (*glossary.CLASS_COLOURS[6], 150)
DARK_BLUE, DARK_RED, BLACK, GREY = (8, 81, 156), (153, 0, 13), (0, 0, 0), (110, 110, 110)
CONTOUR_BROWN = (120, 72, 30)


@dataclass(frozen=True)
class Vector:
    """A GeoPackage layer's name in the project, whether it is shown at first, and its style (no contours)."""

    name: str
    visible: bool
    geometry: str
    style: list


#: The GeoPackage layers of the products by their layer name; ``contours`` is styled by its interval.
VECTORS = {
    "boundary": Vector("survey boundary", True, "Polygon", fill_style(None, BLACK, 0.6)),
    "input_files": Vector("input files (tile index)", False, "Polygon", fill_style(None, GREY, 0.3, dashed=True)),
    "flight_lines": Vector("flight lines", True, "Line", line_style((255, 127, 0), 0.5)),
    "breaklines": Vector("breaklines", True, "Line", line_style(DARK_BLUE, 0.4)),
    "water_bodies": Vector("water", True, "Polygon", fill_style(WATER_FILL, DARK_BLUE, 0.3)),
    "buildings": Vector("buildings", True, "Polygon", fill_style(BUILDING_FILL, DARK_RED, 0.3)),
}


def contour_style(interval: float, metres_per_unit: float) -> list:
    """Contours every *interval* metres, every :data:`INDEX_EVERY` th thicker (``elevation`` in the CRS's unit)."""
    index = INDEX_EVERY * interval
    return index_lines_style(
        CONTOUR_BROWN,
        0.15,
        0.45,
        multiple_of("elevation", index, metres_per_unit),
        f"index contours, every {index:g} m",
        f"contours, every {interval:g} m",
    )


def vector_layers(path: str, tables: Sequence[tuple[str, str]], interval: float, metres_per_unit: float) -> list[Layer]:
    """The layers of the GeoPackage at *path*: its *tables* as (layer name, geometry type)."""
    out = []
    for name, geometry in tables:
        if name == "contours":
            known = Vector("contours", True, "Line", contour_style(interval, metres_per_unit))
        else:
            known = VECTORS.get(name) or _plain(name, geometry)
        out.append(
            Layer(
                known.name,
                "vector",
                "ogr",
                path,
                known.style,
                visible=known.visible,
                table=name,
                geometry=known.geometry,
            )
        )
    return out


def _plain(name: str, geometry: str) -> Vector:
    """A layer of no known product: grey, outlined if it is polygons."""
    if "Polygon" in geometry:
        return Vector(name, False, "Polygon", fill_style(None, GREY, 0.3))
    return Vector(name, False, "Line", line_style(GREY, 0.3))


#: Noise classes: drawn in these colours when switched on, off at first (the report leaves them out too).
NOISE = {glossary.LOW_NOISE: (255, 0, 255), glossary.HIGH_NOISE: (160, 32, 240)}
#: Classes the pipeline does not make (an input may hold them): one grey.
OTHER_CLASS = (128, 128, 128)


def point_classes() -> list[tuple[int, tuple[int, int, int], str, bool]]:
    """Every ASPRS class 0-22 as (code, colour, label, drawn): the report's colours, noise off at first."""
    out = []
    for code, name in glossary.CLASS_NAMES.items():
        colour = glossary.CLASS_COLOURS.get(code) or NOISE.get(code) or OTHER_CLASS
        out.append((code, colour, f"{code} {name}", code not in NOISE))
    return out


def point_layers(artifact: str, path: str, files: Sequence[str] = ()) -> list[Layer]:
    """The point cloud *path* (``points.laz``), or the per-input *files* under it in a group ``points``."""
    style = point_classes_style(point_classes())
    if artifact == "points_export":
        return [Layer("points", "point-cloud", "pdal", path, style, visible=False)]
    return [
        Layer(name, "point-cloud", "pdal", f"{path}/{name}", style, visible=False, group="points") for name in files
    ]
