"""Issue 22: what real LAS/LAZ files say is kept, products are typed right, ``pipeline info``.

The files are public test data of other projects (``../shared/data/real/``,
see its README); the known answers are what the files themselves hold, read
with laspy, and what the LAS 1.4 and GeoPackage specifications say.
"""

from __future__ import annotations

import ctypes
import json
import sqlite3
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
import rasterio
from affine import Affine

from lidar.gridrun.point_tiles import merge_classes
from lidar.mosaic import RasterMosaic
from lidar.rasters import write_cog
from lidar.vectors import write_lines_gpkg
from pipeline import __version__
from pipeline.cli import main
from pipeline.errors import InputDataError
from stages.classify_ground.csf import csf
from stages.parse.read_las import convert_las_files
from tests.shared_data import REAL

ROOT = Path(__file__).resolve().parents[3]
TOPOGRAPHY = REAL / "lidR" / "Topography.laz"
COLOUR = REAL / "pdal" / "1.2-with-color.las"
FULLWAVE = REAL / "laspy" / "fullwave.laz"
AUTZEN = REAL / "pdal" / "autzen_trim.las"


def _convert(path: Path, dst: Path, assign=None):
    return convert_las_files(
        [path],
        dst,
        crs_setting="auto-utm",
        assign_crs=pyproj.CRS.from_user_input(assign) if assign else None,
        chunk_size=20_000,
    )


def test_adjusted_standard_gps_time_is_kept_in_the_intermediate(tmp_path):
    """Topography.laz: global encoding bit 0 = 1 (adjusted standard GPS time, values about 2.2e8)."""
    _convert(TOPOGRAPHY, tmp_path / "points.las")
    src, out = laspy.read(TOPOGRAPHY), laspy.read(tmp_path / "points.las")
    assert int(src.header.global_encoding.gps_time_type) == 1
    assert int(out.header.global_encoding.gps_time_type) == 1  # was 0: the times read as seconds of the week
    np.testing.assert_array_equal(np.asarray(out.gps_time), np.asarray(src.gps_time))
    assert out.header.generating_software == f"dtm-pipeline {__version__}"  # was "laspy 2.7.0"
    assert out.header.system_identifier == "dtm-pipeline"
    for name in ("scan_direction_flag", "edge_of_flight_line", "intensity", "point_source_id"):
        np.testing.assert_array_equal(np.asarray(out[name]), np.asarray(src[name]), err_msg=name)


def test_week_time_stays_week_time(tmp_path):
    """fullwave.laz has GPS week seconds (bit 0 = 0): not turned into standard time."""
    _convert(FULLWAVE, tmp_path / "points.las")
    assert int(laspy.read(tmp_path / "points.las").header.global_encoding.gps_time_type) == 0


def test_rgb_of_a_las_1_2_file_is_kept(tmp_path):
    """1.2-with-color.las: point format 3 with RGB, no CRS (EPSG:2992 per its README)."""
    _convert(COLOUR, tmp_path / "points.las", assign="EPSG:2992")
    src, out = laspy.read(COLOUR), laspy.read(tmp_path / "points.las")
    assert out.header.point_format.id == 7  # LAS 1.4 with RGB; was 6, colour dropped
    for band in ("red", "green", "blue"):
        np.testing.assert_array_equal(np.asarray(out[band]), np.asarray(src[band]))
    assert np.asarray(out.red).max() > 0


def test_nir_is_kept_and_the_dropped_waveform_is_named(tmp_path):
    """fullwave.laz: point format 10 (RGB, NIR, waveform packets)."""
    _, report, _ = _convert(FULLWAVE, tmp_path / "points.las")
    src, out = laspy.read(FULLWAVE), laspy.read(tmp_path / "points.las")
    assert out.header.point_format.id == 8
    np.testing.assert_array_equal(np.asarray(out.nir), np.asarray(src.nir))
    assert len(report.dropped) == 1 and "wavepacket_index" in report.dropped[0] and "waveform" in report.dropped[0]
    assert not out.header.global_encoding.waveform_data_packets_external  # no waveform claimed


