"""The survey on one grid, in passes over its points, gives the classes of the tiles and of all the points at once.

The survey (the synthetic scene: buildings, trees with second returns,
terrain) carries ground classes from its truth, plus a flat roof 7 m up
that the ground filter took for ground, noise and withheld points, and two
noise points beyond the others on the west and north-east: the header's
grid is wider than the grid of the usable points, which the one-grid path
must use (the tiles' grids, and :func:`object_classes`', are of the usable
points).  The reference is :func:`object_classes` on every point in memory.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from lidar import glossary
from lidar.grid import Grid
from lidar.gridrun import passes
from lidar.gridrun.passes import STRAYS_BEYOND
from pipeline.executor import LocalExecutor
from stages.classify_objects.kernel import ObjectsKernel
from stages.classify_objects.objects import object_classes
from stages.classify_objects.params import ClassifyObjectsParams
from tests.conftest import run_stages, run_until
from tests.gridruns import one_grid
from tests.synthetic import make_scene, terrain

X0, Y0 = 440_000.0, 4_474_000.0
ROOF = (150.0, 100.0, 15.0, 12.0)  # centre x, y, half width, half depth: a flat roof taken for ground
WALL = (80.0, 130.0, 159.9)  # from x, to x, at y: a wall whose roof lies beyond the survey's north edge


def objects_one_grid(src: Path, dst: Path, params: ClassifyObjectsParams, cell: float, multi: bool, **workers):
    """The survey's classes on one grid, as the stage runs it (:func:`tests.gridruns.one_grid`)."""
    kernel = ObjectsKernel(params.model_dump(mode="json"), cell, multi)
    return one_grid(kernel, src, dst, params.one_grid_cells, **workers)


