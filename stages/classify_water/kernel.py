"""``classify_water``'s work for the run service: level bodies of ground on the survey's grid, each point by its cells.

Pass 1 gathers, per cell, the lowest ground point and then the moments of
the ground points about it (:func:`~stages.classify_water.water.cell_moments`,
summed point by point in file order: those of all the points at once);
with polygons, the ground points inside them too.  A window's water cells
and levels are :func:`~stages.classify_water.water.planes_of` and the steps
after it; pass 2 gives each candidate point its water class by the cells
around its own (:func:`~stages.classify_water.water.near_level`).  The
classes are those of :func:`water_mask` on all the points at once.  Cells
hold ``[k c, (k + 1) c)`` on both axes; arrays run along x, then y, as
:func:`~stages.classify_water.water.cells_of` makes them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import ClassVar

import numpy as np

from lidar import glossary
from lidar.arrays import add_counts
from lidar.gridrun.kernel import Axis, Frame, StageKernel
from lidar.vectors import read_polygons
from stages.classify_water.params import ClassifyWaterParams
from stages.classify_water.water import (
    CANDIDATES,
    could_hold_level,
    in_cell,
    inside_polygons,
    level_and_mean,
    near_level,
    water_bodies,
    water_from_points,
    water_from_polygons,
)
from stages.classify_water.water import (
    reach as detect_reach,
)

#: The moments of each cell's ground points, as :func:`stages.classify_water.water.cell_moments` names them.
MOMENTS = ("x", "y", "z", "xx", "yy", "xy", "xz", "yz", "zz")


def reach(params: ClassifyWaterParams) -> float:
    """The buffer (m) a tile needs for results equal to untiled ones: the larger of the two tests' reaches."""
    d = params.detect
    found = detect_reach(d.cell_size, d.window, d.min_area, d.grow) if d.enabled else 0.0
    given = params.polygon_window + d.cell_size + 1.0 if params.polygons is not None else 0.0
    return max(found, given)


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


@cache
def polygons_in_metres(path: str, scale: float, digest: str) -> list:
    """The water polygons of the layer *path*, in metres (*scale*: metres per unit); *digest*: the layer's, a key."""
    return [[ring * scale for ring in rings] for rings in read_polygons(path)[0]]