def test_real_extra_bytes_and_user_vlrs_are_kept(tmp_path):
    """MixedConifer.laz has an extra-byte treeID (f8); mvk-thin.las two NIIRS10 VLRs (timestamp, tile index)."""
    src_path = REAL / "lidR" / "MixedConifer.laz"
    _convert(src_path, tmp_path / "trees.las")
    src, out = laspy.read(src_path), laspy.read(tmp_path / "trees.las")
    assert list(out.point_format.extra_dimension_names) == ["treeID"]
    np.testing.assert_array_equal(np.asarray(out.treeID), np.asarray(src.treeID))
    src_path = REAL / "pdal" / "mvk-thin.las"
    _convert(src_path, tmp_path / "mvk.las")
    theirs = {
        (v.user_id, v.record_id): v.record_data for v in laspy.read(src_path).header.vlrs if v.user_id == "NIIRS10"
    }
    ours = {
        (v.user_id, v.record_id): v.record_data
        for v in laspy.read(tmp_path / "mvk.las").header.vlrs
        if v.user_id == "NIIRS10"
    }
    assert len(theirs) == 2 and all(ours.get(k) == data for k, data in theirs.items())


def _with_extra_bytes(path: Path, *, version: str, point_format: int, crs: str) -> laspy.LasData:
    rng = np.random.default_rng(3)
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales, header.offsets = np.array([0.01] * 3), np.array([500000.0, 4000000.0, 0.0])
    header.add_extra_dims(
        [
            laspy.ExtraBytesParams("reflectance", "i2", description="dB x 100", scales=[0.01], offsets=[0.0]),
            laspy.ExtraBytesParams("deviation", "u1", description="pulse shape"),
        ]
    )
    header.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(header)
    n = 500
    las.x, las.y = 500000 + rng.uniform(0, 50, n), 4000000 + rng.uniform(0, 50, n)
    las.z = rng.uniform(100, 110, n)
    las.reflectance = rng.uniform(-20, 5, n)
    las.deviation = rng.integers(0, 255, n)
    las.write(str(path))
    return laspy.read(path)


@pytest.mark.parametrize(
    ("version", "point_format", "crs"),
    [("1.4", 6, "EPSG:32630"), ("1.2", 1, "EPSG:32630"), ("1.4", 6, "EPSG:25830")],
    ids=["copied-as-delivered", "converted", "reprojected"],
)
def test_extra_bytes_are_carried_through(tmp_path, version, point_format, crs):

    src = _with_extra_bytes(tmp_path / "in.las", version=version, point_format=point_format, crs=crs)
    _convert(tmp_path / "in.las", tmp_path / "points.las")
    out = laspy.read(tmp_path / "points.las")
    assert list(out.point_format.extra_dimension_names) == ["reflectance", "deviation"]
    np.testing.assert_array_equal(np.asarray(out.deviation), np.asarray(src.deviation))
    np.testing.assert_allclose(np.asarray(out.reflectance), np.asarray(src.reflectance), atol=1e-9)
    # and through a stage that rewrites the classes
    result = tmp_path / "result"
    result.mkdir()
    np.save(result / "idx.npy", np.arange(len(src.points)))
    np.save(result / "classification.npy", np.full(len(src.points), 2, np.uint8))
    merge_classes(tmp_path / "points.las", tmp_path / "classified.las", [result])
    merged = laspy.read(tmp_path / "classified.las")
    np.testing.assert_array_equal(np.asarray(merged.deviation), np.asarray(src.deviation))
    assert (np.asarray(merged.classification) == 2).all()


def test_inputs_with_different_gps_time_types_are_refused(tmp_path):
    week = tmp_path / "week.las"
    _with_extra_bytes(week, version="1.4", point_format=6, crs="EPSG:32630")
    standard = tmp_path / "standard.las"
    las = laspy.read(week)
    las.header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    las.write(str(standard))
    with pytest.raises(InputDataError, match="adjusted standard GPS time but .*week.las GPS week seconds"):
        convert_las_files(
            [standard, week], tmp_path / "out.las", crs_setting="auto-utm", assign_crs=None, chunk_size=1000
        )


# --------------------------------------------------------------------------
# Products


