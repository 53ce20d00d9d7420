"""The airborne LiDAR -> DTM stages, registered with the engine as one plugin.

Stage order (the natural order of the graph):
parse -> georeference (raw formats) -> strip_adjust -> denoise -> classify_ground -> rasterize -> hillshade, contours, accuracy;
export_las, export_tiles; report (last: it reads every stage's metrics).
"""

from __future__ import annotations

from pydantic import Field

from dtm.commands.budget.command import BUDGET
from dtm.commands.evaluate.command import EVALUATE
from dtm.commands.info import INFO
from dtm.commands.simulate.command import SIMULATE
from dtm.common.crs import check_crs_setting
from dtm.stages.accuracy.stage import Accuracy
from dtm.stages.classify_ground.stage import ClassifyGround
from dtm.stages.contours.stage import Contours
from dtm.stages.denoise.stage import Denoise
from dtm.stages.export_las.stage import ExportLas
from dtm.stages.export_tiles.stage import ExportTiles
from dtm.stages.georeference.stage import Georeference
from dtm.stages.hillshade.stage import Hillshade
from dtm.stages.parse.stage import Parse
from dtm.stages.rasterize.stage import Rasterize
from dtm.stages.report.stage import Report
from dtm.stages.strip_adjust.stage import StripAdjust
from pipeline.stage import Plugin


def _versions() -> dict[str, str]:
    from importlib.metadata import PackageNotFoundError, version

    out = {}
    for name in ("numpy", "scipy", "laspy", "lazrs", "rasterio", "pyproj", "pydantic", "contourpy", "pyogrio"):
        try:
            out[name] = version(name)
        except PackageNotFoundError:
            pass
    try:
        import rasterio

        out["gdal"] = rasterio.__gdal_version__
    except ImportError:
        pass
    return out


def _crs_field():
    from typing import Annotated

    from pydantic import AfterValidator

    return (
        Annotated[str, AfterValidator(check_crs_setting)],
        Field("auto-utm", description="output CRS: auto-utm (WGS 84 / UTM zone of the data) or e.g. EPSG:25830"),
    )


plugin = Plugin(
    name="dtm-pipeline",
    stages=[
        Parse,
        Georeference,
        StripAdjust,
        Denoise,
        ClassifyGround,
        Rasterize,
        Hillshade,
        Contours,
        Accuracy,
        ExportLas,
        ExportTiles,
        Report,
    ],
    global_fields={"crs": _crs_field()},
    commands=[EVALUATE, INFO, BUDGET, SIMULATE],
    versions=_versions,
)
