"""Water bodies: outlines of the water points with one level each, written and read as a GeoPackage, burnt into grids.

``classify_water`` makes them (:func:`water_bodies` on its water and ground
points, :func:`write_water_bodies`); ``rasterize`` flattens the DTM inside
them (:func:`read_water_bodies`, :func:`burn_levels`).  Method and
thresholds: docs/stages/classify_water.md, "Water bodies and
hydro-flattening".
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: The layer's name in ``water.gpkg``.
LAYER = "water_bodies"


@dataclass(frozen=True)
class WaterBody:
    """One water body's polygon: rings (outer first, (n, 2), metres), level (m), area (m2), the body's points and
    height spread (m); a body whose cells touch only at corners has one polygon per part, each with its figures.

    ``flat``: its water points span at most the flatness limit, so the DTM
    is flattened at ``level`` inside it.
    """

    rings: list[np.ndarray]
    level: float
    area: float
    points: int
    spread: float
    flat: bool


def _ring_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _cells(xy: np.ndarray, cell: float, lo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row (north down) and column of each point on a grid of *cell* whose upper-left corner is *lo* (x0, y1)."""
    col = np.floor((xy[:, 0] - lo[0]) / cell).astype(np.int64)
    row = np.floor((lo[1] - xy[:, 1]) / cell).astype(np.int64)
    return row, col


@dataclass(frozen=True)
class CellMask:
    """Cells of *cell* metres on a grid whose upper-left corner is *corner* (x0, y1): :meth:`holds` tells points in."""

    corner: tuple[float, float]
    cell: float
    mask: np.ndarray

    def holds(self, xy: np.ndarray) -> np.ndarray:
        """Which points (metres) lie in a masked cell."""
        row, col = _cells(xy, self.cell, np.asarray(self.corner))
        inside = (row >= 0) & (row < self.mask.shape[0]) & (col >= 0) & (col < self.mask.shape[1])
        out = np.zeros(len(xy), dtype=bool)
        out[inside] = self.mask[row[inside], col[inside]]
        return out


def water_bodies(
    water: np.ndarray,
    ground: np.ndarray,
    *,
    cell: float,
    min_area: float,
    close: int,
    max_spread: float,
    min_bank: float,
) -> tuple[list[WaterBody], CellMask]:
    """The water bodies of the water points *water* ((n, 3), metres), with the ground points *ground* around them.

    Cells of *cell* (anchored at whole multiples) holding a water point,
    closed by *close* cells (the dropouts between echoes), make bodies
    (8 neighbours).  A body's level is the median height of its water
    points; its banks, the lowest ground point per cell in the ring of two
    cells around it.  A body whose banks rise less than *min_bank* above its
    level (their median; a body without banks is kept) is no water: paved
    ground, level and wide, that drains away at its edges.  Of the others,
    those of *min_area* or more are returned, their level lowered to the 5th
    percentile of the banks when that is lower (the water at or below its
    banks); flat when the spread of their water heights (5th to 95th
    percentile) is at most *max_spread*.  Also returns the cells of the
    bodies taken for no water.
    """
    from scipy import ndimage

    if len(water) == 0:
        return [], CellMask((0.0, 0.0), cell, np.zeros((0, 0), dtype=bool))
    pad = close + 3
    first = np.floor(water[:, :2].min(axis=0) / cell).astype(np.int64)
    last = np.floor(water[:, :2].max(axis=0) / cell).astype(np.int64)
    lo = np.array([first[0] - pad, last[1] + 1 + pad], dtype=np.float64) * cell  # upper-left corner
    shape = (int(last[1] - first[1]) + 1 + 2 * pad, int(last[0] - first[0]) + 1 + 2 * pad)
    row, col = _cells(water[:, :2], cell, lo)
    mask = np.zeros(shape, dtype=bool)
    mask[row, col] = True
    eight = np.ones((3, 3), bool)
    if close > 0:
        mask = ndimage.binary_closing(mask, structure=eight, iterations=close)
    label, _ = ndimage.label(mask, structure=eight)
    lowest = np.full(shape, np.inf)
    gr, gc = _cells(ground[:, :2], cell, lo)
    inside = (gr >= 0) & (gr < shape[0]) & (gc >= 0) & (gc < shape[1])
    np.minimum.at(lowest, (gr[inside], gc[inside]), ground[inside, 2])
    of_point = label[row, col]
    bodies, rejected = [], np.zeros(shape, dtype=bool)
    for k, (rows, cols) in enumerate(ndimage.find_objects(label), start=1):
        rows = slice(max(rows.start - 2, 0), rows.stop + 2)  # room for the ring of banks
        cols = slice(max(cols.start - 2, 0), cols.stop + 2)
        body = label[rows, cols] == k
        heights = water[of_point == k, 2]
        level = float(np.median(heights))
        ring = ndimage.binary_dilation(body, structure=eight, iterations=2) & ~body
        banks = lowest[rows, cols][ring]
        banks = banks[np.isfinite(banks)]
        if len(banks) and float(np.median(banks)) - level < min_bank:
            rejected[rows, cols] |= body
            continue
        if float(body.sum()) * cell * cell < min_area:
            continue
        if len(banks):
            level = min(level, float(np.percentile(banks, 5)))
        spread = float(np.percentile(heights, 95) - np.percentile(heights, 5))
        corner = (lo[0] + cols.start * cell, lo[1] - rows.start * cell)
        bodies += _polygons(body, corner, cell, level, len(heights), spread, spread <= max_spread)
    return bodies, CellMask((float(lo[0]), float(lo[1])), cell, rejected)