def test_elevation_rasters_name_their_unit_and_vertical_crs(tmp_path):

    transform = Affine(1, 0, 0, 0, -1, 300)
    compound = pyproj.CRS.from_user_input("EPSG:2992+8228")  # Oregon Lambert (ft) + NAVD88 height (ft)
    write_cog(tmp_path / "dtm.tif", np.ones((20, 20)), transform=transform, crs=compound)
    with rasterio.open(tmp_path / "dtm.tif") as ds:
        back = pyproj.CRS.from_wkt(ds.crs.to_wkt())
        assert back.is_compound and back.sub_crs_list[1].name == "NAVD88 height (ft)"
        assert ds.units == ("foot",)
    for code, unit in (("EPSG:2263", "US survey foot"), ("EPSG:25830", "metre")):
        crs = pyproj.CRS.from_user_input(code)
        for name, kind in (("dtm", "height"), ("density", None)):
            m = RasterMosaic(
                tmp_path / f"{name}.tif",
                rows=4,
                cols=4,
                transform=transform,
                crs=crs,
                nodata=-9999.0,
                fill=0.0,
                **({} if kind else {"unit": None}),
            )
            m.write_fill(0, 4, 0, 4)
            m.finish()
            with rasterio.open(tmp_path / f"{name}.tif") as ds:
                assert ds.units == ((unit,) if kind else (None,)), (code, name)


def test_contours_are_geopackage_1_2(tmp_path):
    """GeoPackage stores its version in SQLite's user_version: 1.2 is 10200 (GDAL 3.8's default 1.4: 10400)."""

    path = tmp_path / "contours.gpkg"
    write_lines_gpkg(path, [(100.0, np.array([[0.0, 0.0], [1.0, 1.0]]))], crs=pyproj.CRS.from_epsg(25830))
    with sqlite3.connect(path) as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == 10200
        assert db.execute("PRAGMA application_id").fetchone()[0] == 0x47504B47  # 'GPKG'


def test_csf_library_prints_nothing_on_stdout(capfd):
    """The C++ CSF code prints "[0] Configuring terrain..." through std::cout; stdout is the user's."""

    rng = np.random.default_rng(1)
    points = np.column_stack((rng.uniform(0, 30, (2000, 2)), rng.normal(0, 0.05, 2000)))
    assert csf(points).mean() > 0.9  # a flat plane is ground
    ctypes.CDLL(None).fflush(None)  # what C stdio still buffers would reach the descriptor now
    assert capfd.readouterr().out == ""


# --------------------------------------------------------------------------
# pipeline info


def test_info_summarises_a_real_file(capsys):
    assert main(["info", str(TOPOGRAPHY), "--json"]) == 0
    [s] = json.loads(capsys.readouterr().out)
    las = laspy.read(TOPOGRAPHY)  # the peer's reading
    assert (s["version"], s["point_format"], s["points"], s["points_read"]) == ("1.2", 1, len(las.points), 73_403)
    assert s["gps_time_type"] == "adjusted standard GPS time"
    assert s["gps_time"]["min"] == pytest.approx(float(las.gps_time.min()))
    assert s["gps_time"]["max"] == pytest.approx(float(las.gps_time.max()))
    assert s["crs"]["epsg"] == 2949
    assert "crs_fits" in s  # the run's CRS check (None where it is not installed)
    counts = np.bincount(las.classification)
    assert {int(k): v["points"] for k, v in s["classes"].items()} == {
        int(c): int(counts[c]) for c in np.flatnonzero(counts)
    }
    assert s["classes"]["9"]["name"] == "water"
    rn = np.bincount(las.return_number)
    assert s["returns"]["return_number"] == {str(r): int(rn[r]) for r in np.flatnonzero(rn)}
    np.testing.assert_allclose(s["bounds"]["min"], [las.x.min(), las.y.min(), las.z.min()])
    assert s["scale"] == [0.00025] * 3
    assert [(v["user_id"], v["record_id"]) for v in s["vlrs"]] == [
        ("LASF_Projection", 34735),
        ("laszip encoded", 22204),
    ]


def test_info_text_of_several_files(capsys):
    files = [FULLWAVE, REAL / "pdal" / "warsaw_small.las", REAL / "pdal" / "gps-time-nan.las", AUTZEN]
    assert main(["info", *map(str, files)]) == 0
    text = capsys.readouterr().out
    assert "LAS 1.4, point format 10, 10,750 points" in text
    assert "GPS time: GPS week seconds" in text
    assert "CRS: unreadable (Invalid WKT string: '')" in text  # warsaw_small: empty WKT, still summarised
    assert "1 not finite" in text  # gps-time-nan.las
    assert "x, y in foot (0.3048 m)" in text  # autzen_trim: Oregon State Plane in international feet
    assert text.count("  LAS 1.") == 4


