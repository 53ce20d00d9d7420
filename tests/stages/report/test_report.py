"""The QC report and the acceptance against a specification, on surveys of known geometry.

Each survey is a plane z = z0 + 0.01 x sampled on a regular lattice (so its
pulse density is known exactly) written as LAS; the DTM is the plane itself
(plus noise where a test wants a noisy survey).
"""

from __future__ import annotations

import json
import re
import sqlite3
from pathlib import Path
from unittest import mock

import laspy
import numpy as np
import pyogrio
import pyproj
import pytest
from affine import Affine

from lidar.checkpoints import sample_dtm
from lidar.units import Units
from pipeline.cli import main
from stages.accuracy.vertical import vertical_accuracy
from stages.georeference.strips import write_flight_lines
from stages.report.acceptance import SPECIFICATIONS, evaluate
from stages.report.cloud import summarise_cloud
from stages.report.figures import Canvas, map_figures, pulse_density_figure
from stages.report.inputs import ReportInputs, read_flight_lines
from stages.report.maps import MapFrame
from stages.report.measures import measure
from stages.report.page import build_report
from stages.report.sections import run_warnings_section, summary_section

SIZE = 60.0  # survey side, CRS units


def _survey(tmp_path, *, spacing=0.5, keep_every=1, epsg=25830, strips=(1,), z0=650.0, name="s.las"):
    """A LAS of first (single) ground returns on a lattice of *spacing*; strips side by side in x."""
    g = np.arange(spacing / 2, SIZE, spacing)
    x, y = np.meshgrid(g, g)
    x, y = x.ravel()[::keep_every] + 1000.0, y.ravel()[::keep_every] + 2000.0
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.add_crs(pyproj.CRS.from_epsg(epsg))
    header.scales = [0.001] * 3
    header.offsets = [1000.0, 2000.0, 0.0]
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z0 + 0.01 * (x - 1000.0)
    band = np.minimum((x - 1000.0) / SIZE * len(strips), len(strips) - 1).astype(int)
    las.point_source_id = np.asarray(strips)[band]
    las.return_number = np.ones(len(x), np.uint8)
    las.number_of_returns = np.ones(len(x), np.uint8)
    las.classification = np.full(len(x), 2, np.uint8)
    las.gps_time = np.linspace(1e8, 1e8 + 60, len(x))
    path = tmp_path / name
    las.write(str(path))
    return path


def _dtm(cell=1.0, z0=650.0, noise=0.0, seed=0):
    n = int(SIZE / cell)
    xc = (np.arange(n) + 0.5) * cell
    dtm = np.tile(z0 + 0.01 * xc, (n, 1))
    return dtm + np.random.default_rng(seed).normal(0.0, noise, dtm.shape) if noise else dtm


def _transform(cell=1.0):
    """The DTM's map transform: cells of *cell* from the survey's north-west corner."""
    return Affine(cell, 0, 1000.0, 0, -cell, 2000.0 + SIZE)


def _report(tmp_path, las, dtm, cell=1.0, metrics=None, figures=False, **extra):
    """The page, the verdict, the inputs and the DTM's transform.  The maps (about 1 s of drawing) only
    when *figures*: the tests of text and verdicts read neither, and the verdict is measured before them."""
    cloud = summarise_cloud(las, origin=(1000.0, 2000.0 + SIZE), resolution=cell, shape=dtm.shape, dtm=dtm)
    frame = MapFrame(1000.0, 2000.0 + SIZE, cell, "m")
    data = ReportInputs(dtm=dtm, density=np.ones_like(dtm), frame=frame, cloud=cloud, **extra)
    metrics = metrics or {}
    metrics.setdefault("rasterize", {"cols": dtm.shape[1], "rows": dtm.shape[0], "method": "tin"})
    with mock.patch("stages.report.page.map_figures", wraps=map_figures if figures else lambda *a: []):
        page, verdict = build_report(name="t", metrics=metrics, data=data, max_size=300)
    return page, verdict, data, _transform(cell)


@pytest.fixture(scope="module")
def plain(tmp_path_factory):
    """The report of the plain survey (a 0.5-m lattice, one strip) and its DTM, with no other input:
    built once, read by the tests that need nothing more."""
    root = tmp_path_factory.mktemp("plain")
    las = _survey(root)
    return las, _report(root, las, _dtm())


def _text(page: str) -> str:
    return re.sub(r"\s+", " ", re.sub(r"<[^>]+>", " ", page))


