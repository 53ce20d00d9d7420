"""Parameters that size memory (cells, tiles, neighbours) are checked against the survey before the work starts."""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from lidar.grid import BYTES_PER_CELL, Grid, check_grid_size
from pipeline.cli import main
from pipeline.errors import ConfigError
from stages.rasterize import interpolate
from stages.rasterize.params import RasterizeParams
from stages.rasterize.tile_rasters import RasterTask, check_tile_memory, tile_memory
from tests.conftest import run_stages

ROOT = Path(__file__).resolve().parents[3]


def small_survey(folder: Path, side: float = 20.0) -> Path:
    """The sample's points in a *side* x *side* m square (a few hundred), as a LAS of their own."""
    las = laspy.read(ROOT / "data_samples" / "las" / "sample.laz")
    x0, y0 = las.header.mins[:2] + 100.0
    keep = (las.x >= x0) & (las.x < x0 + side) & (las.y >= y0) & (las.y < y0 + side)
    out = laspy.LasData(las.header)
    out.points = las.points[keep]
    out.update_header()
    path = folder / "small.las"
    out.write(path)
    return path


def run(tmp_path: Path, path: Path, *sets: str) -> int:
    args = ["run", str(ROOT / "configs" / "las.yaml"), "-q", "--set", f"input.paths=[{path}]"]
    for s in (f"output={tmp_path / 'out'}", f"cache={tmp_path / 'cache'}", "stages.accuracy.enabled=false", *sets):
        args += ["--set", s]
    return main(args)


def test_a_resolution_too_fine_for_free_memory_is_refused_after_reading(tmp_path, capsys, monkeypatch):
    """0.05 m cells over 20 x 20 m: 160,801 cells, about 19 MB; with 5 MB free: exit 2 naming the key, at once."""
    monkeypatch.setattr("lidar.memory.free_memory", lambda: 5_000_000)
    monkeypatch.setattr("lidar.grid.free_memory", lambda: 5_000_000)  # lidar.grid imports it at its top
    path = small_survey(tmp_path)
    assert run(tmp_path, path, "stages.rasterize.resolution=0.05") == 2
    err = capsys.readouterr().err
    assert "stages.rasterize.resolution: 0.05 m cells over this 20 x 20 m survey" in err
    assert "cells (about 19 MB for the products), more than the 5 MB of free memory" in err
    assert "of free memory; use a coarser resolution (at least" in err and "Traceback" not in err
    ran = [name for name, s in run_stages(tmp_path / "out").items() if s.get("status") == "ran"]
    assert "rasterize" not in ran and not (tmp_path / "out" / "dtm.tif").exists()


def test_the_check_suggests_a_resolution_that_fits():
    grid = Grid.covering(0.0, 0.0, 120.0, 118.0, 0.01)
    free = 9_800_000_000
    with pytest.raises(ConfigError) as refused:
        check_grid_size(grid, (0.0, 0.0, 120.0, 118.0), memory=free)
    message = str(refused.value)
    assert message.startswith("stages.rasterize.resolution: 0.01 m cells over this 120 x 118 m survey")
    assert "make 141,623,801 cells (about 17 GB for the products), more than the 9.8 GB of free memory" in message
    fits = float(message.split("at least ")[1].split(" m")[0])
    check_grid_size(Grid.covering(0.0, 0.0, 120.0, 118.0, fits), (0.0, 0.0, 120.0, 118.0), memory=free)
    assert BYTES_PER_CELL * grid.rows * grid.cols > free


def test_tiles_too_large_for_the_workers_are_refused_before_they_are_made():
    """Each tile's grid plus the TIN's nodata margin, times the tiles made at once, against free memory."""
    grid = Grid.covering(0.0, 0.0, 99.9, 99.9, 0.25)
    tasks = [RasterTask(i, (0, grid.rows, 0, grid.cols), 10, "", "", grid, {}, 0.0, 1.0, ()) for i in range(3)]
    tin = RasterizeParams(resolution=0.25, nodata_distance=5.0)
    cells, mask, rows, cols = tile_memory(tasks[0], tin)
    assert (rows, cols) == (grid.rows + 44, grid.cols + 44) == (445, 444) and mask < cells
    check_tile_memory(tasks, tin, workers=1, memory=cells + mask)
    with pytest.raises(ConfigError, match=r"^stages.rasterize.resolution: 0.25 m cells make grids of 444 x 445 cells"):
        check_tile_memory(tasks, tin, workers=2, memory=cells + mask)  # two tiles side by side
    idw = RasterizeParams(resolution=0.25, nodata_distance=5.0, method="idw")
    assert tile_memory(tasks[0], idw)[1] == 0  # no nodata mask
    far = RasterizeParams(resolution=0.25, nodata_distance=50.0)  # the mask reaches 50 m farther all round
    with pytest.raises(ConfigError, match=r"^stages.rasterize.nodata_distance: 50 m around each tile at 0.25 m"):
        check_tile_memory(tasks, far, workers=1, memory=cells + mask)


def test_neighbors_beyond_the_cap_are_refused_by_name(tmp_path, capsys):
    path = small_survey(tmp_path)
    assert run(tmp_path, path, "stages.rasterize.method=idw", "stages.rasterize.idw.neighbors=1000000000") == 2
    assert "stages.rasterize.idw.neighbors: Input should be less than or equal to 1000" in capsys.readouterr().err


def test_idw_in_blocks_of_a_few_cells_is_the_same(monkeypatch):
    """Many neighbours per cell: blocks of fewer cells (never more than NEIGHBOUR_BLOCK neighbours), same values."""
    rng = np.random.default_rng(7)
    pts = np.column_stack((rng.uniform(0, 30, (500, 2)) + [440_000.0, 4_474_000.0], rng.uniform(600, 610, 500)))
    grid = Grid.covering(440_000.0, 4_474_000.0, 440_030.0, 4_474_030.0, 1.0)
    whole = interpolate.idw(pts, grid, nodata_distance=10.0, neighbors=40)
    asked = []
    real = interpolate.canonical_neighbours

    def spy(tree, q, k, upper):
        asked.append(len(q) * k)
        return real(tree, q, k, upper)

    monkeypatch.setattr(interpolate, "NEIGHBOUR_BLOCK", 100)
    monkeypatch.setattr(interpolate, "canonical_neighbours", spy)
    blocks = interpolate.idw(pts, grid, nodata_distance=10.0, neighbors=40)
    np.testing.assert_array_equal(blocks, whole)
    assert max(asked) <= 100 and len(asked) == grid.rows * grid.cols // 2 + grid.rows * grid.cols % 2
    np.testing.assert_array_equal(
        interpolate.nearest(pts, grid, nodata_distance=10.0), interpolate.nearest(pts, grid, nodata_distance=10.0)
    )
