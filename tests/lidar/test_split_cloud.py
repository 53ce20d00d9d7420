"""Cutting a LAS file into tiles (lidar.tile_points.split_cloud), in one process and on two workers.

On two workers the file's records are cut into ranges that the workers split
at once, each into parts of its own; read in turn, a tile's parts must hold
exactly the points of the tile plus its buffer, in the file's order, as the
split in one process writes them, and the rasters of each tile must be the
same bytes.  The expected membership is computed here from the coordinates
alone (a point belongs to a tile when it lies in the tile's square widened
by the buffer), not with the layout's own arithmetic.
"""

from __future__ import annotations

from functools import partial
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from lidar.clouds import cloud_info
from lidar.grid import Grid
from lidar.gridrun.point_tiles import PointTask, tile_classes
from lidar.mosaic import core_window
from lidar.tile_points import read_tile, split_cloud, tile_parts
from lidar.units import Units
from pipeline.executor import LocalExecutor
from pipeline.tiling import Layout
from stages.denoise.noise_classes import DenoiseKernel
from stages.denoise.params import DenoiseParams
from stages.rasterize.params import RasterizeParams
from stages.rasterize.tile_rasters import RasterTask, Usable, raster_columns, rasterize_tile

SIZE, BUFFER, CHUNK = 200.0, 30.0, 3_000
X0, Y0 = 500_000.0, 4_400_000.0  # whole tiles in metres


