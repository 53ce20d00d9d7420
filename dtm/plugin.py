"""The airborne LiDAR -> DTM stages, registered with the engine as one plugin.

Stage order (the natural order of the graph):
parse -> georeference (raw formats) -> strip_adjust -> denoise -> classify_ground -> classify_water -> classify_objects -> rasterize -> hillshade, contours, footprints, accuracy;
export_las, export_tiles; report (last: it reads every stage's metrics).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from pipeline.discovery import LazyCommand, LazyPlugin

if TYPE_CHECKING:
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


def _crs_field() -> tuple[Any, Any]:
    from typing import Annotated

    from pydantic import AfterValidator, Field

    from dtm.common.crs import check_crs_setting

    return (
        Annotated[str, AfterValidator(check_crs_setting)],
        Field("auto-utm", description="output CRS: auto-utm (WGS 84 / UTM zone of the data) or e.g. EPSG:25830"),
    )


def _stages_plugin() -> Plugin:
    """The whole plugin: imports every stage (and with them NumPy, pydantic, SciPy, ...)."""
    from dtm.stages.accuracy.stage import Accuracy
    from dtm.stages.classify_ground.stage import ClassifyGround
    from dtm.stages.classify_objects.stage import ClassifyObjects
    from dtm.stages.classify_water.stage import ClassifyWater
    from dtm.stages.contours.stage import Contours
    from dtm.stages.denoise.stage import Denoise
    from dtm.stages.export_las.stage import ExportLas
    from dtm.stages.export_tiles.stage import ExportTiles
    from dtm.stages.footprints.stage import Footprints
    from dtm.stages.georeference.stage import Georeference
    from dtm.stages.hillshade.stage import Hillshade
    from dtm.stages.parse.stage import Parse
    from dtm.stages.rasterize.stage import Rasterize
    from dtm.stages.report.stage import Report
    from dtm.stages.strip_adjust.stage import StripAdjust
    from dtm.tile_plan import plan_tiles
    from pipeline.stage import Plugin

    return Plugin(
        name=NAME,
        stages=[
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
            Report,
        ],
        global_fields={"crs": _crs_field()},
        commands=COMMANDS,
        versions=_versions,
        plan_tiles=plan_tiles,
    )


NAME = "dtm-pipeline"

#: The sub-commands: their arguments come from light modules, their code is
#: imported when they run.
COMMANDS = [
    LazyCommand(
        "evaluate",
        "measure accuracy against reference data",
        arguments="dtm.commands.evaluate.arguments:add_arguments",
        run_with="dtm.commands.evaluate.command:run",
    ),
    LazyCommand(
        "info",
        "summarise LAS/LAZ files (header, CRS, points)",
        arguments="dtm.commands.info:add_arguments",
        run_with="dtm.commands.info:run",
    ),
    LazyCommand(
        "budget",
        "seed 2's error budget: systems x flying height",
        arguments="dtm.commands.budget.command:add_arguments",
        run_with="dtm.commands.budget.command:run",
    ),
    LazyCommand(
        "simulate",
        "write a simulated survey in every raw format, with its truth",
        arguments="dtm.commands.simulate.command:add_arguments",
        run_with="dtm.commands.simulate.command:run",
    ),
]

#: The plugin the entry point names: the parser is built from its name and
#: commands; its stages are imported on first use (``plugin.stages``).
plugin = LazyPlugin(name=NAME, commands=COMMANDS, load=_stages_plugin)
