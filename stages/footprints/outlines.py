"""Building outlines and canopy height from a classified cloud on the DTM's grid.

Each building is a connected group (8-neighbour) of the DTM's cells holding
points of class 6, its one-cell gaps closed; its outline is the cells'
edge (GDAL's polygonize through rasterio) simplified within one cell
(Douglas-Peucker with topology kept, shapely), with its ground height (the
median DTM over its cells: the terrain the DTM interpolated beneath it), its
roof height (the median of its cells' highest points), its highest point
and its point count.  The canopy height is each cell's highest vegetation
point (classes 3, 4, 5) above the DTM.  Heights are in the CRS's unit.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import rasterio.features
import shapely
from scipy import ndimage

from lidar.arrays import add_counts
from lidar.grid import Grid, cell_of

BUILDING = 6
VEGETATION = (3, 4, 5)


@dataclass
class CellTally:
    """Per DTM cell, summed chunk by chunk: class-6 points and their highest z, the highest vegetation z."""

    roof_count: np.ndarray
    roof_top: np.ndarray
    canopy_top: np.ndarray

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> CellTally:
        size = shape[0] * shape[1]
        return cls(np.zeros(size, np.int32), np.full(size, -np.inf), np.full(size, -np.inf))

    def add(self, cell: np.ndarray, z: np.ndarray, cls_: np.ndarray) -> None:
        """Count the points of one chunk, their flat cell indices *cell* (-1: off the grid)."""
        on = cell >= 0
        roof = on & (cls_ == BUILDING)
        add_counts(self.roof_count, cell[roof])
        np.maximum.at(self.roof_top, cell[roof], z[roof])
        veg = on & np.isin(cls_, VEGETATION)
        np.maximum.at(self.canopy_top, cell[veg], z[veg])


def flat_cells(x: np.ndarray, y: np.ndarray, transform, shape: tuple[int, int]) -> np.ndarray:
    """Flat index of the DTM cell of each point (-1 off the grid); *transform* north-up (:func:`~lidar.grid.cell_of`)."""
    rows, cols = shape
    row, col = cell_of(np.column_stack((x, y)), Grid(transform.c, transform.f, transform.a, cols, rows))
    return np.where(row >= 0, row * cols + col, -1)


def building_labels(roof_count: np.ndarray) -> tuple[np.ndarray, int]:
    """Buildings as labels (1, 2, ...; 0 none) of the cells holding class-6 points, one-cell gaps closed."""
    has = roof_count > 0
    closed = ndimage.binary_closing(has, structure=np.ones((3, 3), bool)) | has
    return ndimage.label(closed, structure=np.ones((3, 3), bool))


def building_rows(labels: np.ndarray, count: int, tally: CellTally, dtm: np.ndarray, transform) -> dict:
    """The buildings' outlines (WKB MultiPolygons) and attributes, one per label, in label order."""
    if count == 0:
        empty = np.zeros(0)
        fields = {"ground_z": empty, "roof_z": empty, "highest_z": empty, "height": empty}
        return {"geometry": [], "fields": {**fields, "points": np.zeros(0, np.int64), "area": empty}}
    # the buildings' cells only (a few in a hundred): the statistics of the whole grids without its copies
    cells = np.flatnonzero(labels.ravel())
    label = labels.ravel()[cells]
    roof_count = tally.roof_count[cells]
    roof_top = np.where(roof_count > 0, tally.roof_top[cells], np.nan)
    index = np.arange(1, count + 1)
    with warnings.catch_warnings():  # a building wholly off the DTM (nodata under it): its ground_z is NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        ground = ndimage.labeled_comprehension(dtm.ravel()[cells], label, index, np.nanmedian, float, np.nan)
    roof = ndimage.labeled_comprehension(roof_top, label, index, np.nanmedian, float, np.nan)
    highest = ndimage.labeled_comprehension(roof_top, label, index, np.nanmax, float, np.nan)
    points = ndimage.sum(roof_count, label, index).astype(np.int64)
    parts: dict[int, list] = {}
    for geom, value in rasterio.features.shapes(
        labels.astype(np.int32, copy=False), mask=labels > 0, connectivity=8, transform=transform
    ):
        parts.setdefault(int(value), []).append(shapely.geometry.shape(geom))
    tolerance = abs(transform.a)
    wkb, area = [], []
    for k in index:
        shape_k = shapely.MultiPolygon([p.simplify(tolerance, preserve_topology=True) for p in parts[int(k)]])
        wkb.append(shapely.to_wkb(shape_k, byte_order=1))
        area.append(float(shape_k.area))
    return {
        "geometry": wkb,
        "fields": {
            "ground_z": ground,
            "roof_z": roof,
            "highest_z": highest,
            "height": roof - ground,
            "points": points,
            "area": np.asarray(area),
        },
    }


def canopy_height(tally: CellTally, dtm: np.ndarray, *, in_place: bool = False) -> np.ndarray:
    """Each cell's highest vegetation point above the DTM, at least 0 (NaN: no vegetation or no DTM).

    *in_place*: written over ``tally.canopy_top`` (no other grid of the
    survey's size: 100 MB at 100 M points).
    """
    top = tally.canopy_top.reshape(dtm.shape)
    known = np.isfinite(top) & np.isfinite(dtm)
    out = top if in_place else top.copy()
    np.subtract(out, dtm, out=out, where=known)
    np.maximum(out, 0.0, out=out)
    out[~known] = np.nan
    return out
