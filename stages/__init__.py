"""The airborne LiDAR -> DTM stages, registered with the engine as one plugin.

Stage order (the natural order of the graph):
parse -> georeference (raw formats) -> strip_adjust -> denoise -> classify_ground -> rasterize -> hillshade, contours, accuracy;
export_las, export_tiles; report (last: it reads every stage's metrics).
"""

from __future__ import annotations

from pydantic import Field

from pipeline.stage import Plugin
from stages.accuracy import Accuracy
from stages.budget.command import BUDGET
from stages.classify import ClassifyGround
from stages.denoise import Denoise
from stages.dtm_tiles import ExportTiles
from stages.evaluate import EVALUATE
from stages.export import ExportLas
from stages.georeference import Georeference
from stages.info import INFO
from stages.parse import Parse, _check_crs
from stages.rasterize import Rasterize
from stages.report import Report
from stages.sim.command import SIMULATE
from stages.strip_adjust import StripAdjust
from stages.terrain import Contours, Hillshade


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
        Annotated[str, AfterValidator(_check_crs)],
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
