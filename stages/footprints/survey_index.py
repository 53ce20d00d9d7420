"""``survey.gpkg``: the survey's boundary and its tile index, the two layers an analyst overlays first.

``boundary`` (MultiPolygon, one feature): the DTM's valid cells, their
edges traced exactly (cell edges, holes kept: voids wider than
``nodata_distance`` and water left as nodata), with the ``area`` it covers
(CRS units squared).  ``input_files`` (Polygon, LAS input only): each
input file's header bounds in the output CRS (the box's edges densified,
then transformed), with its ``file`` name, ``points`` and ``points_kept``,
as ``qc/input_files.csv`` lists them; the delivery's tiles when the
provider tiled the survey.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import numpy as np
import pyproj
import rasterio.features
import shapely

from lidar.input_files import read_input_files_csv
from lidar.vectors import write_gpkg

#: Segments of each side of a file's box when it is transformed into the output CRS (densified, as
#: pyproj's transform_bounds does).
DENSIFY = 21


def boundary(valid: np.ndarray, transform) -> shapely.MultiPolygon:
    """The union of the cells where *valid* (rows, cols) is true, as polygons on the cell edges."""
    parts = [
        shapely.geometry.shape(geom)
        for geom, _ in rasterio.features.shapes(valid.astype(np.uint8), mask=valid, connectivity=4, transform=transform)
    ]
    return shapely.MultiPolygon(parts)


def file_boxes(csv: Path, crs: pyproj.CRS) -> dict:
    """Each input file's header box in *crs* (the output CRS), with its name and counts, from ``input_files.csv``.

    The table names each file's CRS; a file in another CRS whose name pyproj
    cannot read back is left out, listed in ``skipped``.
    """
    rows, skipped = [], []
    for row in read_input_files_csv(csv):
        name = row.get("crs") or crs.name
        if name == crs.name:
            row["_crs"] = crs
        else:
            try:
                row["_crs"] = pyproj.CRS.from_user_input(name)
            except pyproj.exceptions.CRSError:
                skipped.append(Path(row["path"]).name)
                continue
        rows.append(row)
    geometry = []
    for row in rows:
        box = shapely.box(*(float(row[k]) for k in ("xmin", "ymin", "xmax", "ymax")))
        source = row["_crs"]
        if source is not crs and not source.equals(crs):
            side = max(box.bounds[2] - box.bounds[0], box.bounds[3] - box.bounds[1])
            to_crs = pyproj.Transformer.from_crs(source, crs, always_xy=True)
            box = shapely.transform(shapely.segmentize(box, side / DENSIFY), partial(_through, to_crs))
        geometry.append(shapely.to_wkb(box, byte_order=1))
    return {
        "skipped": skipped,
        "geometry": geometry,
        "fields": {
            "file": np.array([Path(r["path"]).name for r in rows], dtype=object),
            "points": np.array([int(r["points"]) for r in rows], dtype=np.int64),
            "points_kept": np.array([int(r["points_kept"]) for r in rows], dtype=np.int64),
        },
    }


def _through(transformer: pyproj.Transformer, xy: np.ndarray) -> np.ndarray:
    return np.column_stack(transformer.transform(xy[:, 0], xy[:, 1]))


def write_survey_index(path: Path, dtm: np.ndarray, transform, crs, input_files: Path | None) -> tuple[float, list]:
    """Write ``survey.gpkg`` (its ``boundary`` and, with *input_files*, its ``input_files`` layer).

    Returns the boundary's area and the files left out of the tile index (:func:`file_boxes`).
    """
    shape = boundary(np.isfinite(dtm), transform)
    area = float(shape.area)
    write_gpkg(
        path,
        [shapely.to_wkb(shape, byte_order=1)],
        {"area": np.array([area])},
        crs=crs,
        layer="boundary",
        geometry_type="MultiPolygon",
    )
    if input_files is not None:
        rows = file_boxes(input_files, pyproj.CRS.from_wkt(crs.to_wkt() if hasattr(crs, "to_wkt") else str(crs)))
        write_gpkg(path, rows["geometry"], rows["fields"], crs=crs, layer="input_files", geometry_type="Polygon")
        return area, rows["skipped"]
    return area, []
