"""How many tiles a re-run will run, said by ``pipeline run --dry-run`` before anything runs.

A re-run after input files changed runs again only the tiles whose core
plus buffer reaches a changed point (:class:`pipeline.cache.TileCache`).
Before the run, the changed points are known only by their files' bounds:
the header's now, and the last run's ``qc/input_files.csv`` for the file as
it was.  Each tiled stage's changes spread by its reach (its buffer) to the
stages after it, so the count is an upper bound ("at most").  The layout is
the last run's (its extent, tile size and buffer, from ``run.json``),
widened to the new files.  Strip adjustment fits whole strips, so one file
may change every tile: with it on, every tile is counted.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

#: The stages that keep their tiles, in the order of the graph.  ``classify_water`` also judges whole water
#: bodies after its tiles: a change that reaches a body may change it beyond the reach counted here.
TILED = ("denoise", "classify_ground", "classify_water", "classify_objects", "rasterize")


def plan_tiles(config: Any, changed: dict[str, str], previous: dict[str, Any], output: Path) -> dict[str, str]:
    """The dry run's note per tiled stage: ``{"rasterize": "at most 4 of 72 (1 file changed)", ...}``.

    *changed*: input path -> "changed", "new" or "removed" against the last
    run's ``run.json`` (*previous*) in *output*.
    """
    if getattr(config.input, "format", None) != "las":
        return {}
    from stages.parse.las_index import read_input_files_csv

    index = Path(output) / "qc" / "input_files.csv"
    rows = {r["path"]: r for r in read_input_files_csv(index)} if index.is_file() else {}
    files = {p: how for p, how in changed.items() if how != "removed" or p in rows}
    if not files:
        return {}
    said = _said(files)
    boxes, unknown = _boxes(config, files, rows, Path(output) / "dtm.tif")
    stages = {s["name"]: s for s in previous.get("stages", [])}
    strips = getattr(getattr(config.stages, "strip_adjust", None), "enabled", False) and (
        stages.get("strip_adjust", {}).get("metrics", {}).get("strips_adjusted", 1) != 0
    )
    notes, reach = {}, 0.0
    for name in TILED:
        record = stages.get(name, {})
        tiling = record.get("metrics", {}).get("tiling")
        if not getattr(getattr(config.stages, name), "enabled", True):
            continue
        if strips or unknown:
            why = "strip adjustment fits whole strips" if strips else unknown
            notes[name] = f"all ({said}; {why})"
        elif tiling is None or "extent" not in tiling:
            notes[name] = f"the whole survey at once, as in the last run ({said})"
        else:
            notes[name] = f"at most {_touched(tiling, boxes, reach)} ({said})"
        reach += float(record.get("tile_buffer") or 0.0)
    return notes


def _said(files: dict[str, str]) -> str:
    counts = {how: sum(1 for h in files.values() if h == how) for how in ("changed", "new", "removed")}
    return ", ".join(f"{n} file{'s' if n > 1 else ''} {how}" for how, n in counts.items() if n)


def _boxes(
    config: Any, files: dict[str, str], rows: dict[str, dict], dtm: Path
) -> tuple[list[tuple[float, ...]], str | None]:
    """The changed files' bounds now and as they were, in metres of the last run's CRS; or why they are unknown."""
    import pyproj

    from lidar.las_guard import header_mins_maxs, open_las
    from lidar.units import Units
    from stages.parse.read_las import file_crs

    if not rows or not dtm.is_file():
        return [], "no earlier run to compare"
    import rasterio

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
        import pyproj

        t = pyproj.Transformer.from_crs(crs, target, always_xy=True)
        box = t.transform_bounds(mins[0], mins[1], maxs[0], maxs[1], densify_pts=21)
    else:
        box = (mins[0], mins[1], maxs[0], maxs[1])
    return tuple(float(v) * metres for v in box)


def _touched(tiling: dict, boxes: list[tuple[float, ...]], reach: float) -> str:
    """ "N of M": the tiles of the last run's layout (widened to *boxes*) whose core plus buffer meets a box grown by *reach*."""
    from pipeline.tiling import Layout

    x0, y0, x1, y1 = tiling["extent"]
    for b in boxes:
        x0, y0, x1, y1 = min(x0, b[0]), min(y0, b[1]), max(x1, b[2]), max(y1, b[3])
    layout = Layout.of((x0, y0, x1, y1), tiling["size"], float(tiling["buffer"]))
    grow = reach + layout.buffer
    touched = sum(
        1
        for t in layout.tiles
        if any(
            b[0] - grow < t.xmax and t.xmin <= b[2] + grow and b[1] - grow < t.ymax and t.ymin <= b[3] + grow
            for b in boxes
        )
    )
    return f"{touched} of {len(layout)} tiles"
