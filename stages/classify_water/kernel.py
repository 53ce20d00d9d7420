"""Water classes for a tile: :mod:`stages.classify_water.water` on a tile's points, in a worker."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar import glossary
from lidar.tile_classes import PointTask
from stages.classify_water.params import ClassifyWaterParams
from stages.classify_water.water import (
    inside_polygons,
    water_from_points,
    water_from_polygons,
)
from stages.classify_water.water import (
    reach as detect_reach,
)

if TYPE_CHECKING:
    import laspy


def reach(params: ClassifyWaterParams) -> float:
    """The buffer (m) a tile needs for results equal to untiled ones: the larger of the two tests' reaches."""
    d = params.detect
    found = detect_reach(d.cell_size, d.window, d.min_area, d.grow) if d.enabled else 0.0
    given = params.polygon_window + d.cell_size + 1.0 if params.polygons is not None else 0.0
    return max(found, given)


def water_columns(chunk: laspy.ScaleAwarePointRecord) -> dict[str, np.ndarray]:
    """The columns the water tests need besides x, y, z (:func:`lidar.tile_points.split_cloud`)."""
    return {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }


def water_mask(
    xyz: np.ndarray, cls: np.ndarray, usable: np.ndarray, params: ClassifyWaterParams, polygons: list | None
) -> tuple[np.ndarray, np.ndarray]:
    """``(found, given)``: the points found to be water in the points, and those the polygons make water."""
    d = params.detect
    found = np.zeros(len(cls), dtype=bool)
    given = np.zeros(len(cls), dtype=bool)
    if d.enabled:
        found = water_from_points(
            xyz,
            cls,
            usable,
            cell_size=d.cell_size,
            window=d.window,
            min_points=d.min_points,
            max_slope=d.max_slope,
            max_rms=d.max_rms,
            step=d.step,
            min_area=d.min_area,
            grow=d.grow,
            tolerance=d.tolerance,
        )
    if polygons:
        inside = inside_polygons(xyz[:, :2], polygons)
        given = water_from_polygons(
            xyz, cls, usable, inside, cell_size=d.cell_size, window=params.polygon_window, height=params.polygon_height
        )
    return found, given


def water_tile(task: PointTask) -> dict:
    """One tile of the water tests (runs in a worker process): writes ``idx`` and ``classification`` of its core points.

    ``task.params``: the stage's parameters plus ``polygon_scale`` (metres
    per unit of the polygons' coordinates) when there are polygons.
    """
    from lidar.tile_points import read_column, read_xyz, write_result
    from lidar.vectors import read_polygons

    source = Path(task.source)
    extra = {k: task.params[k] for k in ("polygon_scale", "polygons_sha256") if k in task.params}
    params = ClassifyWaterParams.model_validate({k: v for k, v in task.params.items() if k not in extra})
    polygons = None
    if params.polygons is not None:
        scale = float(extra.get("polygon_scale", 1.0))
        polygons = [[ring * scale for ring in rings] for rings in read_polygons(params.polygons)[0]]
    xyz = read_xyz(source)
    cls = read_column(source, "classification")
    usable = glossary.usable(cls, read_column(source, "withheld"))
    found, given = water_mask(xyz, cls, usable, params, polygons)
    core = read_column(source, "core")
    idx = read_column(source, "idx")
    was_ground = cls == glossary.GROUND
    water = found | given
    changed = water & (cls != glossary.WATER)
    cls[water] = glossary.WATER
    write_result(Path(task.result), idx=idx[core], classification=cls[core])
    return {
        "tile": task.tile,
        "points": int(core.sum()),
        "water": int(water[core].sum()),
        "from_points": int(found[core].sum()),
        "from_polygons": int(given[core].sum()),
        "ground_to_water": int((water & was_ground)[core].sum()),
        "changed": int(changed[core].sum()),
    }