def test_info_unreadable_file_is_one_sentence_exit_3(tmp_path, capsys):
    bad = tmp_path / "bad.las"
    bad.write_bytes(b"not a las file" * 20)
    assert main(["info", str(bad), str(TOPOGRAPHY)]) == 3
    out, err = capsys.readouterr()
    assert err.strip().count("\n") == 0 and f"{bad}: not a readable LAS/LAZ file" in err
    assert "Traceback" not in err
    assert "73,403 points" in out  # the readable file is still summarised
    assert main(["info", str(tmp_path / "missing.las")]) == 2


def test_evaluate_names_its_own_way_out_for_a_file_without_crs(capsys):
    """sample_c.las has no CRS: the run's sentence, and the option of this command (not a config key) to fix it."""
    assert main(["evaluate", "ground", str(REAL / "pdal" / "sample_c.las")]) == 3
    err = capsys.readouterr().err.strip()
    assert "sample_c.las" in err and "--crs" in err and "\n" not in err


# --------------------------------------------------------------------------
# The run and `evaluate ground` on real files (end to end)


def _config(tmp_path: Path, source: Path) -> Path:
    config = tmp_path / "run.yaml"
    config.write_text(
        f"input: {{format: las, paths: [{source}]}}\n"
        f"output: {tmp_path / 'out'}\ncache: {tmp_path / 'cache'}\n"
        "executor: {kind: local, workers: 2}\n",
        encoding="utf-8",
    )
    return config


@pytest.mark.slow
def test_run_keeps_the_metadata_and_evaluate_is_the_run_topography(tmp_path, capfd):
    """Topography.laz: points.laz keeps adjusted GPS time; water (9) stays water in run and evaluate."""
    config = _config(tmp_path, TOPOGRAPHY)
    assert main(["run", str(config), "-q"]) == 0
    assert capfd.readouterr().out == ""  # no library output on stdout
    out = tmp_path / "out"
    src, run = laspy.read(TOPOGRAPHY), laspy.read(out / "points.laz")
    assert int(run.header.global_encoding.gps_time_type) == 1
    np.testing.assert_array_equal(np.asarray(run.gps_time), np.asarray(src.gps_time))
    assert run.header.generating_software == f"dtm-pipeline {__version__}"
    with rasterio.open(out / "hillshade.tif") as ds:
        assert ds.dtypes[0] == "uint8" and ds.nodata == 0  # was float32 0-255, nodata -9999
    with rasterio.open(out / "dtm.tif") as ds:
        assert ds.units == ("metre",)  # MTM zone 7: metres (was no unit)
    with sqlite3.connect(out / "contours.gpkg") as db:
        assert db.execute("PRAGMA user_version").fetchone()[0] == 10200  # was 10400 (1.4)
    evaluated = tmp_path / "evaluated.laz"
    assert main(["evaluate", "ground", str(TOPOGRAPHY), "--write", str(evaluated)]) == 0
    ev = laspy.read(evaluated)
    water = np.asarray(src.classification) == 9
    assert (np.asarray(run.classification)[water] == 9).sum() == 3897  # every water point stays water
    np.testing.assert_array_equal(np.asarray(ev.classification), np.asarray(run.classification))  # was 3,895 ground


@pytest.mark.slow
def test_evaluate_is_the_run_on_a_feet_survey(tmp_path, capsys):
    """autzen_trim.las (Oregon State Plane, feet): evaluate found 84,428 ground points where run found 88,182."""
    config = _config(tmp_path, AUTZEN)
    assert main(["run", str(config), "-q", "--until", "export_las"]) == 0
    evaluated = tmp_path / "evaluated.las"
    assert main(["evaluate", "ground", str(AUTZEN), "--json", "--write", str(evaluated)]) == 0
    [row] = json.loads(capsys.readouterr().out)
    run = np.asarray(laspy.read(tmp_path / "out" / "points.laz").classification)
    ev = laspy.read(evaluated)
    np.testing.assert_array_equal(np.asarray(ev.classification), run)
    assert row["ground_as_ground"] + row["object_as_ground"] == int((run == 2).sum())
    assert ev.header.parse_crs().axis_info[0].unit_name == "foot"  # written as the run writes it
