"""Polygons read back from GeoPackages and shapefiles (lidar.vectors.read_polygons), and their CRS checked."""

from __future__ import annotations

import struct

import numpy as np
import pyogrio.raw
import pyproj
import pytest

from lidar.crs import horizontal_crs_matches
from lidar.vectors import read_polygons, wkb_polygons

SQUARE = np.array([[0, 0], [4, 0], [4, 4], [0, 4], [0, 0]], float)
HOLE = np.array([[1, 1], [1, 2], [2, 2], [2, 1], [1, 1]], float)


def _polygon(rings, kind=3, dims=2, order="<") -> bytes:
    out = struct.pack(order + "BII", 1 if order == "<" else 0, kind, len(rings))
    for ring in rings:
        coords = np.column_stack([ring] + [np.full(len(ring), 7.0)] * (dims - 2))
        out += struct.pack(order + "I", len(ring)) + coords.astype(order + "f8").tobytes()
    return out


@pytest.mark.parametrize(
    ("kind", "dims", "order"),
    [(3, 2, "<"), (1003, 3, "<"), (2003, 3, "<"), (3003, 4, "<"), (3 | 0x80000000, 3, ">"), (3, 2, ">")],
)
def test_a_polygon_in_every_wkb_flavour_gives_its_rings(kind, dims, order):
    (got,) = wkb_polygons(_polygon([SQUARE, HOLE], kind, dims, order))
    assert len(got) == 2
    np.testing.assert_array_equal(got[0], SQUARE)
    np.testing.assert_array_equal(got[1], HOLE)


def test_a_multipolygon_gives_one_polygon_per_part():
    parts = [_polygon([SQUARE]), _polygon([SQUARE + 10, HOLE + 10])]
    wkb = struct.pack("<BII", 1, 6, 2) + b"".join(parts)
    got = wkb_polygons(wkb)
    assert [len(p) for p in got] == [1, 2]
    np.testing.assert_array_equal(got[1][0], SQUARE + 10)


def test_a_line_is_refused():
    with pytest.raises(ValueError, match="not a polygon"):
        wkb_polygons(struct.pack("<BII", 1, 2, 2) + np.zeros(4).tobytes())


@pytest.mark.parametrize("name", ["water.gpkg", "water.shp"])
def test_read_polygons_from_a_file_with_its_crs(tmp_path, name):
    geometry = np.empty(2, dtype=object)
    geometry[:] = [_polygon([SQUARE + 440000, HOLE + 440000]), _polygon([SQUARE + 440010])]
    driver = "GPKG" if name.endswith("gpkg") else "ESRI Shapefile"
    pyogrio.raw.write(
        str(tmp_path / name),
        geometry=geometry,
        field_data=[np.array([1, 2])],
        fields=["id"],
        driver=driver,
        geometry_type="Polygon",
        crs=pyproj.CRS.from_epsg(25830).to_wkt(),
    )
    polygons, crs = read_polygons(tmp_path / name)
    assert len(polygons) == 2 and len(polygons[0]) == 2
    assert {tuple(p) for p in polygons[1][0]} == {tuple(p) for p in SQUARE + 440010}  # a shapefile turns rings
    assert horizontal_crs_matches(crs, pyproj.CRS.from_epsg(25830)) is None


def test_read_polygons_of_a_file_that_is_not_a_layer(tmp_path):
    (tmp_path / "x.gpkg").write_text("not a GeoPackage")
    with pytest.raises(ValueError, match="cannot read it as a vector layer"):
        read_polygons(tmp_path / "x.gpkg")


def test_crs_checks_compare_the_horizontal_part():
    points = pyproj.CRS.from_user_input("EPSG:25830+5782")  # ETRS89 / UTM 30N + Alicante height
    assert horizontal_crs_matches("EPSG:25830", points) is None
    assert "reproject" in horizontal_crs_matches("EPSG:32630", points)
    assert "no CRS" in horizontal_crs_matches(None, points)
    assert horizontal_crs_matches("EPSG:4326", None) is None