def _polygons(body, corner, cell, level, points, spread, flat) -> list[WaterBody]:
    """The polygons (4-connected parts) of a body's cells, with its figures."""
    import rasterio.features
    from affine import Affine

    transform = Affine(cell, 0.0, corner[0], 0.0, -cell, corner[1])
    out = []
    for geometry, value in rasterio.features.shapes(body.astype(np.uint8), mask=body, transform=transform):
        if value == 1:
            rings = [np.asarray(r, dtype=np.float64) for r in geometry["coordinates"]]
            area = _ring_area(rings[0]) - sum(_ring_area(r) for r in rings[1:])
            out.append(WaterBody(rings, level, area, points, spread, flat))
    return out


def write_water_bodies(path: Path, bodies: list[WaterBody], *, crs, units) -> None:
    """The bodies as a GeoPackage 1.2 of PolygonZ (every vertex at the body's level), in the CRS's *units*."""
    from dtm.common.vectors import polygon_z_wkb, write_gpkg

    h, v = units.horizontal, units.vertical
    geometry = [polygon_z_wkb([r / h for r in b.rings], b.level / v) for b in bodies]
    fields = {
        "level": np.array([b.level / v for b in bodies], dtype=np.float64),
        "area_m2": np.array([b.area for b in bodies], dtype=np.float64),
        "points": np.array([b.points for b in bodies], dtype=np.int64),
        "spread_m": np.array([b.spread for b in bodies], dtype=np.float64),
        "flattened": np.array([int(b.flat) for b in bodies], dtype=np.int32),
    }
    write_gpkg(path, geometry, fields, crs=crs, layer=LAYER, geometry_type="Polygon Z")


def read_water_bodies(path: Path, units) -> list[tuple[list[np.ndarray], float]]:
    """The flattened bodies of a ``water.gpkg``: (rings in metres, level in metres) each."""
    import pyogrio.raw

    from dtm.common.vectors import wkb_polygons

    _, _, geometry, fields = pyogrio.raw.read(str(path), layer=LAYER, columns=["level", "flattened"])
    out = []
    for wkb, level, flat in zip(geometry, fields[0], fields[1], strict=True):
        if wkb is None or not flat:
            continue
        for rings in wkb_polygons(bytes(wkb)):
            out.append(([r * units.horizontal for r in rings], float(level) * units.vertical))
    return out


def burn_levels(bodies: list[tuple[list[np.ndarray], float]], shape: tuple[int, int], transform) -> np.ndarray:
    """Each cell's water level where its centre lies inside a body (NaN elsewhere); *transform* in metres."""
    import rasterio.features

    levels = np.full(shape, np.nan)
    if not bodies or shape[0] == 0 or shape[1] == 0:
        return levels
    shapes = [({"type": "Polygon", "coordinates": [r.tolist() for r in rings]}, level) for rings, level in bodies]
    return rasterio.features.rasterize(
        shapes, out_shape=shape, transform=transform, fill=np.nan, dtype="float64", all_touched=False
    )
