"""Render the configuration reference (docs/CONFIG.md) from the models.

    python -m commands.configdoc > docs/CONFIG.md

A test checks that the committed file matches, so every key and default in
the documentation is the one the code uses.
"""

from __future__ import annotations

import typing
from typing import Any

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from commands.simulate.settings import SimulateConfig
from pipeline.config import field_models
from pipeline.discovery import load_plugin
from pipeline.registry import RegistryField, RegistryName
from pipeline.stage import config_model

HEADER = """# Configuration reference

Generated from the code by `python -m commands.configdoc > docs/CONFIG.md`
(a test fails when this file is stale).  Every relative path is resolved
against the folder of the configuration file.  Linear quantities are in
metres whatever the output CRS's unit (products are written in that unit:
docs/CONVENTIONS.md).  Any key can be
overridden from the command line: `--set stages.rasterize.resolution=0.5`.

| key | type | default | meaning |
|---|---|---|---|
"""


def _type_name(annotation: Any) -> str:
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _type_name(typing.get_args(annotation)[0])
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return "mapping"
    if origin is typing.Literal:
        return " \\| ".join(repr(a).replace("'", "") for a in typing.get_args(annotation))
    if origin is list:
        return f"list of {_type_name(typing.get_args(annotation)[0])}"
    if origin is tuple:
        args = typing.get_args(annotation)
        return f"list of {len(args)} {_type_name(args[0])}"
    args = typing.get_args(annotation)
    if args:
        return " or ".join(_type_name(a) for a in args)
    return (
        getattr(annotation, "__name__", str(annotation))
        .replace("NoneType", "null")
        .replace("PosixPath", "path")
        .replace("Path", "path")
    )


def _default(field) -> str:
    if field.is_required():
        return "**required**"
    if field.default_factory is not None:
        name = getattr(field.default_factory, "__name__", "")
        if name == "<lambda>":
            try:
                value = field.default_factory()
            except TypeError:
                return "(computed)"
            if isinstance(value, BaseModel):
                return "see below"
            return "number of CPU cores" if isinstance(value, int) else f"`{value}`"
        return "see below"
    if field.default is PydanticUndefined:
        return ""
    return f"`{field.default}`" if field.default is not None else "none"


def _rows(model: type[BaseModel], prefix: str) -> list[str]:
    rows = []
    for name, field in model.model_fields.items():
        key = f"{prefix}{name}"
        registry = next((m.registry for m in field.metadata if isinstance(m, RegistryField)), None)
        desc = (field.description or "").replace("|", "\\|")
        if registry is not None:  # one of the registered algorithms: each with its parameters
            desc += "; `name`: " + " \\| ".join(registry.names())
            default = f"`{{name: {field.default_factory().name}}}`" if field.default_factory else _default(field)
            rows.append(f"| `{key}` | mapping | {default} | {desc} |")
            for entry in registry:
                rows.append(f"| `{key}.({entry.name})` | | | {entry.summary} |")
                rows.extend(_rows(entry.params, f"{key}.({entry.name}).")[1:])  # its name row said above
            continue
        names = next((m.registry for m in field.metadata if isinstance(m, RegistryName)), None)
        kind = " \\| ".join(names.names()) if names is not None else _type_name(field.annotation)
        rows.append(f"| `{key}` | {kind} | {_default(field)} | {desc} |")
        models = field_models(field)
        for sub in models:
            sub_prefix = f"{key}." if len(models) == 1 else f"{key}.({sub.__name__})."
            rows.extend(_rows(sub, sub_prefix))
    return rows


def render() -> str:

    return HEADER + "\n".join(_rows(config_model(load_plugin()), "")) + "\n"


SIMULATOR_HEADER = """# Simulator configuration reference

Generated from the models in `commands/simulate/settings.py` by
`python -m commands.configdoc --simulator > docs/SIMULATOR.md`; a test fails
when this page is stale.

`pipeline simulate CONFIG [--out DIR] [--only NAME] [--set key=value ...]`
writes one survey, or several under `surveys: {name: {...}}` (as
`configs/simulate.yaml` does), each to its own `output`:

| file | what |
|---|---|
| `ldmrs/acquisition.log.gz` | format 3.A (LD-MRS + MTi-G log, gzip) |
| `lmsq/scan.lmsq`, `lmsq/nav.nmea`, `lmsq/ins.csv` | format 3.B |
| `lmsq/trajectory.sbet`, `lmsq/trajectory.smrmsg` | format 3.C (same scanner stream) |
| `las/points.laz` | format 3.D: the echoes georeferenced from the recorded navigation |
| `truth/points.laz` | every echo at its true position: `gps_time`, return number/count, `scanner_channel`, `scan_angle`, `point_source_id` = flight line (0 off the lines), class (2 ground, 5 vegetation, 6 building, 7 noise, 9 water, 17 bridge; the scene stands a wall as a one-cell ramp between a low and a high cell, and an echo on it more than 0.1 m up is the high cell's: a building's wall is 6, a deck's 1 m thick side 17, and below that what lies under the deck), extra byte `fault` (0 none, 1 invalid scan, 2 bad GPS, 3 clutter, 4 dirt, 5 after a missed PPS (dated by the µs counter: kept), 6 invalid quality, 7 dust) |
| `truth/terrain.tif` | the bare earth in the output CRS (ellipsoidal heights; water surface over water) |
| `truth/land_cover.tif` | what covers the bare earth on the same cells (uint8 ASPRS codes: 2 open ground, 5 tree crowns more than 0.5 m above the solid surface, 6 building, 9 water, 17 bridge deck; 0 outside the scene); `stages.accuracy.truth_land_cover` splits the DTM-against-truth figures by it |
| `truth/breaklines.gpkg` | the river's two true shores (GeoPackage 1.2, LineString Z, field `shore`: south, north), a vertex every 0.5 m at the water's height (falling eastwards by 0.3 %, under the bridge too); `benchmarks/flight_truth.py` measures the run's `breaklines.gpkg` against them |
| `truth/faults.json` | every injected fault with its count as written, systematic errors, per-line GNSS biases |
| `checkpoints.csv` | check points on the true terrain (open and under trees; none within 5 m of structures, water, breaklines or slopes over 20 %) |

Truth and measurements: the scene lives in a local east-north-up frame
tangent to WGS 84 at `origin` (an exact rigid transform of ECEF); rays are
cast there from the true pose (cubic spline of the flown path) and the true
mounting (configured + `faults.*_error_*`); truth points go to the output
CRS through PROJ point by point.  The simulator's geometry is its own
(`commands/simulate/forward.py`: scipy rotations, PROJ's geodetic and topocentric
conversions; the 3.D LAS is georeferenced there too): it shares no code with
`stages/georeference`, so the two check each other.  Navigation errors are smooth and
stationary (sums of random-phase cosines, periods 20–100 s for position,
5–25 s for attitude by default: `navigation.error_period_s`) with the preset's sigma at every instant, plus the
per-line biases; `noise_seed` redraws the noise alone.  Times are GPS seconds; UTC-stamped
files use `leap_seconds`.

| key | type | default | description |
|---|---|---|---|
"""


def render_simulator() -> str:

    return SIMULATOR_HEADER + "\n".join(_rows(SimulateConfig, "")) + "\n"


if __name__ == "__main__":
    import sys

    print(render_simulator() if "--simulator" in sys.argv else render(), end="")