def _check(verdict: dict, measure_key: str) -> dict:
    return next(c for c in verdict["checks"] if c["measure"] == measure_key)


def test_one_strip_is_counted_not_named_by_its_id(tmp_path):
    """autzen has one strip, point_source_id 7326: the summary says 1, and names the id."""
    page, *_ = _report(tmp_path, _survey(tmp_path, strips=(7326,)), _dtm())
    text = _text(page)
    assert "flight strips 1 (point_source_id 7326)" in text
    assert "7,326" not in text


def test_three_strips_are_three(tmp_path):
    page, *_ = _report(tmp_path, _survey(tmp_path, strips=(1, 2, 3)), _dtm())
    assert "flight strips 3 (point_source_id 1, 2, 3)" in _text(page)


def test_a_survey_in_feet_says_feet_for_cells_and_elevations(tmp_path):
    """EPSG:2992 (Oregon Lambert, international foot): a 1-ft DTM of heights 406-...; no 'm' on them."""
    las = _survey(tmp_path, epsg=2992, z0=406.0)
    page, *_ = _report(tmp_path, las, _dtm(z0=406.0), figures=True)
    text = _text(page)
    assert "cells of 1 ft (0.3048 m)" in text
    assert "DTM elevation range 406.00 – 406.60 ft" in text
    assert "406.00 – 406.60 m" not in text and "cells of 1 m" not in text


def test_input_files_are_listed(tmp_path):
    files = [("scanner / point file", "/data/scan.lmsq"), ("sbet", "/data/trajectory.sbet")]
    page, *_ = _report(tmp_path, _survey(tmp_path), _dtm(), input_files=files)
    text = _text(page)
    assert "input files 2" in text
    assert "/data/scan.lmsq" in text and "/data/trajectory.sbet" in text


def test_strip_table_says_which_strips_were_adjusted(tmp_path):
    """strip_corrections.json of a run where strip 2 was not determined: it is not called adjusted."""
    corrections = {
        "datum": "strip 3",
        "note": None,
        "strips": {
            str(s): {
                "translation_m": [0.1 * s, 0, 0],
                "rotation_deg": [0, 0, 0],
                "sigma_translation_m": [0.01, 0.01, 0.01],
                "points": 100 * s,
            }
            for s in (1, 2, 3)
        },
        "not_determined": {"2": {"sigma_translation_m": [0.2, 0.2, 0.01]}},
        "pairs": [],
    }
    page, *_ = _report(tmp_path, _survey(tmp_path, strips=(1, 2, 3, 4)), _dtm(), corrections=corrections)
    text = _text(page)
    assert "1 100 adjusted" in text
    assert "2 200 not determined: left as it is" in text
    assert "3 300 datum (held fixed)" in text
    assert "4 — no overlap with another strip: not adjusted" in text
    assert "strips_adjusted" not in text


def test_nva_and_vva_are_labelled_with_the_edition_that_states_them(tmp_path):
    """The issue's figures: RMSEz 0.134 on all points, NVA 0.099 = 1.96 x 0.0505 (open ground).  ASPRS Edition 2
    (and the LBS from 2024 rev. A) state NVA and VVA as RMSEz; the 95 % figures are labelled as Edition 1's."""
    acc = {
        "n": 29,
        "rmse_z": 0.134,
        "mean_error": -0.02,
        "n_non_vegetated": 19,
        "nva_95": 0.099,
        "n_vegetated": 10,
        "vva_95": 0.4,
        "vva_rmse_z": 0.25,
        "outside": 1,
    }
    page, *_ = _report(tmp_path, _survey(tmp_path), _dtm(), metrics={"accuracy": acc})
    text = _text(page)
    assert "RMSEz, all 29 check points on the DTM (m) 0.134" in text
    assert "NVA = RMSEz, non-vegetated (19 check points) (m) 0.051" in text
    assert "VVA = RMSEz, vegetated (10 check points) (m) 0.25" in text
    before = "ASPRS Edition 1 and the USGS LBS to 2023 rev. A"
    assert f"NVA at 95 % as in {before}: 1.96 × RMSEz, non-vegetated (m) 0.099" in text
    assert f"VVA as in {before}: 95th percentile of |error|, vegetated (m) 0.4" in text


