"""How many tiles a re-run will run, said by ``pipeline run --dry-run`` before anything runs.

A re-run after input files changed runs again only the tiles whose core
plus buffer reaches a changed item (:class:`pipeline.cache.TileCache`).
Before the run, the changed items are known only by their files' bounds,
which the plugin gives (:class:`ChangedAreas`).  Each tiled stage's changes
spread by its reach (its tile buffer) to the tiled stages after it, so the
count is an upper bound ("at most").  The layout is the last run's (its
extent, tile size and buffer, from ``run.json``), widened to the changed
areas.  A stage that spreads a change over the whole survey
(:meth:`pipeline.stage.Stage.spreads_changes`) makes every tile count.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from pipeline.tiling import Layout


@dataclass(frozen=True)
class ChangedAreas:
    """What the plugin knows of the changed input files before reading them.

    *files*: path -> "changed", "new" or "removed"; *boxes*: their extents
    ``(xmin, ymin, xmax, ymax)`` now and as they were, in the unit the
    stages tile in; *unknown*: why they cannot be placed (then every tile
    counts), None when they can.
    """

    files: dict[str, str]
    boxes: list[tuple[float, ...]]
    unknown: str | None = None


@dataclass(frozen=True)
class PlannedStage:
    """A stage of the re-run: its name, whether it works tile by tile, and why it spreads a change everywhere."""

    name: str
    tiled: bool
    spreads: str | None = None


def tile_notes(stages: Sequence[PlannedStage], areas: ChangedAreas, previous: dict[str, Any]) -> dict[str, str]:
    """The dry run's note per tiled stage: ``{"rasterize": "at most 4 of 72 (1 file changed)", ...}``.

    *stages*: the enabled stages in the graph's order; *previous*: the last
    run's ``run.json``.
    """
    said = _said(areas.files)
    records = {s["name"]: s for s in previous.get("stages", [])}
    everywhere = next((s.spreads for s in stages if s.spreads), None) or areas.unknown
    notes, reach = {}, 0.0
    for stage in (s for s in stages if s.tiled):
        record = records.get(stage.name, {})
        tiling = record.get("metrics", {}).get("tiling")
        if everywhere:
            notes[stage.name] = f"all ({said}; {everywhere})"
        elif tiling is None or "extent" not in tiling:
            notes[stage.name] = f"the whole survey at once, as in the last run ({said})"
        else:
            notes[stage.name] = f"at most {_touched(tiling, areas.boxes, reach)} ({said})"
        reach += float(record.get("tile_buffer") or 0.0)
    return notes


def _said(files: dict[str, str]) -> str:
    counts = {how: sum(1 for h in files.values() if h == how) for how in ("changed", "new", "removed")}
    return ", ".join(f"{n} file{'s' if n > 1 else ''} {how}" for how, n in counts.items() if n)


def _touched(tiling: dict, boxes: list[tuple[float, ...]], reach: float) -> str:
    """ "N of M": the tiles of the last run's layout (widened to *boxes*) whose core plus buffer meets a box grown by *reach*."""
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
