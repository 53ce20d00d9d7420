"""Vector products: GeoPackage 1.2 (:data:`GPKG_VERSION`) layers written with pyogrio; polygon layers read."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pyogrio
import pyogrio.raw
from pyogrio.errors import DataLayerError, DataSourceError

#: GeoPackage version written (GDAL's ``VERSION`` creation option).  GDAL 3.6
#: and QGIS 3.22 read 1.2 without warnings; GDAL 3.8's default, 1.4, makes them
#: warn that the file "may only be partially supported".
GPKG_VERSION = "1.2"


def line_wkb(xy: np.ndarray) -> bytes:
    """A 2D LineString as WKB (little-endian flag, type 2, the point count, the coordinates)."""
    coords = np.ascontiguousarray(np.asarray(xy)[:, :2], dtype="<f8")
    return struct.pack("<BII", 1, 2, len(coords)) + coords.tobytes()


def write_gpkg(
    path: Path,
    geometry: list[bytes],
    fields: dict[str, np.ndarray],
    *,
    crs,
    layer: str,
    geometry_type: str = "LineString",
) -> None:
    """Write WKB geometries (all of *geometry_type*) with attribute columns to a GeoPackage, reproducibly.

    The GeoPackage's ``last_change`` timestamps are fixed (GDAL's
    ``OGR_CURRENT_DATE``) so the same lines give the same bytes on every run:
    products are compared and cached by checksum.  The file is a GeoPackage
    :data:`GPKG_VERSION` (GDAL's ``VERSION`` dataset creation option).
    """
    pyogrio.set_gdal_config_options({"OGR_CURRENT_DATE": "2000-01-01T00:00:00.000Z"})
    wkb = np.empty(len(geometry), dtype=object)
    wkb[:] = list(geometry)
    wkt = None if crs is None else crs.to_wkt() if hasattr(crs, "to_wkt") else str(crs)
    pyogrio.raw.write(
        str(path),
        geometry=wkb,
        field_data=list(fields.values()),
        fields=list(fields),
        layer=layer,
        driver="GPKG",
        geometry_type=geometry_type,
        crs=wkt,
        dataset_options={"VERSION": GPKG_VERSION},
    )


def write_lines_gpkg(path: Path, lines: list[tuple[float, np.ndarray]], *, crs, layer: str = "contours") -> None:
    """Write 2D line strings with an ``elevation`` attribute to a GeoPackage (:func:`write_gpkg`)."""
    elevation = np.array([level for level, _ in lines], dtype=np.float64)
    write_gpkg(path, [line_wkb(xy) for _, xy in lines], {"elevation": elevation}, crs=crs, layer=layer)


def polygon_z_wkb(rings: list[np.ndarray], z: float | list[np.ndarray]) -> bytes:
    """A PolygonZ as ISO WKB (type 1003): *rings* of (n, 2) coordinates at height *z*, or each ring's heights."""
    out = [struct.pack("<BII", 1, 1003, len(rings))]
    for i, ring in enumerate(rings):
        heights = np.full(len(ring), float(z)) if np.isscalar(z) else np.asarray(z[i], dtype=np.float64)
        xyz = np.column_stack((np.asarray(ring, dtype=np.float64)[:, :2], heights))
        out.append(struct.pack("<I", len(xyz)) + np.ascontiguousarray(xyz, dtype="<f8").tobytes())
    return b"".join(out)


def wkb_polygons(wkb: bytes, z: bool = False) -> list[list[np.ndarray]]:
    """The polygons of a WKB Polygon or MultiPolygon (ISO or EWKB, any of Z and M): each a list of (n, 2) rings.

    *z*: rings of (n, 3), x, y and height (0 where the geometry has none).
    """

    def geometry(at: int) -> tuple[list[list[np.ndarray]], int]:
        order = "<" if wkb[at] == 1 else ">"
        (kind,) = struct.unpack_from(order + "I", wkb, at + 1)
        at += 5
        dims = 2 + bool(kind & 0x80000000) + bool(kind & 0x40000000)  # EWKB flags
        has_z = bool(kind & 0x80000000)
        kind &= 0x0FFFFFFF
        if kind >= 1000:  # ISO: 1000 Z, 2000 M, 3000 ZM
            has_z = kind // 1000 in (1, 3)
            dims, kind = 2 + (kind // 1000 in (1, 2)) + 2 * (kind // 1000 == 3), kind % 1000
        if kind == 3:
            (nrings,) = struct.unpack_from(order + "I", wkb, at)
            at += 4
            rings = []
            for _ in range(nrings):
                (n,) = struct.unpack_from(order + "I", wkb, at)
                coords = np.frombuffer(wkb, dtype=order + "f8", count=n * dims, offset=at + 4).reshape(n, dims)
                if z:
                    height = coords[:, 2] if has_z else np.zeros(n)
                    rings.append(np.column_stack((coords[:, :2], height)).astype(np.float64))
                else:
                    rings.append(coords[:, :2].astype(np.float64))
                at += 4 + 8 * n * dims
            return [rings], at
        if kind == 6:
            (parts,) = struct.unpack_from(order + "I", wkb, at)
            at += 4
            out = []
            for _ in range(parts):
                got, at = geometry(at)
                out += got
            return out, at
        raise ValueError(f"a geometry of WKB type {kind}, not a polygon")

    return geometry(0)[0]


def read_polygons(path: Path) -> tuple[list[list[np.ndarray]], str | None]:
    """The polygons of the first layer of a GeoPackage or shapefile, and the layer's CRS (None when it has none).

    Each polygon is a list of (n, 2) rings in the layer's units, its outer
    ring first, then its holes; a MultiPolygon gives one polygon per part.

    Raises
    ------
    ValueError
        A geometry that is not a (multi)polygon, or a file GDAL cannot read.
    """
    try:
        meta, _, geometry, _ = pyogrio.raw.read(str(path), columns=[])
    except (DataSourceError, DataLayerError) as exc:
        raise ValueError(f"cannot read it as a vector layer ({exc})") from None
    polygons = []
    for wkb in geometry:
        if wkb is not None:
            polygons += wkb_polygons(bytes(wkb))
    return polygons, meta.get("crs")