def test_pulse_density_is_the_lattice_density_and_a_thinned_survey_fails_it(tmp_path, plain):
    """A 0.5-m lattice is 4 pulses/m²: QL2 (2/m²) passes; kept every 4th point it is 1/m² and fails."""
    dense = plain[1][1]  # the plain survey: spacing 0.5
    assert _check(dense, "anpd")["measured"] == pytest.approx(4.0, rel=0.01)
    assert _check(dense, "anpd")["status"] == "PASS"
    thin = _report(tmp_path, _survey(tmp_path, spacing=0.5, keep_every=4, name="t.las"), _dtm())[1]
    assert _check(thin, "anpd")["measured"] == pytest.approx(1.0, rel=0.01)
    assert _check(thin, "anpd")["status"] == "FAIL" and thin["status"] == "FAIL"
    # QL1 asks 8/m²: the dense survey fails it too
    ql1 = evaluate("usgs-lbs-ql1", dense["measured"])
    assert _check(ql1, "anpd")["status"] == "FAIL"


def test_a_noisy_survey_fails_nva(tmp_path):
    """Check points on the true plane; DTM noise 15 cm gives NVA = RMSEz ~ 0.15 m > 0.10 m (QL2, LBS 2024 rev. A)."""
    rng = np.random.default_rng(1)
    xy = np.column_stack((rng.uniform(1005, 1055, 40), rng.uniform(2005, 2055, 40)))
    truth = 650.0 + 0.01 * (xy[:, 0] - 1000.0)
    las = _survey(tmp_path)
    verdicts = {}
    for noise in (0.02, 0.15):
        dtm = _dtm(noise=noise)
        acc = vertical_accuracy(sample_dtm(dtm, _transform(), xy) - truth)
        verdicts[noise] = _report(tmp_path, las, dtm, metrics={"accuracy": acc})[1]
    assert _check(verdicts[0.02], "rmse_z_nv")["status"] == "PASS"
    noisy = _check(verdicts[0.15], "rmse_z_nv")
    assert noisy["status"] == "FAIL" and noisy["measured"] == pytest.approx(0.15, rel=0.3)
    asprs = evaluate("asprs-2023-10cm", verdicts[0.15]["measured"])
    assert _check(asprs, "rmse_z_nv")["status"] == "FAIL"


def test_a_hole_in_the_survey_is_a_void(tmp_path, plain):
    """Points removed in a 10 x 10 m square inside the survey: voids are counted and the spec fails."""
    path, (_, whole, _, _) = plain
    las = laspy.read(str(path))
    x, y = np.asarray(las.x) - 1000.0, np.asarray(las.y) - 2000.0
    las.points = las.points[~((x > 20) & (x < 30) & (y > 20) & (y < 30))]
    las.write(str(tmp_path / "hole.las"))
    holed = _report(tmp_path, tmp_path / "hole.las", _dtm())[1]
    assert _check(whole, "voids")["measured"] == 0 and _check(whole, "voids")["status"] == "PASS"
    assert _check(holed, "voids")["measured"] > 0 and _check(holed, "voids")["status"] == "FAIL"


def test_every_limit_names_its_source():
    for name, (title, limits) in SPECIFICATIONS.items():
        assert title
        for lim in limits:
            assert lim.source.document and lim.source.edition and lim.source.table, (name, lim)
    assert len([n for n, (_, lims) in SPECIFICATIONS.items() if lims]) >= 2


#: The edition each LBS row follows (issue 53): 2024 rev. A where it changed the row (absolute vertical accuracy,
#: after ASPRS Edition 2), 2023 rev. A where the row's 2024 text was not read.
LBS_ROW_EDITIONS = {
    "anpd": "2023 rev. A",
    "rmse_z_nv": "2024 rev. A",
    "vva_rmse_z": "2024 rev. A",
    "smooth_surface_repeatability": "2023 rev. A",
    "swath_overlap_rmsdz": "2023 rev. A",
    "swath_overlap_max": "2023 rev. A",
    "voids": "2023 rev. A",
    "class_0": "2023 rev. A",
    "dem_float_bits": "2023 rev. A",
    "dem_nodata": "2023 rev. A",
    "unflat_water": "2023 rev. A",
    "rising_rivers": "2023 rev. A",
    "decks_in_dem": "2023 rev. A",
}