def _survey(path: Path) -> None:
    s = make_scene(width=240.0, height=160.0, density=4.0, seed=7, n_trees=30)
    x, y, z = s.x, s.y, s.z.copy()
    cls = np.where(s.true_ground, glossary.GROUND, glossary.UNCLASSIFIED).astype(np.uint8)
    roof = (np.abs(x - ROOF[0]) < ROOF[2]) & (np.abs(y - ROOF[1]) < ROOF[3])
    z[roof] += 7.0
    cls[roof] = glossary.GROUND
    rng = np.random.default_rng(3)
    cls[rng.random(len(x)) < 0.005] = 7
    withheld = rng.random(len(x)) < 0.003
    # a 6 m wall along the survey's north edge across two tiles, its roof beyond the survey (intensity 999)
    wx, wy = rng.uniform(*WALL[:2], 1500), WALL[2] + rng.normal(0, 0.03, 1500)
    x, y, z = np.r_[x, wx], np.r_[y, wy], np.r_[z, terrain(wx, wy) + rng.uniform(0, 6, len(wx))]
    cls, withheld = np.r_[cls, np.ones(len(wx), np.uint8)], np.r_[withheld, np.zeros(len(wx), bool)]
    intensity = np.r_[np.zeros(len(s.x), np.uint16), np.full(len(wx), 999, np.uint16)]
    returns = np.r_[s.return_number, np.ones(len(wx), np.uint8)], np.r_[s.number_of_returns, np.ones(len(wx), np.uint8)]
    # noise beyond the usable points on two sides: the header's grid is not theirs
    x, y, z = np.r_[x, -20.0, 250.0], np.r_[y, 50.0, 170.0], np.r_[z, z.min() - 20.0, z.max() + 30.0]
    cls, withheld = np.r_[cls, 7, 18], np.r_[withheld, False, False]
    intensity = np.r_[intensity, 0, 0]
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001] * 3)
    header.offsets = np.array([X0, Y0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(25830))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x + X0, y + Y0, z
    las.return_number = np.r_[returns[0], 1, 1]
    las.number_of_returns = np.r_[returns[1], 1, 1]
    las.intensity = intensity
    las.classification = cls
    las.withheld = withheld
    las.write(str(path))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The stage's entries in a run on one grid and in a run in 100 m tiles (with a 121 m buffer)."""
    root = tmp_path_factory.mktemp("objects_grid")
    _survey(root / "survey.las")
    (root / "survey.yaml").write_text(
        "name: objects\ninput: {format: las, paths: [survey.las]}\noutput: out\ncache: cache\n"
        "executor: {kind: local, workers: 2}\ntiling: {size: 100}\n"
        "stages:\n  denoise: {enabled: false}\n  classify_ground: {enabled: false}\n"
        "  classify_water: {enabled: false}\n"
    )
    cache = root / "cache"
    one = run_until(root / "survey.yaml", "classify_objects", root / "one", cache=cache)["classify_objects"]
    tiled = run_until(
        root / "survey.yaml",
        "classify_objects",
        root / "tiled",
        "stages.classify_objects.one_grid_cells=0",
        cache=cache,
    )["classify_objects"]
    return root, one, tiled


def _reference(path: Path, params: ClassifyObjectsParams, cell: float) -> np.ndarray:
    las = laspy.read(str(path))
    cls = np.asarray(las.classification)
    new, _ = object_classes(
        np.column_stack((np.asarray(las.x), np.asarray(las.y), np.asarray(las.z))),
        cls,
        np.asarray(las.number_of_returns),
        glossary.usable(cls, np.asarray(las.withheld)),
        params,
        cell,
        True,
        return_number=np.asarray(las.return_number),
    )
    return new


def test_one_grid_equals_the_tiles_byte_for_byte(runs):
    _, one, tiled = runs
    assert one["metrics"]["tiling"]["tiles"] == 1 and one["metrics"]["tiling"]["executor"] == "one grid, this process"
    assert tiled["metrics"]["tiling"]["tasks"] == 7  # 4 x 2 tiles over the noise too, one of them only noise
    assert one["outputs"]["points_objects"]["sha256"] == tiled["outputs"]["points_objects"]["sha256"]
    counts = {k: v for k, v in one["metrics"].items() if k != "tiling"}
    assert counts == {k: v for k, v in tiled["metrics"].items() if k != "tiling"}
    # the survey has what the classes are about: the roof taken for ground, trees of every height
    assert counts["roof_was_ground"] > 0.8 * 4 * (2 * ROOF[2]) * (2 * ROOF[3])
    assert min(counts[k] for k in ("low_vegetation", "medium_vegetation", "high_vegetation")) > 100
    las = laspy.read(one["outputs"]["points_objects"]["file"])
    wall = np.asarray(las.intensity) == 999
    up = np.asarray(las.z)[wall] - terrain(np.asarray(las.x)[wall] - X0, np.asarray(las.y)[wall] - Y0) > 0.6
    assert wall.sum() == 1500 and np.mean(np.asarray(las.classification)[wall][up] == 6) > 0.95


def test_one_grid_gives_the_classes_of_all_points_at_once(runs, tmp_path):
    """In small chunks, in this process and on two workers writing ranges of records in place."""

    root, one, _ = runs
    src, written = _input_of(root), Path(one["outputs"]["points_objects"]["file"])
    params, cell = ClassifyObjectsParams(), one["metrics"]["cell_m"]
    np.testing.assert_array_equal(np.asarray(laspy.read(str(written)).classification), _reference(src, params, cell))
    here = objects_one_grid(src, tmp_path / "here.las", params, cell, True, chunk_size=7_000)
    executor = LocalExecutor(2)
    try:
        work = tmp_path / "work"
        work.mkdir()
        there = objects_one_grid(
            src, tmp_path / "there.las", params, cell, True, chunk_size=7_000, executor=executor, workdir=work
        )
        assert executor._pool is not None  # the workers wrote the records
    finally:
        executor.close()
    assert here == there
    # on the grid of the usable points (what object_classes makes), not the header's, which the noise widens
    las = laspy.read(str(src))
    usable = glossary.usable(np.asarray(las.classification), np.asarray(las.withheld))
    x, y = np.asarray(las.x)[usable], np.asarray(las.y)[usable]
    grid = Grid.covering(x.min(), y.min(), x.max(), y.max(), cell)
    assert here["grid"] == (grid.rows, grid.cols) and grid.cols < (las.header.maxs[0] - las.header.mins[0]) / cell
    assert (tmp_path / "here.las").read_bytes() == (tmp_path / "there.las").read_bytes() == written.read_bytes()
    assert list(work.iterdir()) == []  # the grids are removed


def _input_of(root: Path) -> Path:
    """The file the stage read: the survey as ``parse`` wrote it (the filters between are disabled)."""
    return Path(run_stages(root / "one")["parse"]["outputs"]["points_georef"]["file"])


def test_a_header_grid_a_little_over_the_limit_is_tiled_without_reading_the_box(runs, tmp_path, monkeypatch):
    """Within STRAYS_BEYOND times the limit, the header's grid is the survey's: tiled, the points not read for
    their box; far beyond it they are (stray points could have made it large)."""

    src = _input_of(runs[0])
    with laspy.open(str(src)) as reader:
        (x0, y0), (x1, y1) = reader.header.mins[:2], reader.header.maxs[:2]
    header = Grid.covering(x0, y0, x1, y1, 1.0)
    cells = header.rows * header.cols
    read, box = [], passes.selected_box
    monkeypatch.setattr(passes, "selected_box", lambda *a, **k: read.append(1) or box(*a, **k))
    within = ClassifyObjectsParams(one_grid_cells=int(cells / (0.5 * (1 + STRAYS_BEYOND))))
    assert objects_one_grid(src, tmp_path / "out.las", within, 1.0, True) is None and read == []
    far = ClassifyObjectsParams(one_grid_cells=int(cells / (2 * STRAYS_BEYOND)))
    assert objects_one_grid(src, tmp_path / "out.las", far, 1.0, True) is None and read == [1]
    assert not (tmp_path / "out.las").exists()


def test_a_grid_over_the_limit_is_left_to_the_tiles(runs, tmp_path):
    params = ClassifyObjectsParams(one_grid_cells=1_000)  # the usable points' grid has about 40,000 cells
    assert objects_one_grid(_input_of(runs[0]), tmp_path / "out.las", params, 1.0, True) is None
    assert not (tmp_path / "out.las").exists()
