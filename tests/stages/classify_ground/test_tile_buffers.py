"""Tiled runs equal the untiled run on a survey where the buffers matter (issue 19).

test_tiled_runs.py shows tiles equal the untiled run on the shipped sample,
but there a buffer much smaller than each stage declares gives the same
products too.  This survey (300 m x 300 m, 100 m tiles) is built so that each
stage's declared reach is needed near a tile edge:

- SMRF (reach 8 w_max + 2 c = 146 m since issue 16): buildings up to 34 m wide astride the
  tile edges, on rolling terrain (a buffer of 38 m gives the same classes
  here; test_smrf_reach.py has the surveys that need more than 38 m and 74 m);
- TIN DTM (reach 2 nodata_distance + 2 cells = 102 m): a lake without
  returns, 62 m wide, astride the edge x = 200 m: the triangles that cover its
  cells span it, so a tile must see the far shore;
- denoise (reach 2 radius + 1 = 41 m): a below-ground echo 1 m inside the
  edge x = 200 m, in a gap 21 m wide on its side and 7 m on the other:
  whether it is low (7) or high (18) noise depends on the points across the
  edge, 7-20 m away.

With the declared buffers the tiled run must equal the untiled one point for
point and cell for cell; with a smaller one it need not (the mutation script,
benchmarks/mutations.py, checks that each stage's test fails then).
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from lidar.rasters import read_raster
from stages.classify_ground.filters import reach
from stages.classify_ground.smrf import SmrfParams, smrf
from tests.conftest import run_until
from tests.stages.denoise.test_noise_classes import X0, Y0, write_las
from tests.synthetic import make_scene

assert X0 % 100 == 0 and Y0 % 100 == 0  # the origin on whole tiles: tile edges at local x, y = 100, 200
#: centre x, y, width, depth, height: buildings near the edges
BUILDINGS = [(80, 180, 34, 30, 8), (185, 95, 30, 34, 12), (200, 190, 33, 33, 7)]
LAKE = (170.0, 232.0, 20.0, 80.0)  # x0, x1, y0, y1: no returns
GAP = (178.0, 207.0, 128.0, 172.0)
LOW_ECHO = (199.0, 150.0)


def _survey(path: Path) -> None:
    s = make_scene(width=300, height=300, seed=1, density=1.0)
    xyz = np.column_stack((s.x, s.y, s.z))
    for cx, cy, w, d, h in BUILDINGS:
        xyz[(np.abs(xyz[:, 0] - cx) < w / 2) & (np.abs(xyz[:, 1] - cy) < d / 2), 2] += h
    keep = np.ones(len(xyz), bool)
    for x0, x1, y0, y1 in (LAKE, GAP):
        keep &= ~((xyz[:, 0] > x0) & (xyz[:, 0] < x1) & (xyz[:, 1] > y0) & (xyz[:, 1] < y1))
    near = np.hypot(xyz[:, 0] - 210, xyz[:, 1] - 150) < 5
    low = np.array([[*LOW_ECHO, float(np.median(xyz[near, 2])) - 12.0]])
    xyz = np.vstack((xyz[keep], low))
    returns = (np.r_[s.return_number[keep], 1], np.r_[s.number_of_returns[keep], 1])
    write_las(path, xyz, returns=returns)


def _run(root: Path, name: str, *sets: str, cache: str | None = None, until: str = "rasterize") -> dict:
    return run_until(root / "survey.yaml", until, root / name, *sets, cache=root / (cache or name) / "cache")


#: The tiles one after the other in this process: the buffers decide what a tile sees, not the worker that
#: runs it (that tiles on two workers give the same bytes is test_split_cloud.py's and test_tiled_runs.py's).
IN_PROCESS = "executor: {kind: local, workers: 1}"

#: SMRF filters a grid this small whole, without tiles; the tiled runs make it cut the survey into tiles.
TILED_SMRF = "stages.classify_ground.one_grid_cells=0"


@pytest.fixture(scope="module")
def survey(tmp_path_factory):
    root = tmp_path_factory.mktemp("buffers")
    _survey(root / "survey.laz")
    (root / "survey.yaml").write_text(
        "name: buffers\ninput: {format: las, paths: [survey.laz]}\noutput: out\ncache: cache\n"
        f"{IN_PROCESS}\n"
        "stages:\n  classify_ground: {algorithm: {name: smrf}}\n"
        "  rasterize: {resolution: 1.0, method: tin, nodata_distance: 50.0}\n"
    )
    untiled = _run(root, "untiled", "tiling.enabled=false")
    tiled = _run(root, "tiled", "tiling.size=100", TILED_SMRF)
    return root, untiled, tiled


def _classes(stage: dict, key: str) -> np.ndarray:
    return np.asarray(laspy.read(stage["outputs"][key]["file"]).classification)


def test_the_survey_is_cut_into_tiles(survey):
    _, untiled, tiled = survey
    for name in ("denoise", "classify_ground", "rasterize"):
        assert untiled[name]["metrics"]["tiling"]["tiles"] == 1
        assert tiled[name]["metrics"]["tiling"]["tiles"] == 9


def test_tiled_denoise_equals_untiled(survey):
    _, untiled, tiled = survey
    a, b = _classes(untiled["denoise"], "points_denoised"), _classes(tiled["denoise"], "points_denoised")
    np.testing.assert_array_equal(b, a)


def test_tiled_denoise_equals_untiled_where_the_buffer_matters(tmp_path):
    """An echo 1 m inside the tile edge x = 200 m, 25 m below the ground above it and level with the floor of
    a quarry whose cliff stands 9.5 m across the edge: untiled, the floor is its nearest point in 3-D (10 m,
    within 10 local spacings): not noise.  A tile that sees less than the declared reach across the edge
    sees only the ground above (25 m) and would call it noise."""
    g = np.arange(100.5, 300.0, 1.0)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    z = np.where(x < 208.5, 100.0, 75.0)  # the quarry floor beyond x = 208.5
    echo = np.array([[199.0, 150.0, 75.0]])
    las = write_las(tmp_path / "quarry.las", np.vstack((np.column_stack((x, y, z)), echo)))
    (tmp_path / "q.yaml").write_text(
        f"name: q\ninput: {{format: las, paths: [{las}]}}\noutput: out\ncache: cache\n{IN_PROCESS}\n"
    )
    classes = {}
    for name, sets in (("untiled", ["tiling.enabled=false"]), ("tiled", ["tiling.size=100"])):
        stage = run_until(tmp_path / "q.yaml", "denoise", tmp_path / name, *sets)["denoise"]
        classes[name] = _classes(stage, "points_denoised")
    assert classes["untiled"][-1] == 0 and not np.isin(classes["untiled"], (7, 18)).any()
    np.testing.assert_array_equal(classes["tiled"], classes["untiled"])


def test_tiled_ground_equals_untiled_where_the_buffer_matters(survey):
    _, untiled, tiled = survey
    a = _classes(untiled["classify_ground"], "points_classified")
    b = _classes(tiled["classify_ground"], "points_classified")
    assert 0.3 < (a == 2).mean() < 0.95
    np.testing.assert_array_equal(b, a)


def test_ground_in_windows_equals_the_tiles(survey):
    """A grid over ``one_grid_cells`` (300 x 300 cells over 30,000) but within four times it: SMRF filters
    it in the tiles' windows, on the cached points of the tiled run, and gives the tiles' classes."""
    root, _, tiled = survey
    windows = _run(
        root,
        "windows",
        "tiling.size=100",
        "stages.classify_ground.one_grid_cells=30000",
        cache="tiled",
        until="classify_ground",
    )
    ground = windows["classify_ground"]
    assert ground["status"] == "ran" and ground["metrics"]["tiling"]["executor"].startswith("one grid in windows")
    assert ground["metrics"]["tiling"]["tiles"] == 9 and ground["metrics"]["tiling"]["buffer"] == 146.0
    np.testing.assert_array_equal(
        _classes(ground, "points_classified"), _classes(tiled["classify_ground"], "points_classified")
    )


@pytest.mark.parametrize("product", ["dtm.tif", "dsm.tif"])
def test_tiled_rasters_equal_untiled_where_the_buffer_matters(survey, product):
    root, _, _ = survey
    a, *_ = read_raster(root / "untiled" / product)
    b, *_ = read_raster(root / "tiled" / product)
    assert np.isfinite(a).mean() > 0.9  # the lake is interpolated across (within nodata_distance)
    np.testing.assert_array_equal(b, a)


def test_a_new_tiling_buffer_reruns_the_ground_stage(survey):
    """The buffer changes the classes near the seams, so it is part of the stage's cache key:
    a run with another ``tiling.buffer`` on the same cache must not reuse the classification."""
    root, _, tiled = survey
    # on the tiled run's cache: parse is reused, denoise and classify_ground must run again
    again = _run(root, "key", "tiling.size=100", TILED_SMRF, "tiling.buffer=1", cache="tiled", until="classify_ground")
    assert again["parse"]["status"] == "cached" and again["classify_ground"]["status"] != "cached"
    a, b = (_classes(s["classify_ground"], "points_classified") for s in (tiled, again))
    assert (a != b).any()  # a 1 m buffer shows at the seams: classified anew


def test_smrf_near_the_survey_boundary_does_not_depend_on_the_tile():
    """Buildings 5-10 m from the survey's north edge: SMRF on each 100 m tile plus the declared buffer
    (146 m) must classify its core points as SMRF on the whole survey does."""

    s = make_scene(width=300, height=200, seed=2, density=1.0)
    xyz = np.column_stack((s.x, s.y, s.z))[s.return_number >= s.number_of_returns]
    for cx, cy, w, d, h in BUILDINGS:
        xyz[(np.abs(xyz[:, 0] - cx) < w / 2) & (np.abs(xyz[:, 1] - cy) < d / 2), 2] += h
    full = smrf(xyz)
    b = reach(SmrfParams(name="smrf"))
    differ = 0
    for x0 in (0.0, 100.0, 200.0):
        for y0 in (0.0, 100.0):
            x, y = xyz[:, 0], xyz[:, 1]
            core = (x >= x0) & (x < x0 + 100) & (y >= y0) & (y < y0 + 100)
            sub = (x >= x0 - b) & (x < x0 + 100 + b) & (y >= y0 - b) & (y < y0 + 100 + b)
            differ += int((smrf(xyz[sub])[core[sub]] != full[core]).sum())
    assert differ == 0, f"{differ} of {len(xyz)} points classified otherwise in tiles"