def test_each_row_names_the_edition_it_follows():
    """Every row of every specification, its edition by name; a 2023 rev. A row says why it is not 2024 rev. A."""
    for spec in ("usgs-lbs-ql1", "usgs-lbs-ql2"):
        _, limits = SPECIFICATIONS[spec]
        assert {lim.measure: lim.source.edition for lim in limits} == LBS_ROW_EDITIONS, spec
        for lim in limits:
            assert lim.source.document == "USGS Lidar Base Specification"
            if lim.source.edition == "2023 rev. A":
                assert lim.source.checked.startswith("follows 2023 rev. A, not 2024 rev. A: "), lim
            else:
                assert "2024 rev. A is the current edition, released 2024-01-25" in lim.source.checked, lim
    _, asprs = SPECIFICATIONS["asprs-2023-10cm"]
    assert {lim.source.edition for lim in asprs} == {"Edition 2, Version 1.0 (2023)"}
    assert (
        "2024 rev. A for absolute vertical accuracy, 2023 rev. A for the other rows"
        in (SPECIFICATIONS["usgs-lbs-ql2"][0])
    )


def test_lbs_nva_is_the_rmse_z_against_10_cm():
    """LBS 2024 rev. A (ASPRS Edition 2): NVA is the RMSEz itself, at most 10 cm for QL1 and QL2; the 95 % figure
    (1.96 x RMSEz against 19.6 cm, until 2023 rev. A) is no row."""
    for spec in ("usgs-lbs-ql1", "usgs-lbs-ql2"):
        nva = _check(evaluate(spec, {"rmse_z_nv": 0.100}), "rmse_z_nv")
        assert nva["limit"] == 0.10 and nva["bound"] == "at most" and nva["status"] == "PASS"
        assert nva["source"]["table"].startswith("Table 4") and nva["source"]["edition"] == "2024 rev. A"
        assert _check(evaluate(spec, {"rmse_z_nv": 0.101}), "rmse_z_nv")["status"] == "FAIL"
        assert "nva_95" not in {c["measure"] for c in evaluate(spec, {})["checks"]}


def test_lbs_vva_is_reported_not_judged():
    """LBS 2024 rev. A (ASPRS Edition 2): VVA is the RMSEz at the vegetated check points, reported without
    pass/fail; until 2023 rev. A its 95th percentile failed above 30 cm."""
    for spec in ("usgs-lbs-ql1", "usgs-lbs-ql2", "asprs-2023-10cm"):
        verdict = evaluate(spec, {"vva_95": 0.9, "vva_rmse_z": 0.6, "rmse_z_nv": 0.05})
        vva = _check(verdict, "vva_rmse_z")
        assert vva["limit"] is None and vva["measured"] == 0.6 and vva["status"] == "REPORTED"
        assert "vva_95" not in {c["measure"] for c in verdict["checks"]}
        assert "FAIL" not in {c["status"] for c in verdict["checks"]}


def test_every_section_is_there_and_every_image_has_a_legend(tmp_path):
    acc = {
        "n": 3,
        "rmse_z": 0.02,
        "mean_error": 0.0,
        "n_non_vegetated": 3,
        "nva_95": 0.04,
        "n_vegetated": 0,
        "vva_95": None,
        "outside": 0,
    }
    cp = {
        "id": ["A", "B", "C"],
        "land_cover": ["open"] * 3,
        "x": np.array([1010.0, 1030.0, 1050.0]),
        "y": np.array([2010.0, 2030.0, 2050.0]),
        "z": np.array([650.1, 650.3, 650.5]),
        "dtm": np.array([650.12, 650.28, 650.5]),
        "error": np.array([0.02, -0.02, 0.0]),
    }
    diff = np.full((10, 10), 0.01)
    page, *_ = _report(
        tmp_path,
        _survey(tmp_path, strips=(1, 2)),
        _dtm(),
        metrics={"accuracy": acc},
        checkpoints=cp,
        differences=(diff, diff / 2, MapFrame(1000.0, 2060.0, 6.0, "m")),
        uncertainty=np.full((60, 60), 0.05),
        trajectory=[(np.array([1000.0, 1060.0]), np.array([2030.0, 2030.0]), "strip 1")],
        figures=True,
    )
    for section in ("acceptance", "summary", "inputs", "maps", "classes", "raw", "strips", "accuracy"):
        assert f'<section id="{section}">' in page
    figures = re.findall(r"<figure>(.*?)</figure>", page, flags=re.S)
    images = re.findall(r"<figure><svg ", page)
    # relief, pulse and point density, strips, classes, 2 differences, voids, residuals, uncertainty, flight lines,
    # histogram
    assert len(figures) == len(images) == 12
    for fig in figures:
        caption = re.search(r"<figcaption>(.+?)</figcaption>", fig, flags=re.S)
        assert caption and len(caption.group(1)) > 20
    assert "http://" not in page and "https://" not in page
    assert "A open 1010.000 2010.000 650.100 650.120 +0.020" in _text(page)  # one row per check point


