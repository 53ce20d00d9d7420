"""The water bodies of a classified file (its water points and the ground around them), and the points of those
taken for no water given back their class: the survey-wide steps after the tiles."""

from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

import laspy
import numpy as np
import shapely

from lidar import glossary
from lidar.clouds import chunk_xyz_metres, open_las_writer
from lidar.water_bodies import CellLevels, CellMask, WaterBody, water_bodies
from stages.classify_water.params import ClassifyWaterParams
from stages.classify_water.water import inside_polygons

#: Points read at a time.
CHUNK = 1_000_000


def _points(path: Path, units, keep) -> np.ndarray:
    """The points of the LAS *path* (metres) for which ``keep(classes, xyz)`` holds, read in chunks."""

    parts = [np.zeros((0, 3))]
    with laspy.open(str(path)) as reader:
        for chunk in reader.chunk_iterator(CHUNK):
            xyz = chunk_xyz_metres(chunk, units)
            cls = np.asarray(chunk.classification)
            usable = glossary.usable(cls, chunk.withheld)
            parts.append(np.ascontiguousarray(xyz[usable & keep(cls, xyz)]))
    return np.concatenate(parts)


def bodies_of(path: Path, units, params: ClassifyWaterParams) -> tuple[list[WaterBody], CellMask, CellLevels]:
    """The water bodies of the classified LAS *path*, the cells of those that are no water, and the levels of the
    cells bodies seen through dropouts grew into.

    :func:`lidar.water_bodies.water_bodies` on two passes: the water
    points, then the ground points within the water's box plus a margin.
    Without detection (polygons only) no body is refused for its banks.
    """
    b = params.bodies
    water = _points(path, units, lambda cls, xyz: cls == glossary.WATER)
    margin = (b.close + 4) * b.cell_size
    lo = water[:, :2].min(axis=0) - margin if len(water) else np.zeros(2)
    hi = water[:, :2].max(axis=0) + margin if len(water) else np.zeros(2)

    def near(cls, xyz):
        return (cls == glossary.GROUND) & np.all((xyz[:, :2] >= lo) & (xyz[:, :2] <= hi), axis=1)

    ground = _points(path, units, near) if len(water) else np.zeros((0, 3))

    def other(cls, xyz):
        inside = np.all((xyz[:, :2] >= lo) & (xyz[:, :2] <= hi), axis=1)
        return inside & (cls != glossary.GROUND) & (cls != glossary.WATER)

    others = _points(path, units, other)[:, :2] if len(water) else np.zeros((0, 2))
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


def _rewrite_classes(dst: Path, units, change, src: Path | None = None) -> None:
    """*dst* rewritten (through a temporary file) with each chunk's classes as ``change(classes, xyz, was)`` gives them.

    *classes*: the chunk's classes (a copy, for ``change`` to alter);
    *xyz*: its coordinates in metres; *was*: the same points' classes in
    *src* (None without one).
    """

    tmp = dst.with_name(f".{dst.name}.tmp")
    with ExitStack() as files:
        after = files.enter_context(laspy.open(str(dst)))
        out = files.enter_context(open_las_writer(tmp, after.header))
        olds = files.enter_context(laspy.open(str(src))).chunk_iterator(CHUNK) if src is not None else None
        for chunk in after.chunk_iterator(CHUNK):
            was = np.asarray(next(olds).classification) if olds is not None else None
            cls = np.asarray(chunk.classification).copy()
            chunk.classification = change(cls, chunk_xyz_metres(chunk, units), was)
            out.write_points(chunk)
    tmp.replace(dst)


def give_back(src: Path, dst: Path, refused: CellMask, units, polygons: list | None) -> tuple[int, int]:
    """Water points of *dst* in *refused* cells (and outside the *polygons*, metres) get their class in *src* back.

    Points that were water in *src* (the input's own) are not given back.

    *src* and *dst* hold the same points in the same order; *dst* is
    rewritten (through a temporary file).  Returns the points given back
    and how many of them were ground.
    """

    counts = [0, 0]

    def change(cls, xyz, was):
        xy = xyz[:, :2]
        undo = (cls == glossary.WATER) & (was != glossary.WATER) & refused.holds(xy)  # the input's own water stays
        if polygons and undo.any():
            undo[undo] = ~inside_polygons(xy[undo], polygons)
        cls[undo] = was[undo]
        counts[0] += int(undo.sum())
        counts[1] += int((undo & (was == glossary.GROUND)).sum())
        return cls

    _rewrite_classes(dst, units, change, src)
    return counts[0], counts[1]


def take_unseen(dst: Path, grown: CellLevels, tolerance: float, units) -> int:
    """Ground points of *dst* in the cells of a body seen through dropouts, up to *tolerance* (m) above its level
    there, become water: ground cannot lie under water (a laser's echo from below a water surface is noise).

    *dst* is rewritten (through a temporary file); returns the points changed.
    """
    if not np.isfinite(grown.level).any():
        return 0
    changed = [0]

    def change(cls, xyz, _):
        ground = np.flatnonzero(cls == glossary.GROUND)
        level = grown.at(xyz[ground, :2])
        take = ground[xyz[ground, 2] - level <= tolerance]  # NaN (no body) compares False
        cls[take] = glossary.WATER
        changed[0] += len(take)
        return cls

    _rewrite_classes(dst, units, change)
    return changed[0]


def ignore_near_shores(dst: Path, bodies: list[WaterBody], distance: float, units) -> int:
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

    _rewrite_classes(dst, units, change)
    return changed[0]
