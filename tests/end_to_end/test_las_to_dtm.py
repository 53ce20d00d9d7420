"""End to end on the shipped sample: configs/las.yaml -> dtm.tif + points.laz.

The sample is the synthetic scene of tests.synthetic (seed 20111), so the
true terrain and the true ground label of every point are known.
"""

from __future__ import annotations

import base64
import html
import json
import re
import sqlite3
from pathlib import Path
from xml.etree import ElementTree

import laspy
import numpy as np
import pyogrio
import pytest
import rasterio

from commands.simulate.settings import SimulateFile
from pipeline.cli import main
from pipeline.config import load_config
from tests.synthetic import SAMPLE_ORIGIN, make_scene, terrain

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
        assert ds.nodata == -999999.0  # the USGS LBS's DEM nodata: the default specification is LBS QL2
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
    valid = dtm != -999999.0
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
    assert las.header.global_encoding.wkt  # LAS 1.4: the CRS is WKT, not GeoTIFF keys
    assert any(type(v).__name__ == "WktCoordinateSystemVlr" for v in las.header.vlrs)
    cls = np.asarray(las.classification)
    assert set(np.unique(cls)) <= {1, 2, 3, 4, 5, 6, 7, 18}
    assert {5, 6} <= set(np.unique(cls))  # the scene's trees and buildings
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
    status = {s["name"]: s["status"] for s in m["stages"]}
    assert status.pop("georeference") == "not applicable"  # LAS input is already georeferenced
    assert status.pop("export_tiles") == "not applicable"  # no stages.export_tiles.tile_size
    assert set(status.values()) == {"cached"}
    assert m["products"] == before


def test_changing_resolution_reruns_only_rasterize_and_its_dependants(run_dir):
    out, args = run_dir
    try:
        assert main([*args, "--set", "stages.rasterize.resolution=2.0"]) == 0
        status = {s["name"]: s["status"] for s in _manifest(out)["stages"]}
        assert status == {
            "parse": "cached",
            "georeference": "not applicable",
            "strip_adjust": "cached",
            "denoise": "cached",
            "classify_ground": "cached",
            "classify_water": "cached",
            "classify_objects": "cached",
            "rasterize": "ran",
            "hillshade": "ran",
            "contours": "ran",
            "footprints": "ran",
            "accuracy": "ran",
            "export_las": "cached",
            "export_tiles": "not applicable",
            "qgis": "ran",
            "report": "ran",
        }
        with rasterio.open(out / "out" / "dtm.tif") as ds:
            assert ds.res == (2.0, 2.0)
    finally:  # leave the default products for the other tests
        assert main(args) == 0
    assert {s["status"] for s in _manifest(out)["stages"]} == {"cached", "not applicable"}


def test_every_config_validates():
    for config in sorted((ROOT / "configs").glob("*.yaml")):
        if config.name == "simulate.yaml":  # a simulation, not a pipeline run
            assert set(load_config(config, SimulateFile).surveys) == {"flight_ldmrs", "flight_lmsq"}
            continue
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


RASTERS = ["dtm.tif", "dsm.tif", "ndsm.tif", "density.tif", "hillshade.tif"]
#: The band description QGIS and gdalinfo show for each raster.
DESCRIPTIONS = {
    "dtm.tif": "bare-earth elevation (DTM)",
    "dsm.tif": "highest-surface elevation (DSM)",
    "ndsm.tif": "height above the bare earth (nDSM)",
    "density.tif": "points per cell, all classes but noise and withheld",
    "hillshade.tif": "hillshade of the DTM, sun at azimuth 315 degrees, altitude 45 degrees",
}


