"""A grid over ``one_grid_cells`` worked in the tiles' windows gives the classes of the tiles of points.

The survey of test_one_grid.py (buildings, trees with second returns, a
roof the ground filter took for ground, a wall along the north edge, noise
beyond the usable points) in 100 m tiles with a 10 m buffer, well short of
the stage's reach (121 m): the tiles of points then classify differently
from one grid, so a window that saw more or less than its tile would show.
The windows run twice: on two workers (pass 2 in ranges of records) and in
this process.
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from tests.conftest import run_until
from tests.stages.classify_objects.test_one_grid import _survey
from tests.stages.parse.test_real_files import REAL

#: The usable points' grid has about 241 x 161 cells, the header's 271 x 191: over 15,000, within 4 x 15,000.
WINDOWED = "stages.classify_objects.one_grid_cells=15000"


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("object_windows")
    _survey(root / "survey.las")
    (root / "survey.yaml").write_text(
        "name: objects\ninput: {format: las, paths: [survey.las]}\noutput: out\ncache: cache\n"
        "executor: {kind: local, workers: 2}\ntiling: {size: 100, buffer: 10}\n"
        "stages:\n  denoise: {enabled: false}\n  classify_ground: {enabled: false}\n"
        "  classify_water: {enabled: false}\n"
    )
    cache = root / "cache"

    def run(name, *sets):
        return run_until(root / "survey.yaml", "classify_objects", root / name, *sets, cache=cache)["classify_objects"]

    return {
        "one grid": run("one"),
        "tiles": run("tiles", "stages.classify_objects.one_grid_cells=0"),
        "windows": run("windows", WINDOWED),
        "windows here": run("here", WINDOWED, "executor.workers=1"),
    }


def _classes(entry: dict) -> np.ndarray:
    return np.asarray(laspy.read(entry["outputs"]["points_objects"]["file"]).classification)


@pytest.mark.parametrize("name", ["windows", "windows here"])
def test_windows_give_the_classes_of_the_tiles(runs, name):
    tiles, windows = runs["tiles"], runs[name]
    tiling = windows["metrics"]["tiling"]
    assert tiling["executor"].startswith("one grid in windows") and tiling["buffer"] == 10.0
    assert tiling["tiles"] == 6 and tiling["grid"][0] * tiling["grid"][1] > 15_000
    assert (_classes(runs["one grid"]) != _classes(tiles)).any()  # the 10 m buffer shows: the test can tell
    assert windows["outputs"]["points_objects"]["sha256"] == tiles["outputs"]["points_objects"]["sha256"]
    counts = {k: v for k, v in windows["metrics"].items() if k != "tiling"}
    assert counts == {k: v for k, v in tiles["metrics"].items() if k != "tiling"}


@pytest.mark.slow  # two runs of a real file up to classify_objects (about 10 s)
def test_a_real_survey_in_windows_equals_its_tiles_of_points(tmp_path):
    """lidR's Topography.laz (73,403 real points, hilly, lakes) in 100 m tiles: both one-grid stages over
    their caps (grids of 286 x 286 cells of 1 m and 144 x 144 of 2 m) work in 16 windows and give the files
    the tiles of points give, byte for byte.  (The same held on 8 of the 12 real files that run; the other
    4 are sparse, their cells no whole part of a tile, and fall back to tiles of points: 2026-12-05.)"""
    (tmp_path / "job.yaml").write_text(
        f"name: real\ninput: {{format: las, paths: [{REAL / 'lidR' / 'Topography.laz'}]}}\ncrs: auto-utm\n"
        "output: out\ncache: cache\nexecutor: {kind: local, workers: 2}\ntiling: {size: 100}\n"
    )

    def run(name, ground, objects):
        sets = (f"stages.classify_ground.one_grid_cells={ground}", f"stages.classify_objects.one_grid_cells={objects}")
        return run_until(tmp_path / "job.yaml", "classify_objects", tmp_path / name, *sets, cache=tmp_path / "cache")

    tiles, windows = run("tiles", 0, 0), run("windows", 30_000, 7_000)
    for stage, key in (("classify_ground", "points_classified"), ("classify_objects", "points_objects")):
        tiling = windows[stage]["metrics"]["tiling"]
        assert tiling["executor"].startswith("one grid in windows") and tiling["tiles"] == 16
        assert windows[stage]["outputs"][key]["sha256"] == tiles[stage]["outputs"][key]["sha256"]