def _write(path: Path, epsg: int) -> Path:
    """Points along flight strips back and forth (the order of a survey), classes 1, 2 and 7, some withheld."""
    rng = np.random.default_rng(3)
    units = Units.of(pyproj.CRS.from_epsg(epsg))
    strips = []
    for k, y0 in enumerate(range(0, 700, 140)):
        x = np.sort(rng.uniform(0, 900, 8_000))[:: 1 if k % 2 == 0 else -1]
        strips.append(np.column_stack((x, y0 + rng.uniform(-40, 180, len(x)), 600 + rng.normal(0, 2, len(x)))))
    xyz = np.vstack(strips)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001] * 3)
    header.offsets = np.array([X0 / units.horizontal, Y0 / units.horizontal, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(epsg))
    las = laspy.LasData(header)
    # local metres -> the CRS's units
    las.x, las.y, las.z = (X0 + xyz[:, 0]) / units.horizontal, (Y0 + xyz[:, 1]) / units.horizontal, xyz[:, 2]
    las.classification = rng.choice(np.array([1, 2, 2, 7], np.uint8), len(xyz))
    las.withheld = rng.random(len(xyz)) < 0.05
    las.write(str(path))
    return path


@pytest.fixture(scope="module", params=[25830, 2227], ids=["metres", "US feet"])
def split(request, tmp_path_factory):
    tmp = tmp_path_factory.mktemp(f"split{request.param}")
    las = _write(tmp / "cloud.las", request.param)
    layout = Layout.of(cloud_info(las).extent, SIZE, BUFFER)
    columns = partial(raster_columns, sigma=False)
    one = split_cloud(las, layout, tmp / "one", columns, chunk_size=CHUNK, count=Usable.of)
    executor = LocalExecutor(2)
    try:
        two = split_cloud(las, layout, tmp / "two", columns, chunk_size=CHUNK, count=Usable.of, executor=executor)
    finally:
        executor.close()
    return las, layout, tmp, one, two


def _expected(las: Path, layout: Layout) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Tile -> (indices in file order, core flags) from the coordinates in metres."""
    cloud = laspy.read(str(las))
    units = Units.of(cloud.header.parse_crs())
    x = np.asarray(cloud.x) * units.horizontal
    y = np.asarray(cloud.y) * units.horizontal
    out = {}
    for tile in layout.tiles:
        near = (
            (x >= tile.xmin - BUFFER) & (x < tile.xmax + BUFFER) & (y >= tile.ymin - BUFFER) & (y < tile.ymax + BUFFER)
        )
        core = (x >= tile.xmin) & (x < tile.xmax) & (y >= tile.ymin) & (y < tile.ymax)
        if near.any():
            out[tile.index] = (np.flatnonzero(near), core[near])
    return out


def test_two_workers_write_each_tile_the_points_of_one_process(split):
    las, layout, tmp, (rows1, usable1), (rows2, usable2) = split
    expected = _expected(las, layout)
    assert sorted(rows1) == sorted(rows2) == sorted(expected)
    assert rows2 == rows1
    n = cloud_info(las).count
    assert sum(core for _, core in rows2.values()) == n  # every point in exactly one core
    for t, (idx, core) in expected.items():
        one, two = read_tile(tmp / "one" / str(t)), read_tile(tmp / "two" / str(t))
        assert np.array_equal(one["idx"], idx), t  # nothing lost, nothing foreign, file order
        assert np.array_equal(one["core"], core), t
        assert rows2[t] == (len(idx), int(core.sum()))
        assert one.keys() == two.keys()
        for name in one:
            assert one[name].dtype == two[name].dtype, (t, name)
            assert np.array_equal(one[name], two[name]), (t, name)
    assert np.array_equal(usable1.classes, usable2.classes)
    assert usable1.box() == usable2.box()
    assert usable2.classes.sum() == n


def test_the_ranges_are_split_into_parts_that_join_in_file_order(split):
    las, layout, tmp, _, (rows2, _) = split
    parts = {t: tile_parts(tmp / "two" / str(t)) for t in rows2}
    assert max(len(p) for p in parts.values()) > 1  # the workers' ranges meet in some tiles
    assert {p.name for ps in parts.values() for p in ps} == {str(k) for k in range(10)}  # ten: the progress moves
    for t, ps in parts.items():
        starts = [int(np.load(p / "idx.npy")[0]) for p in ps]
        assert starts == sorted(starts), t
    assert all(tile_parts(tmp / "one" / str(t)) == [tmp / "one" / str(t)] for t in rows2)


@pytest.mark.parametrize("method", ["tin", "idw"])
def test_a_tile_split_on_two_workers_gives_the_same_raster_bytes(split, method, tmp_path):
    las, layout, tmp, (rows, usable), _ = split
    grid = Grid.covering(*usable.box(), 2.0)
    params = RasterizeParams(method=method, nodata_distance=10.0).model_dump(mode="json")
    outputs = ["dtm", "dsm", "ndsm", "density"]
    drawn = 0
    for tile in layout.tiles:
        if tile.index not in rows:
            continue
        results = []
        for run in ("one", "two"):
            task = RasterTask(
                tile=tile.index,
                window=core_window(grid, tile, layout),
                weight=rows[tile.index][0],
                source=str(tmp / run / str(tile.index)),
                result=str(tmp_path / run / str(tile.index)),
                grid=grid,
                params=params,
                buffer=BUFFER,
                vertical=1.0,
                outputs=tuple(outputs),
            )
            results.append(rasterize_tile(task))
        assert results[0] == results[1]
        for name in outputs:
            a = (tmp_path / "one" / str(tile.index) / f"{name}.npy").read_bytes()
            b = (tmp_path / "two" / str(tile.index) / f"{name}.npy").read_bytes()
            assert a == b, (tile.index, name)
        drawn += results[0]["cells"] - results[0]["nodata_cells"]
    assert drawn > 0.5 * grid.rows * grid.cols


def test_a_tile_split_on_two_workers_gives_the_same_noise_classes(split, tmp_path):

    _, _, tmp, (rows, _), _ = split
    kernel = DenoiseKernel(DenoiseParams().model_dump(mode="json"))
    for t in rows:
        results = [
            tile_classes(PointTask(t, rows[t][0], str(tmp / run / str(t)), str(tmp_path / run / str(t)), kernel))
            for run in ("one", "two")
        ]
        assert results[0] == results[1]
        for name in ("idx", "classification"):
            a = (tmp_path / "one" / str(t) / f"{name}.npy").read_bytes()
            assert a == (tmp_path / "two" / str(t) / f"{name}.npy").read_bytes(), (t, name)
