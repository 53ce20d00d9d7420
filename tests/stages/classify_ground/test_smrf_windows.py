"""SMRF on one grid filtered in the tiles' windows: the classes of the tiles of points, without the tiles.

A survey whose grid is over ``one_grid_cells`` was cut into tiles of points
with SMRF's buffer; the run service (:mod:`lidar.gridrun.windows`) cuts the
grid of lowest candidates instead, and tests each point against its tile's
window.  The reference here is the point tiles written out in the test: for
each 100 m tile, :func:`~stages.classify_ground.ground_classes.classify`
(SMRF on the points in memory) on the points within the tile and its buffer,
kept for the tile's own points.  The buffer is 20 m, as a user may set
``tiling.buffer``, well short of SMRF's reach: the tiles' classes then differ
from one grid's, so that a filter of the grid whole would fail the test.  The survey has buildings, trees,
points the filter leaves alone and a building cut by the survey's edge.
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from lidar.gridrun.passes import survey_statistics
from lidar.gridrun.windows import run_windows, tile_cells
from pipeline.executor import LocalExecutor
from stages.classify_ground.ground_classes import candidates_of
from stages.classify_ground.kernel import GroundKernel
from stages.classify_ground.params import ClassifyGroundParams
from stages.classify_ground.smrf import provisional_dem
from stages.classify_ground.surface import CellIndex, index_points, min_grid, sample_bilinear_all
from tests.stages.classify_ground.test_smrf_one_grid import _reference, _survey, smrf_one_grid

SIZE, BUFFER = 100.0, 20.0
TILES = (100, 20)  # in cells of 1 m


def _point_tiles(las: laspy.LasData, params: ClassifyGroundParams) -> np.ndarray:
    """Each point's class from the tile of points that holds it: tile i holds x in [i s - b, (i + 1) s + b)."""
    x, y = np.asarray(las.x), np.asarray(las.y)
    out = np.zeros(len(x), np.uint8)
    home_i, home_j = np.floor(y / SIZE), np.floor(x / SIZE)
    for i in np.unique(home_i):
        for j in np.unique(home_j):
            mine = (home_i == i) & (home_j == j)
            if not mine.any():
                continue
            inside = (x >= j * SIZE - BUFFER) & (x < (j + 1) * SIZE + BUFFER)
            inside &= (y >= i * SIZE - BUFFER) & (y < (i + 1) * SIZE + BUFFER)
            sel = np.flatnonzero(inside)
            out[sel[mine[sel]]] = _reference(las[sel], params)[mine[sel]]
    return out


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    root = tmp_path_factory.mktemp("windows")
    las = _survey(root / "in.las", stray=False)
    # the grid (about 260 x 190 cells) over the limit, its header's within WINDOWED_BEYOND times it
    params = ClassifyGroundParams(one_grid_cells=20_000)
    return root, las, params, _point_tiles(las, params)


def test_windows_give_the_classes_of_the_point_tiles(survey):
    root, las, params, expected = survey
    assert 0.3 < (expected == 2).mean() < 0.9 and (expected == 1).sum() > 1000
    assert (expected != _reference(las, params)).any()  # the tiles differ from one grid here: the test can tell
    counts = smrf_one_grid(root / "in.las", root / "here.las", params, chunk_size=7_000, tiles=TILES)
    np.testing.assert_array_equal(np.asarray(laspy.read(str(root / "here.las")).classification), expected)
    assert counts["windows"] == 6 and counts["points"] == len(expected)
    assert counts["ground"] == int((expected == 2).sum()) and counts["non_ground"] == int((expected == 1).sum())
    assert not [p for p in root.iterdir() if p.is_dir() and p.name != "work"]  # no window left behind


