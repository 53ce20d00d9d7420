"""``survey.gpkg``: the boundary traces the DTM's valid cells exactly; the tile index is each file's header box."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pyogrio.raw
import pyproj
import pytest
import rasterio
import shapely
from rasterio.transform import from_origin

from stages.footprints.survey_index import boundary, file_boxes, write_survey_index

UTM = pyproj.CRS.from_epsg(25830)


def test_the_boundary_is_the_valid_cells_with_their_holes():
    valid = np.ones((6, 8), dtype=bool)
    valid[2:4, 3:5] = False  # a 2 x 2 void inside: a hole
    valid[:, 7] = False  # an edge column off the survey
    valid[5, 0] = False
    shape = boundary(valid, from_origin(1000.0, 2000.0, 0.5, 0.5))
    assert shape.area == pytest.approx(valid.sum() * 0.25)
    assert sum(len(p.interiors) for p in shape.geoms) == 1
    rows, cols = np.indices(valid.shape)
    x, y = 1000.0 + (cols + 0.5) * 0.5, 2000.0 - (rows + 0.5) * 0.5
    inside = shapely.contains_xy(shape, x.ravel(), y.ravel()).reshape(valid.shape)
    assert np.array_equal(inside, valid)
    assert shape.bounds == (1000.0, 1997.0, 1003.5, 2000.0)


def _table(path: Path, rows: list[dict]) -> Path:
    columns = ["path", "bytes", "points", "points_kept", "xmin", "ymin", "zmin", "xmax", "ymax", "zmax"]
    columns += ["point_format", "gps_time_type", "crs"]
    with open(path, "w", newline="") as fh:
        writer = csv.DictWriter(fh, columns)
        writer.writeheader()
        for row in rows:
            writer.writerow({c: row.get(c, 0) for c in columns})
    return path


def test_the_tile_index_is_each_file_s_box_in_the_output_crs(tmp_path):
    table = _table(
        tmp_path / "input_files.csv",
        [
            {
                "path": "/d/a.laz",
                "points": 10,
                "points_kept": 9,
                "xmin": 440000,
                "ymin": 4474000,
                "xmax": 440500,
                "ymax": 4474400,
                "crs": UTM.name,
            },
            # the same kind of tile in geographic degrees: brought into the output CRS
            {
                "path": "/d/b.laz",
                "points": 5,
                "points_kept": 5,
                "xmin": -3.7,
                "ymin": 40.4,
                "xmax": -3.69,
                "ymax": 40.41,
                "crs": "WGS 84",
            },
            {"path": "/d/c.laz", "points": 1, "points_kept": 1, "crs": "NAD_1983_not_a_crs_name"},
        ],
    )
    rows = file_boxes(table, UTM)
    assert rows["skipped"] == ["c.laz"] and list(rows["fields"]["file"]) == ["a.laz", "b.laz"]
    assert list(rows["fields"]["points_kept"]) == [9, 5]
    a, b = (shapely.from_wkb(g) for g in rows["geometry"])
    assert a.bounds == (440000.0, 4474000.0, 440500.0, 4474400.0) and a.area == pytest.approx(500 * 400)
    to_utm = pyproj.Transformer.from_crs("EPSG:4326", UTM, always_xy=True)
    corners = np.array([to_utm.transform(x, y) for x in (-3.7, -3.69) for y in (40.4, 40.41)])
    assert shapely.contains_xy(b.buffer(1e-6), corners[:, 0], corners[:, 1]).all()


def test_survey_gpkg_has_both_layers_in_the_crs(tmp_path):
    dtm = np.full((4, 4), 100.0)
    dtm[0, 0] = np.nan
    table = _table(
        tmp_path / "t.csv",
        [{"path": "a.las", "points": 3, "points_kept": 3, "xmin": 0, "ymin": 0, "xmax": 4, "ymax": 4, "crs": UTM.name}],
    )
    out = tmp_path / "survey.gpkg"
    area, skipped = write_survey_index(
        out, dtm, from_origin(0.0, 4.0, 1.0, 1.0), rasterio.crs.CRS.from_epsg(25830), table
    )
    assert area == 15.0 and skipped == []
    assert [list(x) for x in pyogrio.list_layers(out)] == [["boundary", "MultiPolygon"], ["input_files", "Polygon"]]
    meta, _, _, fields = pyogrio.raw.read(out, layer="boundary")
    assert fields[0][0] == 15.0 and pyproj.CRS(meta["crs"]).to_epsg() == 25830