@dataclass(frozen=True)
class WaterKernel(StageKernel):
    """The stage's parameters (*params*: their JSON dump) and its polygons' scale (m per unit) and digest."""

    params: dict
    polygon_scale: float = 1.0
    polygons_sha256: str = ""

    Params: ClassVar = ClassifyWaterParams
    counts: ClassVar = ("points", "water", "from_points", "from_polygons", "ground_to_water")
    axes: ClassVar = (Axis(0), Axis(1))  # along x, then y, as cells_of makes the grids
    passes: ClassVar = 2  # the cells' lowest ground points, then the moments about them

    @property
    def polygons(self) -> list | None:
        p = self.model.polygons
        return polygons_in_metres(str(p), self.polygon_scale, self.polygons_sha256) if p is not None else None

    @property
    def cell(self) -> float:
        return self.model.detect.cell_size

    @property
    def reach(self) -> float:
        return reach(self.model)

    @property
    def grow_cells(self) -> int:
        return math.ceil(self.model.detect.grow / self.cell - 1e-9)

    @property
    def polygon_half(self) -> int:
        return math.ceil(self.model.polygon_window / self.cell - 1e-9)

    @property
    def margin(self) -> int:
        return max(self.grow_cells, self.polygon_half if self.model.polygons is not None else 0)

    @property
    def grid_form(self) -> bool:
        return self.model.detect.enabled or self.model.polygons is not None

    def tested(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        return glossary.usable(cols["classification"], cols["withheld"]) & np.isin(cols["classification"], CANDIDATES)

    def classes(
        self, cols: dict[str, np.ndarray], tested: np.ndarray, values: np.ndarray
    ) -> tuple[np.ndarray, tuple[int, ...]]:
        """*values*: 1 found in the points, 2 given by the polygons, 3 both."""
        cls = cols["classification"].copy()
        found, given = np.zeros(len(cls), dtype=bool), np.zeros(len(cls), dtype=bool)
        found[tested], given[tested] = (values & 1) > 0, (values & 2) > 0
        water = found | given
        was_ground = cls == glossary.GROUND
        cls[water] = glossary.WATER
        counts = (len(cls), int(water.sum()), int(found.sum()), int(given.sum()), int((water & was_ground).sum()))
        return cls, counts

    def tile(self, xyz: np.ndarray, cols: dict[str, np.ndarray], tested: np.ndarray) -> np.ndarray:
        usable = glossary.usable(cols["classification"], cols["withheld"])
        found, given = water_mask(xyz, cols["classification"], usable, self.model, self.polygons)
        return (found[tested].astype(np.uint8) | (given[tested].astype(np.uint8) << 1)).astype(np.uint8)

    # the grid form: each cell's ground points

    def selected(self, cols: dict[str, np.ndarray]) -> np.ndarray:
        return glossary.usable(cols["classification"], cols["withheld"]) & (cols["classification"] == glossary.GROUND)

    def stats(self, size: int) -> dict[str, np.ndarray]:
        stats = {"low": np.full(size, np.inf), "n": np.zeros(size, np.int64)}
        stats.update({name: np.zeros(size) for name in MOMENTS})
        if self.model.polygons is not None:
            stats.update(inside_n=np.zeros(size, np.int64), inside_z=np.zeros(size))
        return stats

    def gather(self, stats: dict, step: int, k: np.ndarray, xyz: np.ndarray, cols: dict) -> None:
        z = xyz[:, 2]
        if step == 0:
            np.minimum.at(stats["low"], k, z)
            return
        low = stats["low"]
        base = np.floor(np.where(np.isfinite(low[k]), low[k], 0.0))  # whole metres: exact differences
        u, v, r = in_cell(xyz[:, 0], self.cell), in_cell(xyz[:, 1], self.cell), z - base
        add_counts(stats["n"], k)
        for name, values in (("x", u), ("y", v), ("z", r)):
            np.add.at(stats[name], k, values)
        for name, (a, b) in {
            "xx": (u, u),
            "yy": (v, v),
            "xy": (u, v),
            "xz": (u, r),
            "yz": (v, r),
            "zz": (r, r),
        }.items():
            np.add.at(stats[name], k, a * b)
        if self.model.polygons is not None:
            inside = inside_polygons(xyz[:, :2], self.polygons)
            add_counts(stats["inside_n"], k[inside])
            np.add.at(stats["inside_z"], k[inside], z[inside])

    def occupied(self, stats: dict[str, np.ndarray]) -> np.ndarray:
        return np.isfinite(stats["low"])

    def window(self, stats: dict[str, np.ndarray], frame: Frame, threads: int = 1) -> dict[str, np.ndarray]:
        d, cell = self.model.detect, self.cell
        half = max(1, math.ceil(d.window / cell - 1e-9))
        min_cells = d.min_area / cell**2
        water = np.zeros(frame.shape, dtype=bool)
        mean = np.full(frame.shape, np.nan)
        if d.enabled and could_hold_level(stats["n"], half, d.min_points, min_cells):
            level, mean = level_and_mean(
                {"n": stats["n"], **{m: stats[m] for m in MOMENTS}},
                stats["low"],
                cell=cell,
                half=half,
                min_points=d.min_points,
                max_slope=d.max_slope,
                max_rms=d.max_rms,
            )
            water = water_bodies(level, mean, step=d.step, min_cells=min_cells)
        results = {"water": water, "mean": mean}
        if self.model.polygons is not None:
            n = stats["inside_n"]
            results["inside_mean"] = np.where(n > 0, stats["inside_z"] / np.maximum(n, 1), np.nan)
        return results

    def unchanged(self, results: dict[str, np.ndarray] | None) -> bool:
        if results is None:
            return True
        return not results["water"].any() and not np.isfinite(results.get("inside_mean", np.nan)).any()

    def values(self, xyz: np.ndarray, cols: dict, results: dict | None, frame: Frame | None) -> np.ndarray:
        out = np.zeros(len(xyz), dtype=np.uint8)
        if results is None or not len(xyz):
            return out
        i, j = frame.indices(xyz)
        r = self.grow_cells
        near = (i >= -r) & (i < frame.shape[0] + r) & (j >= -r) & (j < frame.shape[1] + r)
        if results["water"].any() and near.any():  # cells beyond the frame hold no water: padded with none
            water, mean = np.pad(results["water"], r), np.pad(results["mean"], r, constant_values=np.nan)
            out[near] = near_level(i[near] + r, j[near] + r, xyz[near, 2], water, mean, r, self.model.detect.tolerance)
        if "inside_mean" in results:
            out |= self._given(xyz, i, j, results["inside_mean"]).astype(np.uint8) << 1
        return out

    def _given(self, xyz: np.ndarray, i: np.ndarray, j: np.ndarray, inside_mean: np.ndarray) -> np.ndarray:
        """Candidates inside the polygons within ``polygon_height`` of the lowest ground inside them within the window."""
        h = self.polygon_half
        given = np.zeros(len(xyz), dtype=bool)
        ok = (i >= -h) & (i < inside_mean.shape[0] + h) & (j >= -h) & (j < inside_mean.shape[1] + h)
        ok[ok] = inside_polygons(xyz[ok, :2], self.polygons)
        if not ok.any():
            return given
        padded = np.pad(inside_mean, 2 * h, constant_values=np.nan)
        ii, jj = i[ok] + 2 * h, j[ok] + 2 * h
        level = np.full(len(ii), np.nan)
        for a in range(-h, h + 1):
            for b in range(-h, h + 1):
                level = np.fmin(level, padded[ii + a, jj + b])
        with np.errstate(invalid="ignore"):
            given[ok] = np.abs(xyz[ok, 2] - level) <= self.model.polygon_height
        return given
