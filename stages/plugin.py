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

    from lidar.crs import check_crs_setting

    return (
        Annotated[str, AfterValidator(check_crs_setting)],
        Field("auto-utm", description="output CRS: auto-utm (WGS 84 / UTM zone of the data) or e.g. EPSG:25830"),
    )


def _stages_plugin() -> Plugin:
    """The whole plugin: imports every stage (and with them NumPy, pydantic, SciPy, ...)."""
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
    from stages.parse.stage import Parse
    from stages.rasterize.stage import Rasterize
    from stages.report.stage import Report
    from stages.strip_adjust.stage import StripAdjust
    from stages.tile_plan import plan_tiles

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
        arguments="commands.evaluate.arguments:add_arguments",
        run_with="commands.evaluate.command:run",
    ),
    LazyCommand(
        "info",
        "summarise LAS/LAZ files (header, CRS, points)",
        arguments="commands.info:add_arguments",
        run_with="commands.info:run",
    ),
    LazyCommand(
        "budget",
        "seed 2's error budget: systems x flying height",
        arguments="commands.budget.command:add_arguments",
        run_with="commands.budget.command:run",
    ),
    LazyCommand(
        "simulate",
        "write a simulated survey in every raw format, with its truth",
        arguments="commands.simulate.command:add_arguments",
        run_with="commands.simulate.command:run",
    ),
]

#: The plugin the entry point names: the parser is built from its name and
#: commands; its stages are imported on first use (``plugin.stages``).
plugin = LazyPlugin(name=NAME, commands=COMMANDS, load=_stages_plugin)
