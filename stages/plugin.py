"""The airborne LiDAR -> DTM stages, registered with the engine as one plugin.

Stage order (the natural order of the graph):
parse -> georeference (raw formats) -> strip_adjust -> denoise -> classify_ground -> classify_water -> classify_objects -> rasterize -> hillshade, contours, footprints, accuracy;
export_las, export_tiles; report (last: it reads every stage's metrics).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from pipeline.discovery import LazyCommand, LazyPlugin

if TYPE_CHECKING:
    from pipeline.stage import Plugin


def _load() -> Plugin:
    """The whole plugin, its stages imported (:mod:`stages.catalogue`)."""
    from stages.catalogue import stages_plugin  # lazy: pipeline --help must not import the stages (start-up time)

    return stages_plugin(NAME, COMMANDS)


NAME = "dtm-pipeline"

#: The sub-commands: their arguments come from light modules, their code is
#: imported when they run.
COMMANDS = [
    LazyCommand(
        "init",
        "write a configuration for a folder of LAS/LAZ files (products next to it)",
        arguments="commands.init:add_arguments",
        run_with="commands.init:run",
    ),
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
        "error budget of the airborne LiDAR design: systems x flying height",
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
plugin = LazyPlugin(name=NAME, commands=COMMANDS, load=_load)
