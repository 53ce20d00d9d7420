"""The product's stages in their natural order, with what they add to the engine: the whole plugin.

Imported when the stages are first used (:data:`stages.plugin.plugin`), not
by ``pipeline --help``: it imports every stage, and with them NumPy,
pydantic and SciPy.
"""

from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version
from typing import Annotated, Any

import rasterio
from pydantic import AfterValidator, Field

from lidar.crs import check_crs_setting
from lidar.input_files import not_a_configuration
from pipeline.stage import Plugin
from stages.accuracy.stage import Accuracy
from stages.classify_ground.stage import ClassifyGround
from stages.classify_objects.stage import ClassifyObjects
from stages.classify_water.stage import ClassifyWater
from stages.contours.stage import Contours
from stages.denoise.stage import Denoise
from stages.export_las.stage import ExportLas
from stages.export_tiles.stage import ExportTiles
from stages.footprints.stage import Footprints
from stages.georeference.stage import Georeference
from stages.hillshade.stage import Hillshade
from stages.parse.changes import changed_areas
from stages.parse.checks import configuration_warnings
from stages.parse.stage import Parse
from stages.qgis.stage import Qgis
from stages.rasterize.stage import Rasterize
from stages.report.stage import Report
from stages.strip_adjust.stage import StripAdjust

#: The stages, in the natural order of the graph (ties in this order).
STAGES = [
    Parse,
    Georeference,
    StripAdjust,
    Denoise,
    ClassifyGround,
    ClassifyWater,
    ClassifyObjects,
    Rasterize,
    Hillshade,
    Contours,
    Footprints,
    Accuracy,
    ExportLas,
    ExportTiles,
    Qgis,
    Report,
]

#: The libraries whose versions shape the results (the manifest records them).
LIBRARIES = ("numpy", "scipy", "laspy", "lazrs", "rasterio", "pyproj", "pydantic", "contourpy", "pyogrio")


def versions() -> dict[str, str]:
    """The installed versions of :data:`LIBRARIES`, and GDAL's."""
    out = {}
    for name in LIBRARIES:
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    out["gdal"] = rasterio.__gdal_version__
    return out


#: The top-level ``crs`` key: the output CRS.
CRS_FIELD: tuple[Any, Any] = (
    Annotated[str, AfterValidator(check_crs_setting)],
    Field("auto-utm", description="output CRS: auto-utm (WGS 84 / UTM zone of the data) or e.g. EPSG:25830"),
)


def stages_plugin(name: str, commands: list[Any]) -> Plugin:
    """The whole plugin of *name* with its *commands*."""
    return Plugin(
        name=name,
        stages=list(STAGES),
        global_fields={"crs": CRS_FIELD},
        commands=commands,
        versions=versions,
        changed_areas=changed_areas,
        not_a_configuration=not_a_configuration,
        configuration_warnings=configuration_warnings,
    )
