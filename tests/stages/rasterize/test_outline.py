"""The survey's outline: notches of the coverage are cut from the rasters, enclosed holes are not, tiles agree."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
import rasterio

from pipeline.cli import main
from stages.rasterize.outline import CELL_M, occupied_cells, survey_outline

ROOT = Path(__file__).resolve().parents[3]


def _l_with_a_hole(n: int = 200_000, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Points over an L of 200 m arms 60 m wide, less a 40 m x 40 m hole in its horizontal arm."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 200, n), rng.uniform(0, 200, n)
    keep = ((y < 60) | (x < 60)) & ~((x > 100) & (x < 140) & (y > 10) & (y < 50))
    return x[keep], y[keep]


def _inside(outline, *xy: tuple[float, float]) -> list[bool]:
    return outline.contains(np.array([p[0] for p in xy]), np.array([p[1] for p in xy])).tolist()


def test_the_notch_of_an_l_is_cut_and_its_enclosed_hole_kept():
    outline = survey_outline(occupied_cells(*_l_with_a_hole()), 20.0)
    # the data, the enclosed hole, the notch (inside the convex hull), beyond the survey
    assert _inside(outline, (30, 30), (120, 30), (150, 150), (70, 70), (-10, 5), (205, 5)) == [
        True,
        True,
        False,
        False,
        False,
        False,
    ]


def test_no_limit_means_no_outline():
    outline = survey_outline(occupied_cells(*_l_with_a_hole()), 0.0)
    assert outline.everywhere and _inside(outline, (150, 150), (1e6, -1e6)) == [True, True]


def test_a_sparse_survey_is_not_peeled_away():
    """1,000 points over 1 km x 1 km (about 32 m apart): the limit follows the spacing (4 x the median edge)."""
    rng = np.random.default_rng(1)
    x, y = rng.uniform(0, 1000, 1000), rng.uniform(0, 1000, 1000)
    outline = survey_outline(occupied_cells(x, y), 20.0)
    g = np.arange(100.0, 900.0, 10.0)
    gx, gy = np.meshgrid(g, g)
    assert outline.contains(gx.ravel(), gy.ravel()).mean() > 0.99


def test_cells_are_anchored_on_multiples_of_their_side():
    """The outline of the same points is the same whichever other points a tile or survey holds far away."""
    x, y = _l_with_a_hole()
    far = survey_outline(occupied_cells(np.append(x, 5000.0 + x[:3]), np.append(y, y[:3])), 20.0)
    near = survey_outline(occupied_cells(x, y), 20.0)
    g = np.arange(-10.0, 210.0, CELL_M / 2)
    gx, gy = np.meshgrid(g, g)
    np.testing.assert_array_equal(far.contains(gx.ravel(), gy.ravel()), near.contains(gx.ravel(), gy.ravel()))


@pytest.fixture(scope="module")
def l_runs(tmp_path_factory):
    """The sample's points cut to an L with a hole, through the LAS job: untiled, tiled, and without an outline."""
    tmp = tmp_path_factory.mktemp("outline")
    src = laspy.read(ROOT / "data_samples" / "las" / "sample.laz")
    x0, y0 = src.header.mins[:2]
    x, y = np.asarray(src.x) - x0, np.asarray(src.y) - y0
    keep = ((y < 120) | (x < 150)) & (x < 350) & ~((x > 200) & (x < 240) & (y > 40) & (y < 80))
    las = laspy.LasData(src.header)
    las.points = src.points[keep]
    las.write(tmp / "l.laz")
    runs = {}
    for name, sets in {
        "untiled": ("tiling.enabled=false",),
        "tiled": ("tiling.size=100", "executor.workers=2", "stages.classify_ground.one_grid_cells=0"),
        "no_outline": ("tiling.enabled=false", "stages.rasterize.outline_edge=0"),
    }.items():
        args = ["run", str(ROOT / "configs" / "las.yaml"), "-q", "--set", f"input.paths=[{tmp / 'l.laz'}]"]
        for s in (f"output={tmp / name}", f"cache={tmp / 'cache'}", "stages.report.enabled=false", *sets):
            args += ["--set", s]
        assert main(args) == 0
        runs[name] = tmp / name
    return runs, (x0, y0)


def _dtm_at(folder: Path, origin, *xy: tuple[float, float]) -> list[float]:
    with rasterio.open(folder / "dtm.tif") as ds:
        values = [v[0] for v in ds.sample([(origin[0] + a, origin[1] + b) for a, b in xy])]
        return [None if v == ds.nodata else float(v) for v in values]


@pytest.mark.slow
def test_the_dtm_leaves_the_notch_and_fills_the_hole(l_runs):
    runs, origin = l_runs
    notch, hole, data = (190, 140), (220, 60), (50, 50)  # the notch point 20 m off both arms
    with_outline = _dtm_at(runs["untiled"], origin, notch, hole, data)
    without = _dtm_at(runs["no_outline"], origin, notch, hole, data)
    assert with_outline[0] is None and without[0] is not None  # the TIN's hull triangles filled the notch
    assert with_outline[1:] == without[1:] and None not in with_outline[1:]
    manifest = json.loads((runs["untiled"] / "run.json").read_text())
    rasterize = next(s for s in manifest["stages"] if s["name"] == "rasterize")
    assert rasterize["metrics"]["outside_outline_cells"] > 0


@pytest.mark.slow
def test_tiles_cut_the_same_outline(l_runs):
    runs, _ = l_runs
    for name in ("dtm.tif", "dsm.tif", "ndsm.tif", "density.tif"):
        assert (runs["tiled"] / name).read_bytes() == (runs["untiled"] / name).read_bytes(), name
