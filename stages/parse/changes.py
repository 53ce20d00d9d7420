"""Where the changed input files lie, for the dry run's count of the tiles a re-run will run (:mod:`pipeline.replan`).

Before a run, a changed file is known by its bounds: its header's now, and
the last run's ``qc/input_files.csv`` for the file as it was, both in
metres of the last run's CRS (its DTM's).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pyproj
import rasterio

from lidar.input_files import read_input_files_csv
from lidar.las_guard import header_mins_maxs, open_las
from lidar.units import Units
from pipeline.replan import ChangedAreas
from stages.parse.las_index import file_crs


def changed_areas(config: Any, changed: dict[str, str], previous: dict[str, Any], output: Path) -> ChangedAreas | None:
    """The changed LAS/LAZ files of *changed* and their bounds; None for other inputs or when none is left to place.

    *changed*: input path -> "changed", "new" or "removed" against the last
    run's ``run.json`` (*previous*) in *output*.
    """
    if getattr(config.input, "format", None) != "las":
        return None
    index = Path(output) / "qc" / "input_files.csv"
    rows = {r["path"]: r for r in read_input_files_csv(index)} if index.is_file() else {}
    files = {p: how for p, how in changed.items() if how != "removed" or p in rows}
    if not files:
        return None
    boxes, unknown = _boxes(config, files, rows, Path(output) / "dtm.tif")
    return ChangedAreas(files, boxes, unknown)


def _boxes(
    config: Any, files: dict[str, str], rows: dict[str, dict], dtm: Path
) -> tuple[list[tuple[float, ...]], str | None]:
    """The changed files' bounds now and as they were, in metres of the last run's CRS; or why they are unknown."""
    if not rows or not dtm.is_file():
        return [], "no earlier run to compare"
    with rasterio.open(dtm) as src:
        target = pyproj.CRS.from_wkt(src.crs.to_wkt())
    metres = Units.of(target).horizontal
    inp = config.input
    assign = pyproj.CRS.from_user_input(inp.crs) if inp.crs else None
    override = pyproj.CRS.from_user_input(inp.override_crs) if inp.override_crs else None
    boxes = []
    for path, how in files.items():
        crs = None
        if how != "removed":
            with open_las(Path(path)) as reader:
                crs, _ = file_crs(Path(path), reader.header, assign, override)
                boxes.append(_in(target, crs, *header_mins_maxs(reader.header), metres))
        if how != "new":
            row = rows[path]
            if crs is None or crs.name != row["crs"]:
                if row["crs"] != target.name:
                    return [], f"{Path(path).name} was in another CRS"
                crs = target
            mins = [float(row[k]) for k in ("xmin", "ymin", "zmin")]
            maxs = [float(row[k]) for k in ("xmax", "ymax", "zmax")]
            boxes.append(_in(target, crs, mins, maxs, metres))
    return boxes, None


def _in(target: Any, crs: Any, mins: Any, maxs: Any, metres: float) -> tuple[float, ...]:
    if not crs.equals(target):
        t = pyproj.Transformer.from_crs(crs, target, always_xy=True)
        box = t.transform_bounds(mins[0], mins[1], maxs[0], maxs[1], densify_pts=21)
    else:
        box = (mins[0], mins[1], maxs[0], maxs[1])
    return tuple(float(v) * metres for v in box)