def test_measure_reports_why_a_value_is_missing(plain):
    _, (_, verdict, data, _) = plain
    values, why, _ = measure({}, data)
    assert values["nva_95"] is None and "stages.accuracy.checkpoints" in why["nva_95"]
    assert values["vva_rmse_z"] is None and "stages.accuracy.checkpoints" in why["vva_rmse_z"]
    assert _check(verdict, "rmse_z_nv")["status"] == "NOT MEASURED"
    assert _check(verdict, "vva_rmse_z")["status"] == "REPORTED"
    assert verdict["status"] == "INCOMPLETE"


def test_the_acceptance_table_and_json_name_each_rows_edition(tmp_path):
    """The page's row of the NVA says 2024 rev. A, the pulse density's 2023 rev. A; the verdict written to
    qc/acceptance.json carries the edition of every row, and the check points' VVA as RMSEz."""
    acc = {"n": 12, "rmse_z": 0.05, "n_non_vegetated": 8, "nva_95": 0.098, "n_vegetated": 4, "vva_95": 0.3}
    acc["vva_rmse_z"] = 0.2
    page, verdict, *_ = _report(tmp_path, _survey(tmp_path), _dtm(), metrics={"accuracy": acc})
    rows = {_text(r).split(" ", 2)[1]: _text(r) for r in re.findall(r"<tr class=.*?</tr>", page, flags=re.S)}
    assert "USGS Lidar Base Specification, 2024 rev. A, Table 4" in rows["NVA:"]
    assert "USGS Lidar Base Specification, 2024 rev. A, Table 4" in rows["VVA:"] and "reported only" in rows["VVA:"]
    assert "USGS Lidar Base Specification, 2023 rev. A, Table 1" in rows["aggregate"]
    written = json.loads(json.dumps(verdict, default=float))  # as the stage writes qc/acceptance.json
    assert {c["measure"]: c["source"]["edition"] for c in written["checks"]} == LBS_ROW_EDITIONS
    assert _check(written, "rmse_z_nv")["measured"] == pytest.approx(0.05)
    assert _check(written, "rmse_z_nv")["status"] == "PASS"
    assert _check(written, "vva_rmse_z")["measured"] == 0.2


def test_flight_lines_are_written_one_feature_a_strip(tmp_path):
    """qc/trajectory.gpkg: a LineString per flight line with its id, times and heights; turns (0) left out."""
    t = np.arange(0.0, 30.0, 1.0)
    strip = np.repeat([1, 0, 2], 10)
    xyz = np.column_stack((440000 + 10 * t, 4474000 + 0 * t, 700 + t))
    path = tmp_path / "trajectory.gpkg"
    write_flight_lines(path, t, xyz, strip, pyproj.CRS.from_epsg(32630))
    info = pyogrio.read_info(str(path))
    assert info["features"] == 2 and info["geometry_type"] == "LineString" and info["crs"] == "EPSG:32630"
    _, _, _, fields = pyogrio.raw.read(str(path))
    names = list(info["fields"])
    assert fields[names.index("strip")].tolist() == [1, 2]
    assert fields[names.index("time_start")].tolist() == [0.0, 20.0]
    assert fields[names.index("time_end")].tolist() == [9.0, 29.0]
    assert fields[names.index("altitude_min")].tolist() == [700.0, 720.0]
    lines = read_flight_lines(path)
    assert [name for *_, name in lines] == ["strip 1", "strip 2"]
    # without GDAL too (ogrinfo is not installed here): the standard library's SQLite reads a GeoPackage 1.2
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47  # 'GPKG'
        assert db.execute("PRAGMA user_version").fetchone()[0] == 10200
        assert db.execute(
            "SELECT data_type, srs_id FROM gpkg_contents WHERE table_name = 'flight_lines'"
        ).fetchall() == [("features", 32630)]
        assert db.execute("SELECT strip, time_start FROM flight_lines ORDER BY strip").fetchall() == [
            (1, 0.0),
            (2, 20.0),
        ]
        assert db.execute("PRAGMA integrity_check").fetchone()[0] == "ok"
    assert lines[1][0].tolist() == (440000 + 10 * t[20:]).tolist()


