"""DTM tiles and their VRT (stage ``export_tiles``): known answers from the raster's own geometry.

A made-up DTM whose edges are not on the tile grid, with a nodata hole that
empties one whole tile, cut into 50 m tiles: the VRT must read back as the
untiled raster cell for cell, and the tiles must lie on multiples of 50 m,
be named by their lower-left corner, not overlap and hold every valid cell.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
import rasterio
from affine import Affine
from pyproj import CRS

from lidar.rasters import NODATA, write_cog
from pipeline.errors import ConfigError
from stages.export_tiles.cog_tiles import tile_cells, write_tiles

CELL = 0.5
LEFT, TOP = 1001.5, 2099.0  # not multiples of the 50 m tile side
ROWS, COLS = 211, 317


@pytest.fixture(scope="module")
def tiled(tmp_path_factory):
    folder = tmp_path_factory.mktemp("tiles")
    rng = np.random.default_rng(5)
    dtm = (600 + rng.normal(0, 3, (ROWS, COLS))).astype(np.float32)
    dtm[98:198, 97:197] = NODATA  # x 1050..1100, y 2000..2050: one whole tile without a valid cell
    dtm[10:20, 30:45] = NODATA  # a hole
    src = folder / "dtm.tif"
    write_cog(src, dtm, transform=Affine(CELL, 0, LEFT, 0, -CELL, TOP), crs=CRS.from_epsg(25830), unit="metre")
    tiles = write_tiles(src, folder / "tiles" / "dtm", folder / "dtm.vrt", "dtm", 100, "tiles/dtm")
    return folder, src, dtm, tiles


def test_the_vrt_reads_back_the_untiled_dtm_exactly(tiled):
    folder, src, dtm, _ = tiled
    with rasterio.open(src) as a, rasterio.open(folder / "dtm.vrt") as b:
        assert b.driver == "VRT"
        assert (b.width, b.height) == (a.width, a.height)
        assert b.transform == a.transform and b.crs == a.crs
        assert b.nodata == a.nodata == NODATA and b.units == ("metre",)
        assert np.array_equal(b.read(1), a.read(1))
        assert np.array_equal(b.read(1), dtm)


def test_tiles_on_the_grid_named_by_lower_left_corner_without_overlap(tiled):
    folder, _, _, tiles = tiled
    files = sorted((folder / "tiles" / "dtm").glob("*.tif"))
    assert [f.name for f in files] == sorted(t["file"] for t in tiles)
    boxes = []
    for f in files:
        e, n = map(float, re.fullmatch(r"dtm_(\d+)_(\d+)\.tif", f.name).groups())
        with rasterio.open(f) as ds:
            assert ds.res == (CELL, CELL) and (ds.width, ds.height) == (100, 100)
            left, bottom, right, top = ds.bounds
            assert (left, bottom) == (e, n) and e % 50 == 0 and n % 50 == 0
            assert (right - left, top - bottom) == (50.0, 50.0)
            assert ds.crs.to_epsg() == 25830 and ds.nodata == NODATA
        boxes.append((left, bottom))
    assert len(set(boxes)) == len(boxes)  # same size on one grid: distinct corners = no overlap
    # the raster spans x 1001.5..1160, y 1993.5..2099: tile columns 1000..1150, rows 1950..2050 (4 x 3);
    # the empty one at (1050, 2000) is not written
    grid = [(x, y) for x in (1000.0, 1050.0, 1100.0, 1150.0) for y in (1950.0, 2000.0, 2050.0)]
    assert sorted(boxes) == [b for b in grid if b != (1050.0, 2000.0)]


def test_every_valid_cell_in_exactly_one_tile_with_its_value(tiled):
    folder, _, dtm, tiles = tiled
    covered = np.zeros(dtm.shape, dtype=int)
    for t in tiles:
        with rasterio.open(folder / "tiles" / "dtm" / t["file"]) as ds:
            block = ds.read(1)
            col0 = round((ds.bounds.left - LEFT) / CELL)
            row0 = round((TOP - ds.bounds.top) / CELL)
        r_lo, c_lo = max(row0, 0), max(col0, 0)
        r_hi, c_hi = min(row0 + 100, ROWS), min(col0 + 100, COLS)
        part = block[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0]
        assert np.array_equal(part, dtm[r_lo:r_hi, c_lo:c_hi])
        covered[r_lo:r_hi, c_lo:c_hi] += 1
        # the parts of the tile outside the raster are nodata
        outside = np.ones((100, 100), bool)
        outside[r_lo - row0 : r_hi - row0, c_lo - col0 : c_hi - col0] = False
        assert np.all(block[outside] == NODATA)
        assert t["valid_cells"] == int(np.count_nonzero(part != NODATA)) > 0
    assert np.all(covered[dtm != NODATA] == 1)
    assert covered.max() == 1


def test_a_tile_size_that_is_not_whole_cells_is_a_config_error():
    assert tile_cells(50.0, 0.5) == 100
    with pytest.raises(ConfigError, match="tile_size 50.3 m is not a whole number of cells"):
        tile_cells(50.3, 0.5)
