"""Vector products: GeoPackage 1.2 (:data:`GPKG_VERSION`) layers written with pyogrio."""

from __future__ import annotations

from pathlib import Path

import numpy as np

#: GeoPackage version written (GDAL's ``VERSION`` creation option).  GDAL 3.6
#: and QGIS 3.22 read 1.2 without warnings; GDAL 3.8's default, 1.4, makes them
#: warn that the file "may only be partially supported".
GPKG_VERSION = "1.2"


def line_wkb(xy: np.ndarray) -> bytes:
    """A 2D LineString as WKB (little-endian flag, type 2, the point count, the coordinates)."""
    import struct

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
    import pyogrio
    import pyogrio.raw

    pyogrio.set_gdal_config_options({"OGR_CURRENT_DATE": "2000-01-01T00:00:00.000Z"})
    wkb = np.empty(len(geometry), dtype=object)
    wkb[:] = list(geometry)
    wkt = crs.to_wkt() if hasattr(crs, "to_wkt") else str(crs)
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
