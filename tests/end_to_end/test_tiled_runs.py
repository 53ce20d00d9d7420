"""Tiled runs equal the untiled run: locally and on a Dask cluster, every product, byte for byte.

The shipped LAS sample (512 m x 384 m, 306,405 points) through the whole LAS
job (noise, SMRF ground, TIN DTM, DSM, nDSM, density, hillshade, contours,
check points, LAZ export): untiled, then cut into 200 m tiles (3 x 2) run by
two local worker processes, then by a local Dask cluster of two workers.
A run with a 1 m buffer shows the comparison can fail: without the buffer
its algorithms need, the tiles' seams show in the products.
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
import rasterio

from pipeline.cli import main

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "las.yaml"

pytestmark = pytest.mark.slow


def _run(tmp: Path, name: str, *sets: str) -> dict:
    out = tmp / name
    args = ["run", str(CONFIG), "-q", "--set", f"output={out}", "--set", f"cache={out / '.cache'}"]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return json.loads((out / "run.json").read_text())


def _products(manifest: dict) -> dict[str, str]:
    # report.html names the run's folders and time: not comparable
    return {name: p["sha256"] for name, p in manifest["products"].items() if name != "report.html"}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("tiled")
    # the ground and water grids of a survey this small fit whole; zero cells makes them use the tiles too
    tiles = (
        "tiling.size=200",
        "executor.workers=2",
        "stages.classify_ground.one_grid_cells=0",
        "stages.classify_water.one_grid_cells=0",
    )
    return tmp, {
        "untiled": _run(tmp, "untiled", "tiling.enabled=false"),
        "local": _run(tmp, "local", *tiles),
        "dask": _run(tmp, "dask", *tiles, "executor.kind=dask"),
    }


def _stage(manifest: dict, name: str) -> dict:
    return next(s for s in manifest["stages"] if s["name"] == name)


def test_tiles_were_used(runs):
    _, m = runs
    for name in ("denoise", "classify_ground", "classify_water", "rasterize"):
        assert _stage(m["untiled"], name)["metrics"]["tiling"]["tiles"] == 1
        tiling = _stage(m["local"], name)["metrics"]["tiling"]
        assert tiling["tiles"] == 6 and tiling["tasks"] == 6
        assert tiling["executor"] == "local, 2 workers"
        assert _stage(m["dask"], name)["metrics"]["tiling"]["executor"].startswith("dask local cluster")


def test_tiled_products_equal_untiled_byte_for_byte(runs):
    _, m = runs
    untiled = _products(m["untiled"])
    assert {"dtm.tif", "dsm.tif", "ndsm.tif", "density.tif", "points.laz", "contours.gpkg"} <= set(untiled)
    assert _products(m["local"]) == untiled
    assert _products(m["dask"]) == untiled
    # the intermediates too: same noise and ground class for every point, in the same order
    for name in ("denoise", "classify_ground", "classify_water"):
        sha = {k: _stage(v, name)["outputs"] for k, v in m.items()}
        assert _same_files(sha["local"], sha["untiled"])
        assert _same_files(sha["dask"], sha["untiled"])


def _same_files(a: dict, b: dict) -> bool:
    return {k: v["sha256"] for k, v in a.items()} == {k: v["sha256"] for k, v in b.items()}


def test_a_missing_buffer_shows_at_the_seams(runs):
    tmp, m = runs
    bare = _run(tmp, "nobuffer", "tiling.size=200", "executor.workers=2", "tiling.buffer=1")
    differ = {n for n, sha in _products(bare).items() if _products(m["untiled"])[n] != sha}
    # the DSM (highest return per cell) needs no buffer where every cell holds a point; on this gentle
    # sample SMRF's edge-local padding gives the same classes even with a 1 m buffer (the survey where
    # its buffer matters is tests/stages/classify_ground/test_tile_buffers.py), but the TIN's triangles cross the seams
    assert "dtm.tif" in differ, differ
    # and the differences sit at the tile edges (multiples of 200 m)
    with rasterio.open(tmp / "untiled" / "dtm.tif") as a, rasterio.open(tmp / "nobuffer" / "dtm.tif") as b:
        da, db, t = a.read(1), b.read(1), a.transform
    rows, cols = np.nonzero(da != db)
    x = t.c + (cols + 0.5) * t.a
    y = t.f + (rows + 0.5) * t.e
    to_edge = np.minimum(np.abs((x + 100) % 200 - 100), np.abs((y + 100) % 200 - 100))
    assert len(rows) and np.median(to_edge) < 10.0, np.median(to_edge)


def test_points_keep_their_order_and_attributes(runs):
    tmp, _ = runs
    a = laspy.read(tmp / "untiled" / "points.laz")
    b = laspy.read(tmp / "dask" / "points.laz")
    assert np.array_equal(a.points.array, b.points.array)