def test_windows_on_two_workers_write_the_same_file(survey):

    root, _, params, _ = survey
    smrf_one_grid(root / "in.las", root / "one.las", params, chunk_size=7_000, tiles=TILES)
    work = root / "work"
    work.mkdir()
    executor = LocalExecutor(2)
    try:
        smrf_one_grid(
            root / "in.las", root / "two.las", params, chunk_size=7_000, tiles=TILES, executor=executor, workdir=work
        )
    finally:
        executor.close()
    assert (root / "two.las").read_bytes() == (root / "one.las").read_bytes()
    assert list(work.iterdir()) == []  # the windows and the grids are removed


def test_a_grid_far_over_the_limit_is_left_to_the_point_tiles(survey):
    root, _, _, _ = survey
    params = ClassifyGroundParams(one_grid_cells=5_000)  # 4 x 5,000 cells: less than the header's grid
    assert smrf_one_grid(root / "in.las", root / "none.las", params, tiles=TILES) is None
    assert not (root / "none.las").exists()


def test_tiles_in_whole_cells():
    assert tile_cells(500.0, 146.0, 1.0) == (500, 146)
    assert tile_cells(500.0, 146.5, 1.0) == (500, 147)  # the buffer rounded up: at least the reach
    assert tile_cells(500.0, 146.0, 2.0) == (250, 73)
    assert tile_cells(500.0, 146.0, 3.0) is None  # a tile of 166.7 cells: the point tiles
    assert tile_cells(None, 146.0, 1.0) is None


def test_each_point_gets_the_dem_of_its_tile_of_points(survey):
    """The DEM and slope at every candidate, bit for bit those SMRF makes on its tile's points.

    Closer than the classes can tell (a point moves class only near the
    threshold): the window's cut to its candidates, its corner and the cells
    kept around the core all show here.
    """

    root, las, params, _ = survey
    algo = params.algorithm
    extent = (*las.header.mins[:2], *las.header.maxs[:2])
    kernel = GroundKernel.of(params)
    stats, frame = survey_statistics(root / "in.las", kernel, extent, cap=4 * params.one_grid_cells)
    folder = root / "windows"
    folder.mkdir()
    windows = run_windows(kernel, frame, stats, TILES, folder, None)
    saved = windows.lookup()
    empty = np.zeros(0, np.int64)

    xyz = np.column_stack((np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)))
    _, cand = candidates_of(
        np.asarray(las.classification),
        np.asarray(las.return_number),
        np.asarray(las.number_of_returns),
        np.asarray(las.withheld),
        params,
    )
    xyz = xyz[cand]
    home_i, home_j = np.floor(xyz[:, 1] / SIZE), np.floor(xyz[:, 0] / SIZE)
    checked = 0
    for i, j in {(a, b) for a, b in zip(home_i, home_j, strict=True)}:
        mine = (home_i == i) & (home_j == j)
        key = (int(i), int(j))
        grids, window = saved.recent.get(key, saved._read), saved.frames[key]
        index = CellIndex(window.corner(1), window.corner(0), window.cell, *window.shape, empty, empty)
        at, grad = sample_bilinear_all((grids["surface_0"], grids["surface_1"]), index, xyz[mine, 0], xyz[mine, 1])
        inside = (xyz[:, 0] >= j * SIZE - BUFFER) & (xyz[:, 0] < (j + 1) * SIZE + BUFFER)
        inside &= (xyz[:, 1] >= i * SIZE - BUFFER) & (xyz[:, 1] < (i + 1) * SIZE + BUFFER)
        tile = xyz[inside]
        idx = index_points(tile[:, :2], algo.cell_size)
        dem, slope = provisional_dem(
            min_grid(tile[:, 2], idx),
            **algo.model_dump(exclude={"name", "cell_size"}),
            cell_size=algo.cell_size,
        )
        want = sample_bilinear_all((dem, slope), idx, xyz[mine, 0], xyz[mine, 1])
        np.testing.assert_array_equal(at, want[0])
        np.testing.assert_array_equal(grad, want[1])
        checked += int(mine.sum())
    assert checked == len(xyz) and len(windows.frames) == windows.worked == 6
