"""``points.vpc``: a virtual point cloud over the ``per_input`` files, for QGIS (3.32 and later) and PDAL wrench.

The format is PDAL wrench's VPC (``vpc-spec.md`` of github.com/PDAL/wrench):
a STAC API ItemCollection, one STAC 1.0.0 Item per file with the
``pointcloud`` and ``projection`` extensions.  Each Item gives its file's
bounds in WGS 84 (GeoJSON's ``geometry`` and 3-D ``bbox``, the corners
transformed with the edges densified) and in the file's own CRS
(``proj:bbox``, 3-D, which readers prefer), its CRS as WKT2
(``proj:wkt2``: a compound CRS has no single EPSG code), its point count,
encoding and dimensions, and the file as the ``data`` asset, relative to
the ``.vpc``.  ``datetime`` is the LAS header's creation date (midnight
UTC), as LAS defines it; null with no date.
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import pyproj

from lidar.clouds import cloud_crs

STAC_VERSION = "1.0.0"
EXTENSIONS = [
    "https://stac-extensions.github.io/pointcloud/v1.0.0/schema.json",
    "https://stac-extensions.github.io/projection/v1.1.0/schema.json",
]
_KINDS = {"SignedInteger": "signed", "UnsignedInteger": "unsigned", "FloatingPoint": "floating"}


def item(path: Path, href: str) -> dict:
    """The STAC Item of one LAS/LAZ file at *path*, its asset at *href* (relative to the ``.vpc``)."""
    with laspy.open(str(path)) as reader:
        h = reader.header
        crs = cloud_crs(reader)
    lo, hi = [float(v) for v in h.mins], [float(v) for v in h.maxs]
    to_wgs84 = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    w, s, e, n = to_wgs84.transform_bounds(lo[0], lo[1], hi[0], hi[1], densify_pts=21)
    date = h.creation_date
    return {
        "type": "Feature",
        "stac_version": STAC_VERSION,
        "stac_extensions": EXTENSIONS,
        "id": path.stem,
        "geometry": {"type": "Polygon", "coordinates": [[[w, s], [e, s], [e, n], [w, n], [w, s]]]},
        "bbox": [w, s, lo[2], e, n, hi[2]],
        "properties": {
            "datetime": f"{date.isoformat()}T00:00:00Z" if date else None,
            "pc:count": int(h.point_count),
            "pc:type": "lidar",
            "pc:encoding": "application/vnd.laszip" if path.suffix.lower() == ".laz" else "application/vnd.las",
            "pc:schemas": [
                {"name": d.name, "size": max(d.num_bits // 8, 1), "type": _KINDS.get(d.kind.name, "unsigned")}
                for d in h.point_format.dimensions
            ],
            "proj:epsg": crs.to_epsg(),
            "proj:wkt2": crs.to_wkt(),
            "proj:bbox": lo + hi,
        },
        "links": [],
        "assets": {"data": {"href": href, "roles": ["data"]}},
    }


def write_vpc(path: Path, files: list[Path]) -> None:
    """Write the virtual point cloud *path* over *files* (each under the ``.vpc``'s folder)."""
    items = [item(f, "./" + f.relative_to(path.parent).as_posix()) for f in files]
    path.write_text(json.dumps({"type": "FeatureCollection", "features": items}, indent=1) + "\n", encoding="utf-8")