@pytest.mark.parametrize("name", RASTERS)
def test_every_raster_product_is_a_cog_with_crs_and_nodata(run_dir, name):
    out, _ = run_dir
    with rasterio.open(out / "out" / name) as ds:
        assert ds.crs.to_epsg() == 25830
        if name == "hillshade.tif":  # an image, as gdaldem writes it: Byte, shades 1-255, nodata 0
            assert ds.dtypes[0] == "uint8" and ds.nodata == 0
            assert ds.units == ("grey level, 1 (shadow) to 255 (lit); 0 is nodata",)
            assert ds.read(1).max() > 1  # lit cells
        else:
            assert ds.dtypes[0] == "float32" and ds.nodata == -999999.0
            # heights name their unit (EPSG:25830: metres); the density counts points per cell
            assert ds.units == (("points per cell",) if name == "density.tif" else ("metre",))
        assert ds.descriptions[0] == DESCRIPTIONS[name]
        # the sample's EPSG:25830 names no vertical CRS: its heights' datum is said to be unknown, and only
        # the elevation rasters say it
        datum = ds.tags().get("VERTICAL_DATUM")
        assert datum == ("unknown: the input names no vertical CRS" if name in ("dtm.tif", "dsm.tif") else None)
        assert ds.tags(ns="IMAGE_STRUCTURE").get("LAYOUT") == "COG"
        assert ds.block_shapes[0] == (256, 256) and ds.overviews(1)
        assert ds.transform.c % 1.0 == 0 and ds.transform.f % 1.0 == 0


def test_surface_models_are_consistent(run_dir):
    out, _ = run_dir

    def band(name):
        with rasterio.open(out / "out" / name) as ds:
            a = ds.read(1).astype(float)
            a[a == ds.nodata] = np.nan
            return a

    dtm, dsm, ndsm, density = band("dtm.tif"), band("dsm.tif"), band("ndsm.tif"), band("density.tif")
    ok = np.isfinite(dtm) & np.isfinite(dsm)
    assert np.all(ndsm[ok] >= 0)
    np.testing.assert_allclose(ndsm[ok], np.maximum(dsm - dtm, 0)[ok], atol=1e-3)
    # the tallest object: the 15 m building (its roof 15 m above the highest ground under it)
    assert 15.0 < np.nanmax(ndsm) < 25.0
    las = laspy.read(out / "out" / "points.laz")
    usable = ~np.isin(np.asarray(las.classification), (7, 18))
    assert density.sum() == usable.sum()