@pytest.mark.slow
def test_main_job_report_and_acceptance_against_two_specifications(tmp_path):
    """configs/flight.yaml end to end: qc/acceptance.json for QL2 (default) and ASPRS 2023, every section."""
    config = Path(__file__).resolve().parents[3] / "configs" / "flight.yaml"
    verdicts = {}
    for spec in ("usgs-lbs-ql2", "asprs-2023-10cm"):
        out = tmp_path / spec
        args = ["run", str(config), "-q", "--set", f"output={out}", "--set", f"cache={tmp_path / 'cache'}"]
        assert main([*args, "--set", f"stages.report.specification={spec}"]) == 0
        verdicts[spec] = json.loads((out / "qc" / "acceptance.json").read_text())
        page = (out / "report.html").read_text()
        for section in ("acceptance", "summary", "inputs", "maps", "classes", "raw", "strips", "accuracy"):
            assert f'<section id="{section}">' in page
        assert "acquisition.log.gz" in _text(page) and "flight lines" in page
    ql2 = {c["measure"]: c for c in verdicts["usgs-lbs-ql2"]["checks"]}
    assert ql2["anpd"]["limit"] == 2.0 and ql2["anpd"]["source"]["table"].startswith("Table 1")
    assert ql2["anpd"]["source"]["edition"] == "2023 rev. A"
    assert ql2["rmse_z_nv"]["status"] == "PASS"  # the sample's open ground: NVA 0.06 m at 95 %, RMSEz 0.03 m
    assert ql2["rmse_z_nv"]["source"]["edition"] == "2024 rev. A"
    # the simulated vegetation: 10 vegetated check points; LBS 2024 rev. A reports their RMSEz without pass/fail
    vva = json.loads((tmp_path / "usgs-lbs-ql2" / "accuracy.json").read_text())["vva_rmse_z"]
    assert ql2["vva_rmse_z"]["measured"] == pytest.approx(vva) and ql2["vva_rmse_z"]["status"] == "REPORTED"
    asprs = {c["measure"]: c for c in verdicts["asprs-2023-10cm"]["checks"]}
    assert asprs["vva_rmse_z"]["status"] == "REPORTED" and "anpd" not in asprs


def test_every_limit_names_where_it_was_checked():
    for _, limits in SPECIFICATIONS.values():
        for lim in limits:
            assert "http" in lim.source.checked or "doi:" in lim.source.checked, lim


def test_the_summary_counts_the_delivered_ground_as_the_class_table_does():
    """The ground filter kept 900 points; later stages took 150 of them (roofs, water): the summary's ground
    is the delivered cloud's 750 (of 1,000 points), beside the filter's own count."""
    dtm = np.full((4, 4), 100.0)
    cv = Canvas.of(dtm, MapFrame(0.0, 4.0, 1.0, "m"), Units.of(pyproj.CRS.from_epsg(25830)), 256)
    counts = np.zeros(256, dtype=np.int64)
    counts[[1, 2, 6]] = [100, 750, 150]
    verdict = {"title": "none", "status": "not judged"}
    metrics = {"classify_ground": {"ground": 900, "ground_fraction": 0.9}}
    html_ = summary_section(metrics, verdict, cv, np.array([1]), 1, None, counts)
    assert "<th>ground points (class 2, delivered)</th><td>750 (75.00 %)</td>" in html_
    assert "<th>ground points by the ground filter</th><td>900</td>" in html_


def test_all_points_per_m2_are_over_the_first_returns_covered_area():
    """Half the DTM grid has points (2 first returns and 3 points a m²), the other half none: all points are
    3 per m² over the covered area, as the first returns are 2 (over the whole grid: 1.5, fewer than pulses)."""
    dtm = np.full((20, 20), 100.0)
    cv = Canvas.of(dtm, MapFrame(0.0, 20.0, 1.0, "m"), Units.of(pyproj.CRS.from_epsg(25830)), 256)
    first, density = np.zeros((20, 20)), np.full((20, 20), np.nan)
    first[:10], density[:10] = 2.0, 3.0
    assert "All points: 3.00 per m² over the same covered area." in pulse_density_figure(cv, first, density, 2.0)


def test_every_warning_of_the_run_is_on_the_page():
    metrics = {
        "parse": {"log_warnings": ["return number 0 on every point"]},
        "classify_ground": {"ground": 5},
        "classify_objects": {"log_warnings": ["sparse survey filtered on 17 m cells", "a <b> tag"]},
    }
    page = run_warnings_section(metrics)
    assert "3 warning(s)" in page
    assert "<li><b>parse</b>: return number 0 on every point</li>" in page
    assert "<li><b>classify_objects</b>: a &lt;b&gt; tag</li>" in page  # escaped
    assert "None: no stage logged a warning" in run_warnings_section({"parse": {}})
