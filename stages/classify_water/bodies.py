"""The water bodies of a classified file (its water points and the ground around them), and the points of those
taken for no water given back their class: the survey-wide steps after the tiles."""

from __future__ import annotations

from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

import laspy
import numpy as np
import shapely

from lidar import glossary
from lidar.clouds import chunk_xyz_metres, open_las_writer, progress_chunk
from lidar.water_bodies import CellLevels, CellMask, WaterBody, water_bodies
from stages.classify_water.params import ClassifyWaterParams
from stages.classify_water.water import inside_polygons

#: Points read at a time (fewer in a small file: :func:`~lidar.clouds.progress_chunk`).
CHUNK = 1_000_000
#: The most passes :func:`bodies_of` reads the file in: the water, then the ground and other points near it.
BODY_PASSES = 2

#: Told the points read or written (a progress figure's update), or None.
Advance = Callable[[int], object] | None


def _points(path: Path, units, keep, advance: Advance = None, classes: bool = False):
    """The points of the LAS *path* (metres) for which ``keep(classes, xyz)`` holds, read in chunks (*advance* told
    the points read); with *classes*, ``(points, their classes)``."""

    parts, kinds = [np.zeros((0, 3))], [np.zeros(0, dtype=np.uint8)]
    with laspy.open(str(path)) as reader:
        for chunk in reader.chunk_iterator(progress_chunk(reader.header.point_count, CHUNK)):
            xyz = chunk_xyz_metres(chunk, units)
            cls = np.asarray(chunk.classification)
            kept = glossary.usable(cls, chunk.withheld) & keep(cls, xyz)
            parts.append(np.ascontiguousarray(xyz[kept]))
            kinds.append(cls[kept])
            if advance is not None:
                advance(len(chunk))
    return (np.concatenate(parts), np.concatenate(kinds)) if classes else np.concatenate(parts)


def bodies_of(
    path: Path, units, params: ClassifyWaterParams, advance: Advance = None
) -> tuple[list[WaterBody], CellMask, CellLevels]:
    """The water bodies of the classified LAS *path*, the cells of those that are no water, and the levels of the
    cells bodies seen through dropouts grew into.

    :func:`lidar.water_bodies.water_bodies` on two passes: the water
    points, then the ground and other points within the water's box plus a
    margin.
    Without detection (polygons only) no body is refused for its banks.
    *advance* is told the points read, in up to :data:`BODY_PASSES` passes.
    """
    b = params.bodies
    water = _points(path, units, lambda cls, xyz: cls == glossary.WATER, advance)
    margin = (b.close + 4) * b.cell_size
    lo = water[:, :2].min(axis=0) - margin if len(water) else np.zeros(2)
    hi = water[:, :2].max(axis=0) + margin if len(water) else np.zeros(2)

    def near(cls, xyz):
        return np.all((xyz[:, :2] >= lo) & (xyz[:, :2] <= hi), axis=1) & (cls != glossary.WATER)

    # the ground and the other points around the water, in one pass
    around, cls = _points(path, units, near, advance, classes=True) if len(water) else (np.zeros((0, 3)), [])
    ground, others = around[cls == glossary.GROUND], around[cls != glossary.GROUND, :2]
    return water_bodies(
        water,
        ground,
        cell=b.cell_size,
        min_area=b.min_area,
        close=b.close,
        max_spread=b.max_spread,
        min_bank=params.detect.min_bank if params.detect.enabled else -np.inf,
        tolerance=params.detect.tolerance if params.detect.enabled else 0.0,
        others=others,
    )


def _rewrite_classes(dst: Path, units, change, src: Path | None = None, advance: Advance = None) -> None:
    """*dst* rewritten (through a temporary file) with each chunk's classes as ``change(classes, xyz, was)`` gives them.

    *classes*: the chunk's classes (a copy, for ``change`` to alter);
    *xyz*: its coordinates in metres; *was*: the same points' classes in
    *src* (None without one).  *advance* is told the points written.
    """

    tmp = dst.with_name(f".{dst.name}.tmp")
    with ExitStack() as files:
        after = files.enter_context(laspy.open(str(dst)))
        chunk_size = progress_chunk(after.header.point_count, CHUNK)
        out = files.enter_context(open_las_writer(tmp, after.header))
        olds = files.enter_context(laspy.open(str(src))).chunk_iterator(chunk_size) if src is not None else None
        for chunk in after.chunk_iterator(chunk_size):
            was = np.asarray(next(olds).classification) if olds is not None else None
            cls = np.asarray(chunk.classification).copy()
            chunk.classification = change(cls, chunk_xyz_metres(chunk, units), was)
            out.write_points(chunk)
            if advance is not None:
                advance(len(chunk))
    tmp.replace(dst)


def settle(
    src: Path,
    dst: Path,
    refused: CellMask,
    grown: CellLevels,
    units,
    polygons: list | None,
    advance: Advance = None,
) -> tuple[int, int, int]:
    """The water of *dst* settled by its bodies, in one rewrite (through a temporary file):

    - water points in *refused* cells (and outside the *polygons*, metres)
      get their class in *src* back, unless they were water there (the
      input's own);
    - ground points in the cells of a body seen through dropouts (*grown*),
      up to its echoes' reach above its level there (``CellLevels.water``), become water: ground
      cannot lie under water (a laser's echo from below a water surface is
      noise).

    *src* and *dst* hold the same points in the same order.  Returns the
    points given back, how many of them were ground, and the ground points
    that became water.
    """

    counts = [0, 0, 0]
    taking = bool(np.isfinite(grown.level).any())

    def change(cls, xyz, was):
        xy = xyz[:, :2]
        undo = (cls == glossary.WATER) & (was != glossary.WATER) & refused.holds(xy)  # the input's own water stays
        if polygons and undo.any():
            undo[undo] = ~inside_polygons(xy[undo], polygons)
        cls[undo] = was[undo]
        counts[0] += int(undo.sum())
        counts[1] += int((undo & (was == glossary.GROUND)).sum())
        if taking:
            ground = np.flatnonzero(cls == glossary.GROUND)
            take = ground[grown.water(xyz[ground])]
            cls[take] = glossary.WATER
            counts[2] += len(take)
        return cls

    _rewrite_classes(dst, units, change, src, advance)
    return counts[0], counts[1], counts[2]


def ignore_near_shores(dst: Path, bodies: list[WaterBody], distance: float, units, advance: Advance = None) -> int:
    """Ground points of *dst* within *distance* (m) of a flattened body's outline become ignored ground (20).

    The outlines are the hydro breaklines the DTM is flattened to: the
    ground points on them would pull the TIN across the shore (LBS class
    20, "breakline proximity").  *dst* is rewritten through a temporary
    file; returns the points changed.
    """

    shores = [shapely.Polygon(b.rings[0], b.rings[1:]).boundary for b in bodies if b.flat]
    if not shores or distance <= 0:
        return 0
    zone = shapely.union_all([line.buffer(distance) for line in shores])
    shapely.prepare(zone)
    x0, y0, x1, y1 = zone.bounds
    changed = [0]

    def change(cls, xyz, _):
        xy = xyz[:, :2]
        near = (cls == glossary.GROUND) & (xy[:, 0] >= x0) & (xy[:, 0] <= x1) & (xy[:, 1] >= y0) & (xy[:, 1] <= y1)
        if near.any():
            near[near] = shapely.contains_xy(zone, xy[near, 0], xy[near, 1])
            cls[near] = glossary.IGNORED_GROUND
            changed[0] += int(near.sum())
        return cls

    _rewrite_classes(dst, units, change, advance=advance)
    return changed[0]