def test_hillshade_png_and_contours(run_dir):
    out, _ = run_dir
    assert (out / "out" / "hillshade.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    info = pyogrio.read_info(out / "out" / "contours.gpkg")
    assert info["geometry_type"] == "LineString" and info["crs"] == "EPSG:25830"
    assert list(info["fields"]) == ["elevation"] and info["features"] > 50
    meta, _, geometry, fields = pyogrio.raw.read(out / "out" / "contours.gpkg")
    levels = fields[0]
    assert np.allclose(levels, np.round(levels))  # 1 m interval
    with rasterio.open(out / "out" / "dtm.tif") as ds:
        lo, hi = ds.read(1, masked=True).min(), ds.read(1, masked=True).max()
    assert lo <= levels.min() and levels.max() <= hi


def test_accuracy_at_check_points(run_dir):
    out, _ = run_dir
    acc = json.loads((out / "out" / "accuracy.json").read_text())
    assert acc["n"] == 60 and acc["outside"] == 0
    assert acc["rmse_z"] < 0.036  # 1.2 x the 3 cm range noise
    assert acc["n_vegetated"] == 20 and acc["vva_95"] is not None
    assert acc["nva_95"] == pytest.approx(1.96 * acc["by_land_cover"]["open"]["rmse_z"])


def test_report_is_self_contained(run_dir):
    out, _ = run_dir
    page = (out / "out" / "report.html").read_text()
    for section in ("acceptance", "summary", "inputs", "maps", "classes", "strips", "accuracy"):
        assert f'<section id="{section}">' in page
    figures = re.findall(r"<figure>(<svg .*?</svg>)<figcaption>", page, flags=re.S)
    # relief, pulse and point density, strips, classes, voids, check-point residuals, error histogram (the
    # sample's three strips do not overlap on planar patches: no strip-difference maps)
    assert len(figures) == 8
    for svg in figures:
        ElementTree.fromstring(svg)  # well-formed
        for png in re.findall(r'href="data:image/png;base64,([^"]+)"', svg):
            assert base64.b64decode(png)[:8] == b"\x89PNG\r\n\x1a\n"
    assert "http://" not in page and "https://" not in page  # opens offline
    assert "306,405" in page  # points read
    assert "RMSEz" in page
    # the delivered cloud by its product's name, not the intermediate's; the units said once, plainly
    assert "<td>delivered (classified)</td><td>points.laz</td>" in page
    assert "x, y in metre, heights in metre · vertical datum: unknown: the input names no vertical CRS</p>" in page
    assert "unless a heading" not in page
    # the summary's ground is the class table's
    summary = re.search(r"<th>ground points \(class 2, delivered\)</th><td>([\d,]+) \(([\d.]+ %)\)</td>", page)
    table = re.search(r"<tr><td>2</td><td>ground</td><td>([\d,]+)</td><td>([\d.]+ %)</td></tr>", page)
    assert summary and table and summary.groups() == table.groups()
    # the verdict at the top, each failed check listed (the sample's 1.5 pulses/m² fail QL2's 2)
    verdict = json.loads((out / "out" / "qc" / "acceptance.json").read_text())
    failed = [c["description"] for c in verdict["checks"] if c["status"] == "FAIL"]
    assert verdict["status"] == "FAIL" and failed
    banner = re.search(r'<div class="banner fail">(.*?)</div>', page, flags=re.S)
    assert banner and page.index('<div class="banner') < page.index('<section id="acceptance">')
    assert f"{len(failed)} of {len(verdict['checks'])} checks failed" in banner.group(1)
    assert all(html.escape(d) in banner.group(1) for d in failed)
    report = next(s for s in _manifest(out)["stages"] if s["name"] == "report")
    assert len(report["metrics"]["failed_checks"]) == len(failed)


def test_evaluate_dtm_against_truth_and_checkpoints(run_dir, capsys):
    out, _ = run_dir
    dtm = str(out / "out" / "dtm.tif")
    truth = str(ROOT / "data_samples" / "las" / "truth_terrain.tif")
    assert main(["evaluate", "dtm", dtm, "--truth", truth, "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert result["rmse_z"] < 0.05 and abs(result["mean_error"]) < 0.01
    cps = str(ROOT / "data_samples" / "las" / "checkpoints.csv")
    assert main(["evaluate", "dtm", dtm, "--checkpoints", cps]) == 0
    text = capsys.readouterr().out
    assert "60 check points" in text and "NVA 95 %" in text
    with pytest.raises(SystemExit) as exc:  # argparse: --truth or --checkpoints is required
        main(["evaluate", "dtm", dtm])
    assert exc.value.code == 2


def test_building_outlines_and_canopy_height_are_products(run_dir):
    """The sample's scene has buildings and trees: outlines as a GeoPackage 1.2 layer, canopy above the DTM."""
    out, _ = run_dir
    info = pyogrio.read_info(str(out / "out" / "buildings.gpkg"))
    assert info["features"] > 0 and info["geometry_type"] == "MultiPolygon" and info["crs"] == "EPSG:25830"
    meta, _, _, fields = pyogrio.raw.read(str(out / "out" / "buildings.gpkg"))
    height = fields[list(meta["fields"]).index("height")]
    assert (height > 2.0).all()  # a roof stands above its ground
    with sqlite3.connect(out / "out" / "buildings.gpkg") as db:
        assert db.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47  # 'GPKG'
        assert db.execute("PRAGMA user_version").fetchone()[0] == 10200  # GeoPackage 1.2
    with rasterio.open(out / "out" / "canopy_height.tif") as ds:
        chm = ds.read(1, masked=True)
        assert ds.nodata == -999999.0 and chm.count() > 0 and chm.min() >= 0.0
