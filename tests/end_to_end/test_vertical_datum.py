"""Every height product states its vertical datum: named, ellipsoidal, from a geoid grid, or unknown.

Known answers: EPSG's names of the vertical CRSs; a raw flight georeferenced
without a geoid has heights above its CRS's ellipsoid (WGS 84 for the
sample's UTM zone), and with a constant geoid grid of separation N its DTM
is the ellipsoidal DTM lowered by N everywhere (H = h - N).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyproj
import pytest
import rasterio

from lidar.crs import ELLIPSOIDAL, GEOID_GRID, UNKNOWN, VERTICAL_CRS, heights_of
from stages.report.page import heights_datum, page
from tests.conftest import constant_geoid, run_until

ROOT = Path(__file__).resolve().parents[2]
FLIGHT, LAS = ROOT / "configs" / "flight.yaml", ROOT / "configs" / "las.yaml"


def test_a_compound_crs_names_its_vertical_crs():
    nap = heights_of(pyproj.CRS("EPSG:28992+5709"), georeferenced=False)
    assert (nap.kind, nap.datum, nap.warning) == (VERTICAL_CRS, "NAP height (EPSG:5709)", None)
    # named whatever the input: a raw flight's compound output CRS too
    assert heights_of(pyproj.CRS("EPSG:25830+5782"), georeferenced=True).datum == "Alicante height (EPSG:5782)"


def test_las_heights_without_a_vertical_crs_are_unknown_never_ellipsoidal():
    h = heights_of(pyproj.CRS("EPSG:2154"), georeferenced=False)
    assert h.kind == UNKNOWN and "ellipsoid" not in h.datum
    assert "input.override_crs" in h.warning and "EPSG:2154+" in h.warning  # the key, and its form for this CRS


def test_a_raw_flight_without_geoid_is_ellipsoidal_and_warns():
    h = heights_of(pyproj.CRS("EPSG:32630"), georeferenced=True)
    assert h.kind == ELLIPSOIDAL and "WGS 84 ellipsoid" in h.datum
    assert "stages.georeference.geoid" in h.warning
    grs80 = heights_of(pyproj.CRS("EPSG:25830"), georeferenced=True)
    assert "GRS 1980 ellipsoid" in grs80.datum


def test_a_geoid_grid_makes_orthometric_heights_without_a_warning():
    h = heights_of(pyproj.CRS("EPSG:32630"), georeferenced=True, geoid="/grids/egm08_25.gtx")
    assert h.kind == GEOID_GRID and "egm08_25.gtx" in h.datum and h.warning is None


def test_the_report_header_says_the_stage_s_datum():
    metrics = {"parse": {"heights": "NAP height (EPSG:5709)"}}
    assert heights_datum(metrics) == "NAP height (EPSG:5709)"
    assert heights_datum({"georeference": {"heights": "ellipsoidal: x"}, "parse": {}}) == "ellipsoidal: x"
    assert heights_datum({"parse": {}}).startswith("unknown")
    head = page("s", "x, y in metre, heights in metre", [], "NAP height (EPSG:5709)")
    assert "vertical datum: NAP height (EPSG:5709)</p>" in head


def _datum(path: Path) -> str | None:
    with rasterio.open(path) as ds:
        return ds.tags().get("VERTICAL_DATUM")


@pytest.mark.slow
def test_the_flight_states_ellipsoidal_heights_and_a_geoid_lowers_them(tmp_path, capsys):
    runs = run_until(FLIGHT, "rasterize", tmp_path / "h", "stages.report.enabled=false", cache=tmp_path / "c")
    err = capsys.readouterr().err
    assert "WARNING [rasterize] the products' heights are ellipsoidal" in err
    datum = "ellipsoidal: heights above the WGS 84 ellipsoid, no geoid applied"
    assert runs["georeference"]["metrics"]["heights"] == datum
    assert _datum(tmp_path / "h" / "dtm.tif") == _datum(tmp_path / "h" / "dsm.tif") == datum
    assert _datum(tmp_path / "h" / "ndsm.tif") is None  # a height above the ground has no datum
    grid = constant_geoid(tmp_path / "geoid.tif", 51.25)
    runs = run_until(FLIGHT, "rasterize", tmp_path / "H", f"stages.georeference.geoid={grid}", cache=tmp_path / "c")
    assert "heights are ellipsoidal" not in capsys.readouterr().err
    assert runs["georeference"]["metrics"]["heights_kind"] == GEOID_GRID
    assert "geoid.tif" in _datum(tmp_path / "H" / "dtm.tif")
    with rasterio.open(tmp_path / "h" / "dtm.tif") as h, rasterio.open(tmp_path / "H" / "dtm.tif") as big_h:
        a, b = h.read(1, masked=True).filled(np.nan), big_h.read(1, masked=True).filled(np.nan)
    both = np.isfinite(a) & np.isfinite(b)
    assert both.sum() > 1000
    # H = h - N, to the points' and the TIN's precision (the cells hold the same points)
    assert np.median(a[both] - b[both]) == pytest.approx(51.25, abs=0.01)


@pytest.mark.slow
def test_las_heights_unknown_warn_and_a_compound_override_names_them(tmp_path, capsys):
    runs = run_until(LAS, "rasterize", tmp_path / "u", cache=tmp_path / "c")
    err = capsys.readouterr().err
    assert "WARNING [rasterize] the input's CRS names no vertical CRS" in err and "input.override_crs" in err
    assert runs["parse"]["metrics"]["heights_kind"] == UNKNOWN
    assert _datum(tmp_path / "u" / "dtm.tif") == "unknown: the input names no vertical CRS"
    runs = run_until(LAS, "rasterize", tmp_path / "n", "input.override_crs=EPSG:25830+5782", cache=tmp_path / "c")
    assert "names no vertical CRS" not in capsys.readouterr().err
    with rasterio.open(tmp_path / "n" / "dtm.tif") as ds:
        assert ds.tags()["VERTICAL_DATUM"] == "Alicante height (EPSG:5782)"
        assert pyproj.CRS(ds.crs.to_wkt()).is_compound  # GDAL wrote the vertical CRS in the GeoKeys
    assert json.loads((tmp_path / "n" / "run.json").read_text())["status"] == "ok"
