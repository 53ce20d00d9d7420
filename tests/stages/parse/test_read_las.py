"""Reading LAS/LAZ input (SPEC 3.D): CRS rules, reprojection, bad files."""

from __future__ import annotations

import tracemalloc
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from lidar.crs import output_crs
from pipeline.cli import main
from pipeline.errors import InputDataError
from stages.parse.read_las import convert_las_files, read_las_files

ROOT = Path(__file__).resolve().parents[3]


def _write(path, x, y, z, crs=None, point_format=3, version="1.2"):
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.scales = np.array([1e-7, 1e-7, 1e-3]) if crs == "EPSG:4326" else np.array([1e-3, 1e-3, 1e-3])
    header.offsets = np.array([float(np.min(x)), float(np.min(y)), 0.0])
    if crs:
        header.add_crs(pyproj.CRS.from_user_input(crs))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.classification = np.full(len(x), 2, dtype=np.uint8)
    las.write(str(path))
    return path


def test_geographic_input_goes_to_its_utm_zone(tmp_path):
    lon = np.array([-3.70, -3.69, -3.68])
    lat = np.array([40.41, 40.42, 40.43])
    path = _write(tmp_path / "geo.las", lon, lat, np.array([650.0, 651.0, 652.0]), crs="EPSG:4326")
    las, report = read_las_files([path], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    assert las.header.parse_crs().to_epsg() == 32630
    e, n = pyproj.Transformer.from_crs(4326, 32630, always_xy=True).transform(lon, lat)
    np.testing.assert_allclose(las.x, e, atol=2e-3)
    np.testing.assert_allclose(las.y, n, atol=2e-3)
    np.testing.assert_allclose(las.z, [650.0, 651.0, 652.0], atol=1e-3)
    assert report.points[str(path)] == 3 and report.gps_time_missing == []


def test_explicit_output_crs_reprojects(tmp_path):
    x, y = np.array([440_000.0, 440_100.0]), np.array([4_474_000.0, 4_474_100.0])
    path = _write(tmp_path / "a.las", x, y, np.zeros(2), crs="EPSG:25830")
    las, _ = read_las_files([path], crs_setting="EPSG:25831", assign_crs=None, chunk_size=1000)
    e, n = pyproj.Transformer.from_crs(25830, 25831, always_xy=True).transform(x, y)
    np.testing.assert_allclose(las.x, e, atol=2e-3)
    np.testing.assert_allclose(las.y, n, atol=2e-3)


def test_missing_crs_is_an_input_error_unless_assigned(tmp_path):
    path = _write(tmp_path / "nocrs.las", np.array([1.0, 2.0]), np.array([1.0, 2.0]), np.zeros(2))
    with pytest.raises(InputDataError, match="has no CRS; set input.crs"):
        read_las_files([path], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    las, report = read_las_files(
        [path], crs_setting="auto-utm", assign_crs=pyproj.CRS.from_epsg(25830), chunk_size=1000
    )
    assert las.header.parse_crs().to_epsg() == 25830
    assert report.crs_source[str(path)] == "input.crs"


def test_crs_in_feet_is_accepted_and_a_geographic_one_refused():
    assert output_crs("EPSG:2227", None, None).to_epsg() == 2227  # units: tests/end_to_end/test_feet_crs.py
    with pytest.raises(InputDataError, match="is not projected"):
        output_crs("EPSG:4326", None, None)


def test_not_a_las_file_exits_3_with_the_file_name(tmp_path, capsys):
    bad = tmp_path / "bad.laz"
    bad.write_bytes(b"this is not a LAS file at all" * 10)
    config = tmp_path / "c.yaml"
    config.write_text(f"input: {{format: las, paths: [{bad.name}]}}\noutput: out\n")
    assert main(["run", str(config), "-q"]) == 3
    err = capsys.readouterr().err
    assert "bad.laz: not a readable LAS/LAZ file" in err and "Traceback" not in err


def test_unknown_format_and_bad_crs_are_config_errors(tmp_path, capsys):
    path = _write(tmp_path / "a.las", np.array([1.0]), np.array([1.0]), np.zeros(1), crs="EPSG:25830")
    config = tmp_path / "c.yaml"
    config.write_text(f"input: {{format: lass, paths: [{path.name}]}}\noutput: out\n")
    assert main(["validate", str(config)]) == 2
    assert "c.yaml, line 1: input" in capsys.readouterr().err
    config.write_text(f"input: {{format: las, paths: [{path.name}]}}\noutput: out\ncrs: EPSG:999999\n")
    assert main(["validate", str(config)]) == 2
    assert "line 3: crs: 'EPSG:999999' is not a CRS pyproj knows" in capsys.readouterr().err


def test_point_format_1_input_keeps_gps_time_and_attributes(tmp_path):
    x = np.linspace(440_000, 440_010, 5)
    path = _write(tmp_path / "pf1.las", x, x * 0 + 4_474_000, np.arange(5.0), crs="EPSG:25830", point_format=1)
    src = laspy.read(path)
    src.gps_time = np.arange(5) + 100.5
    src.intensity = np.arange(5) * 10
    src.point_source_id = np.full(5, 7)
    src.write(str(path))
    las, _ = read_las_files([path], crs_setting="auto-utm", assign_crs=None, chunk_size=2)
    assert las.header.point_format.id == 6
    np.testing.assert_array_equal(las.gps_time, np.arange(5) + 100.5)
    np.testing.assert_array_equal(las.intensity, np.arange(5) * 10)
    np.testing.assert_array_equal(las.point_source_id, 7)
    np.testing.assert_array_equal(las.classification, 2)


def test_a_wide_survey_gets_a_coarser_scale_not_an_overflow(tmp_path):
    x = np.array([200_000.0, 700_000.0])  # 500 km apart: beyond int32 at 0.1 mm
    path = _write(tmp_path / "wide.las", x, np.array([4_400_000.0, 4_400_000.0]), np.zeros(2), crs="EPSG:25830")
    las, _ = read_las_files([path], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    assert las.header.scales[0] == pytest.approx(1e-3)
    np.testing.assert_allclose(las.x, x, atol=1e-3)


def test_damaged_scale_is_refused_with_the_file_name(tmp_path):
    path = _write(tmp_path / "ok.las", np.array([1.0, 2.0]), np.array([1.0, 2.0]), np.zeros(2), crs="EPSG:25830")
    blob = bytearray(path.read_bytes())
    blob[131:139] = np.array([1e12]).tobytes()  # x scale factor (LAS header offset 131)
    bad = tmp_path / "bad_scale.las"
    bad.write_bytes(bytes(blob))
    with pytest.raises(InputDataError, match=r"bad_scale.las, byte 131: the x scale factor 1e\+12 .*damaged"):
        read_las_files([bad], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)


def test_headers_announcing_impossible_sizes_are_refused_before_allocating(tmp_path):
    path = _write(
        tmp_path / "ok.las", np.array([1.0, 2.0]), np.array([1.0, 2.0]), np.zeros(2), crs="EPSG:25830", version="1.4"
    )
    blob = bytearray(path.read_bytes())
    huge = bytearray(blob)
    huge[107:111] = (4_000_000_000).to_bytes(4, "little")  # legacy point count
    (tmp_path / "huge.las").write_bytes(bytes(huge))
    with pytest.raises(InputDataError, match=r"huge.las, byte 107: the header announces 4,000,000,000 points"):
        read_las_files([tmp_path / "huge.las"], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    vlrs = bytearray(blob)
    vlrs[100:104] = (3_000_000_000).to_bytes(4, "little")  # number of VLRs
    (tmp_path / "vlrs.las").write_bytes(bytes(vlrs))
    with pytest.raises(InputDataError, match=r"vlrs.las, byte 100: the header announces 3,000,000,000 VLRs"):
        read_las_files([tmp_path / "vlrs.las"], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    assert blob[24:26] == b"\x01\x04"  # LAS 1.4: the 64-bit point count at byte 247
    trillion = bytearray(blob)
    trillion[247:255] = (10**12).to_bytes(8, "little")
    (tmp_path / "trillion.las").write_bytes(bytes(trillion))

    tracemalloc.start()
    with pytest.raises(InputDataError, match=r"trillion.las, byte 107: the header announces 1,000,000,000,000 points"):
        read_las_files([tmp_path / "trillion.las"], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    assert tracemalloc.get_traced_memory()[1] < 50e6  # nothing near 10^12 points was allocated
    tracemalloc.stop()


def test_laz_chunk_table_claiming_billions_of_chunks_is_refused_before_allocating(tmp_path):
    """Found by the fuzz campaign: one flipped byte in the chunk count made lazrs allocate 64 GB."""
    las = laspy.read(ROOT / "data_samples" / "las" / "sample.laz")
    small = laspy.LasData(las.header)
    small.points = las.points[:2000].copy()
    small.write(str(tmp_path / "ok.laz"))
    blob = bytearray((tmp_path / "ok.laz").read_bytes())
    start = int.from_bytes(blob[96:100], "little")
    table = int.from_bytes(blob[start : start + 8], "little")
    chunks = bytearray(blob)
    chunks[table + 4 : table + 8] = (2**32 - 1).to_bytes(4, "little")
    (tmp_path / "chunks.laz").write_bytes(bytes(chunks))
    with pytest.raises(
        InputDataError, match=rf"chunks.laz, byte {table + 4}: the LAZ chunk table announces 4,294,967,295"
    ):
        read_las_files([tmp_path / "chunks.laz"], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    offset = bytearray(blob)
    offset[start : start + 8] = (2**40).to_bytes(8, "little")
    (tmp_path / "offset.laz").write_bytes(bytes(offset))
    with pytest.raises(
        InputDataError, match=rf"offset.laz, byte {start}: the LAZ chunk table offset .* outside the file"
    ):
        read_las_files([tmp_path / "offset.laz"], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    las, _ = read_las_files([tmp_path / "ok.laz"], crs_setting="auto-utm", assign_crs=None, chunk_size=1000)
    assert len(las.points) == 2000  # the check leaves a sound file alone


def test_las14_format6_in_the_output_crs_is_copied_as_delivered(tmp_path):
    """One LAS 1.4 format-6 file already in the output CRS: every record byte kept, scale and offsets too."""
    rng = np.random.default_rng(1)
    x, y = 440_000 + rng.uniform(0, 300, 5000), 4_474_000 + rng.uniform(0, 300, 5000)
    src = _write(tmp_path / "in.las", x, y, rng.uniform(600, 700, 5000), "EPSG:25830", point_format=6, version="1.4")
    las = laspy.read(src)
    las.point_source_id = rng.integers(1, 4, 5000)
    las.scan_angle = rng.integers(-3000, 3000, 5000)
    las.gps_time = np.sort(rng.uniform(0, 100, 5000))
    las.edge_of_flight_line = rng.integers(0, 2, 5000)  # not among the attributes a conversion keeps
    las.number_of_returns = rng.integers(1, 4, 5000)
    las.return_number = np.minimum(rng.integers(1, 4, 5000), las.number_of_returns)  # valid: 0 would be repaired
    las.write(str(src))
    crs, report, strips = convert_las_files(
        [src], tmp_path / "out.las", crs_setting="auto-utm", assign_crs=None, chunk_size=777
    )
    out = laspy.read(tmp_path / "out.las")
    assert crs.to_epsg() == 25830 and strips == {1, 2, 3} and report.points[str(src)] == 5000
    assert np.array_equal(out.points.array, las.points.array)
    assert np.array_equal(out.header.scales, las.header.scales) and np.array_equal(
        out.header.offsets, las.header.offsets
    )
    # anything else (here another CRS) is converted: coordinates at 0.1 mm, the standard attributes kept
    _, _, strips = convert_las_files(
        [src], tmp_path / "utm31.las", crs_setting="EPSG:25831", assign_crs=None, chunk_size=777
    )
    other = laspy.read(tmp_path / "utm31.las")
    assert np.allclose(other.header.scales, 1e-4) and strips == {1, 2, 3}
    assert np.array_equal(other.gps_time, las.gps_time) and np.array_equal(other.scan_angle, las.scan_angle)
