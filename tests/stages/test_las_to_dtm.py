"""End to end on the shipped sample: configs/las.yaml -> dtm.tif + points.laz.

The sample is the synthetic scene of stages.synthetic (seed 20111), so the
true terrain and the true ground label of every point are known.
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
import rasterio

from pipeline.cli import main
from stages.synthetic import SAMPLE_ORIGIN, make_scene, terrain

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "las.yaml"

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("las-run")
    args = ["run", str(CONFIG), "-q", "--set", f"output={out / 'out'}", "--set", f"cache={out / 'cache'}"]
    assert main(args) == 0
    return out, args


def _manifest(out: Path) -> dict:
    return json.loads((out / "out" / "run.json").read_text())


def test_dtm_is_a_cloud_optimized_geotiff(run_dir):
    out, _ = run_dir
    with rasterio.open(out / "out" / "dtm.tif") as ds:
        assert ds.crs.to_epsg() == 25830
        assert ds.dtypes[0] == "float32"
        assert ds.nodata == -9999.0
        assert ds.profile["tiled"] and ds.block_shapes[0] == (256, 256)
        assert ds.overviews(1), "COG must carry overviews"
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert ds.compression.name.lower() == "deflate"
        t = ds.transform
        assert t.a == 1.0 and t.e == -1.0
        assert t.c % 1.0 == 0 and t.f % 1.0 == 0  # cell-aligned to the resolution
        assert (ds.width, ds.height) == (512, 384)


def test_dtm_matches_the_true_terrain(run_dir):
    out, _ = run_dir
    with rasterio.open(out / "out" / "dtm.tif") as ds:
        dtm = ds.read(1)
        rows, cols = np.indices(dtm.shape)
        x, y = rasterio.transform.xy(ds.transform, rows.ravel(), cols.ravel())
    truth = terrain(np.asarray(x) - SAMPLE_ORIGIN[0], np.asarray(y) - SAMPLE_ORIGIN[1]).reshape(dtm.shape)
    valid = dtm != -9999.0
    assert valid.mean() > 0.99
    err = (dtm - truth)[valid]
    rmse = float(np.sqrt(np.mean(err**2)))
    # 3 cm range noise; TIN on ~1.4 ground points per cell
    assert rmse < 0.06, rmse
    assert abs(float(np.mean(err))) < 0.02


def test_points_laz_is_las14_with_crs_and_ground_class(run_dir):
    out, _ = run_dir
    las = laspy.read(out / "out" / "points.laz")
    assert str(las.header.version) == "1.4" and las.header.point_format.id == 6
    assert las.header.parse_crs().to_epsg() == 25830
    cls = np.asarray(las.classification)
    assert set(np.unique(cls)) <= {1, 2, 7, 18}
    scene = make_scene()
    assert len(cls) == len(scene.x)
    np.testing.assert_allclose(np.asarray(las.gps_time), scene.gps_time, atol=1e-6)
    ground = cls == 2
    type1 = (scene.true_ground & ~ground).sum() / scene.true_ground.sum()
    type2 = (~scene.true_ground & ground).sum() / (~scene.true_ground).sum()
    assert type1 < 0.01 and type2 < 0.01, (type1, type2)
    # the scene has no noise: what denoise flags must be off the ground
    assert not (np.isin(cls, (7, 18)) & scene.true_ground).any()
    assert set(np.unique(las.point_source_id)) == {1, 2, 3}


def test_second_run_is_all_cache_hits(run_dir):
    out, args = run_dir
    before = _manifest(out)["products"]
    assert main(args) == 0
    m = _manifest(out)
    assert {s["status"] for s in m["stages"]} == {"cached"}
    assert m["products"] == before


def test_changing_resolution_reruns_only_rasterize(run_dir):
    out, args = run_dir
    assert main([*args, "--set", "stages.rasterize.resolution=2.0"]) == 0
    status = {s["name"]: s["status"] for s in _manifest(out)["stages"]}
    assert status == {
        "parse": "cached",
        "denoise": "cached",
        "classify_ground": "cached",
        "rasterize": "ran",
        "export_las": "cached",
    }
    with rasterio.open(out / "out" / "dtm.tif") as ds:
        assert ds.res == (2.0, 2.0)


def test_every_config_validates():
    for config in sorted((ROOT / "configs").glob("*.yaml")):
        assert main(["validate", str(config)]) == 0, config


def test_disabled_denoise_passes_points_on(tmp_path):
    out = tmp_path / "run"
    args = ["run", str(CONFIG), "-q", "--set", f"output={out}", "--set", f"cache={tmp_path / 'cache'}"]
    assert main([*args, "--set", "stages.denoise.enabled=false", "--until", "classify_ground"]) == 0
    m = json.loads((out / "run.json").read_text())
    status = {s["name"]: s["status"] for s in m["stages"]}
    assert status["denoise"] == "disabled" and status["classify_ground"] == "ran"
    parse = next(s for s in m["stages"] if s["name"] == "parse")
    classify = next(s for s in m["stages"] if s["name"] == "classify_ground")
    assert classify["inputs"]["points_denoised"] == parse["outputs"]["points_georef"]["sha256"]
    assert classify["metrics"]["noise_or_withheld"] == 0
