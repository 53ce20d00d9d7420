"""Valid but odd surveys, through the command line: smaller than one cell,
water only, water classified by the provider."""

from __future__ import annotations

import json

import laspy
import numpy as np
import pyogrio
import rasterio
from pyproj import CRS

from pipeline.cli import main


def _write(path, x, y, z, cls=0):
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = [0.001] * 3
    header.offsets = [float(x.min()), float(y.min()), 0.0]
    header.add_crs(CRS.from_epsg(25830))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.classification = np.broadcast_to(np.asarray(cls, np.uint8), x.shape)
    las.return_number = las.number_of_returns = np.ones(len(x), np.uint8)
    las.write(str(path))


def _run(tmp_path, name, **sets):
    """``pipeline run`` on *name*.laz, without the report (about 2 s of maps that these tests do not read)."""
    (tmp_path / f"{name}.yaml").write_text(f"input: {{format: las, paths: [{name}.laz]}}\noutput: out\ncache: cache\n")
    args = ["run", str(tmp_path / f"{name}.yaml"), "-q", "--set", "stages.report.enabled=false"]
    for key, value in sets.items():
        args += ["--set", f"{key}={value}"]
    return main(args)


def test_area_smaller_than_one_cell_gives_a_one_cell_dtm(tmp_path):
    rng = np.random.default_rng(1)
    n = 40  # a 0.5 m x 0.5 m patch of a plane z = 100 + 0.02 x, inside the cell [440000, 440001)
    x, y = 440000.25 + 0.5 * rng.random(n), 4474000.25 + 0.5 * rng.random(n)
    _write(tmp_path / "tiny.laz", x, y, 100.0 + 0.02 * (x - 440000.0))
    assert _run(tmp_path, "tiny") == 0
    with rasterio.open(tmp_path / "out" / "dtm.tif") as ds:
        assert ds.shape == (1, 1)
        assert (ds.transform.c, ds.transform.f) == (440000.0, 4474001.0)
        assert abs(float(ds.read(1)[0, 0]) - 100.01) < 1e-3  # the plane at the cell centre
    assert pyogrio.read_info(tmp_path / "out" / "contours.gpkg")["features"] == 0  # no contour fits in one cell
    with laspy.open(tmp_path / "out" / "points.laz") as f:
        assert f.header.point_count == n


def test_water_only_survey_is_one_sentence_exit_3_and_no_products(tmp_path, capsys):
    rng = np.random.default_rng(2)
    n = 5000
    x, y = 440000 + 100 * rng.random(n), 4474000 + 100 * rng.random(n)
    _write(tmp_path / "lake.laz", x, y, 100.0 + rng.normal(0, 0.02, n), cls=9)
    assert _run(tmp_path, "lake") == 3
    err = capsys.readouterr().err
    assert "only 0 ground points (class 2) among 5,000 points" in err and "class 9: " in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not list((tmp_path / "out").glob("*.tif")) and not list((tmp_path / "out").glob("*.laz"))
    assert json.loads((tmp_path / "out" / "run.json").read_text())["status"] == "failed"


def test_water_classified_by_the_provider_stays_water(tmp_path):
    rng = np.random.default_rng(3)
    n = 20000
    x, y = 440000 + 100 * rng.random(n), 4474000 + 100 * rng.random(n)
    lake = x > 440060  # a flat lake 1 m below the east edge of a gentle slope
    z = np.where(lake, 99.0, 100.0 + 0.01 * (440060 - x))
    _write(tmp_path / "shore.laz", x, y, z, cls=np.where(lake, 9, 0))
    assert _run(tmp_path, "shore") == 0
    out = laspy.read(tmp_path / "out" / "points.laz")
    order = np.lexsort((out.y, out.x))  # output order may differ: compare by position
    ref = np.lexsort((y, x))
    cls = np.asarray(out.classification)[order]
    assert np.all(cls[lake[ref]] == 9)
    assert np.mean(cls[~lake[ref]] == 2) > 0.95
    # keep_water: false -> the flat lake surface is ground again, as any filter would call it ...
    off = {"stages.classify_ground.keep_water": "false", "stages.classify_water.enabled": "false"}
    assert _run(tmp_path, "shore", **off) == 0
    out = laspy.read(tmp_path / "out" / "points.laz")
    assert np.mean(np.asarray(out.classification)[np.lexsort((out.y, out.x))][lake[ref]] == 2) > 0.95
    # ... and classify_water finds it water: level, 40 m x 100 m; the 1 % slope beside it stays ground
    assert _run(tmp_path, "shore", **{"stages.classify_ground.keep_water": "false"}) == 0
    out = laspy.read(tmp_path / "out" / "points.laz")
    cls = np.asarray(out.classification)[np.lexsort((out.y, out.x))]
    assert np.all(cls[lake[ref]] == 9) and np.mean(cls[~lake[ref]] == 2) > 0.95
