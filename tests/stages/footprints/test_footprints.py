"""Building outlines and canopy height on a hand-made classified cloud over a flat 100 m DTM."""

from __future__ import annotations

import numpy as np
import pyogrio
import pyproj
import pytest
import shapely
from affine import Affine

from lidar.vectors import write_gpkg
from stages.footprints.outlines import CellTally, building_labels, building_rows, canopy_height, flat_cells

CELL = 1.0
TRANSFORM = Affine(CELL, 0, 1000.0, 0, -CELL, 2100.0)  # 100 x 100 cells, x 1000-1100, y 2000-2100
SHAPE = (100, 100)


def _block(x0, x1, y0, y1, z, cls, spacing=0.5):
    g = np.arange(x0 + spacing / 2, x1, spacing), np.arange(y0 + spacing / 2, y1, spacing)
    x, y = (a.ravel() for a in np.meshgrid(*g))
    return x, y, np.full(len(x), z), np.full(len(x), cls, np.uint8)


@pytest.fixture(scope="module")
def survey():
    """Two roofs (20 m x 10 m at 110, 8 m x 8 m at 106 with a one-cell gap of no points), trees 1000-1010 at 104."""
    blocks = [
        _block(1010, 1030, 2010, 2020, 110.0, 6),
        _block(1050, 1054, 2050, 2058, 106.0, 6),
        _block(1055, 1058, 2050, 2058, 106.0, 6),  # the same roof after a 1 m strip without returns
        _block(1000, 1010, 2080, 2090, 104.0, 5),
        _block(1000, 1100, 2000, 2100, 100.0, 2, spacing=2.0),
    ]
    x, y, z, cls = (np.concatenate(c) for c in zip(*blocks, strict=True))
    tally = CellTally.empty(SHAPE)
    tally.add(flat_cells(x, y, TRANSFORM, SHAPE), z, cls)
    dtm = np.full(SHAPE, 100.0)
    labels, count = building_labels(tally.roof_count.reshape(SHAPE))
    return tally, dtm, labels, count


def test_each_roof_is_one_building_its_gap_closed(survey):
    _, _, _, count = survey
    assert count == 2


def test_outlines_and_heights(survey, tmp_path):
    tally, dtm, labels, count = survey
    rows = building_rows(labels, count, tally, dtm, TRANSFORM)
    path = tmp_path / "buildings.gpkg"
    crs = pyproj.CRS.from_epsg(25830)
    write_gpkg(path, rows["geometry"], rows["fields"], crs=crs, layer="buildings", geometry_type="MultiPolygon")
    info = pyogrio.read_info(str(path))
    assert info["features"] == 2 and info["geometry_type"] == "MultiPolygon" and info["crs"] == "EPSG:25830"
    meta, _, geometry, fields = pyogrio.raw.read(str(path))
    got = {name: fields[i] for i, name in enumerate(meta["fields"])}
    shapes = [shapely.from_wkb(bytes(g)) for g in geometry]
    big = int(np.argmax(got["area"]))
    assert got["area"][big] == pytest.approx(200.0) and shapes[big].bounds == (1010.0, 2010.0, 1030.0, 2020.0)
    assert got["area"][1 - big] == pytest.approx(64.0)  # 8 m x 8 m: the gap closed
    np.testing.assert_allclose(got["ground_z"], 100.0)
    assert sorted(got["roof_z"]) == [106.0, 110.0] and sorted(got["height"]) == [6.0, 10.0]
    assert got["points"][big] == 800  # 20 m x 10 m at 0.5 m spacing


def test_canopy_height_is_the_vegetation_above_the_dtm(survey):
    tally, dtm, _, _ = survey
    chm = canopy_height(tally, dtm)
    assert np.isfinite(chm).sum() == 100  # 10 m x 10 m of trees
    np.testing.assert_allclose(chm[np.isfinite(chm)], 4.0)


def test_a_survey_without_buildings_gives_an_empty_layer(tmp_path):
    x, y, z, cls = _block(1000, 1100, 2000, 2100, 100.0, 2, spacing=2.0)
    tally = CellTally.empty(SHAPE)
    tally.add(flat_cells(x, y, TRANSFORM, SHAPE), z, cls)
    labels, count = building_labels(tally.roof_count.reshape(SHAPE))
    rows = building_rows(labels, count, tally, np.full(SHAPE, 100.0), TRANSFORM)
    path = tmp_path / "buildings.gpkg"
    crs = pyproj.CRS.from_epsg(25830)
    write_gpkg(path, rows["geometry"], rows["fields"], crs=crs, layer="buildings", geometry_type="MultiPolygon")
    info = pyogrio.read_info(str(path))
    assert count == 0 and info["features"] == 0 and info["geometry_type"] == "MultiPolygon"
    assert list(info["fields"]) == ["ground_z", "roof_z", "highest_z", "height", "points", "area"]
