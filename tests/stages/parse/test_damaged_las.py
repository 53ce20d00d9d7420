"""Damaged LAS/LAZ inputs (issue 38): never a wrong product at exit 0, never a wrong diagnosis.

Each damaged file is built here from the shipped sample, cut to a few
thousand points: garbage decoded from a LAZ chunk, damaged LAS records, a
header offset beyond the Earth, a negative scale, a chunk table of 0xFF
bytes, a file the user may not read, a disk that fills up while the points
are written, the same file listed twice.
"""

from __future__ import annotations

import builtins
import errno
import logging
import os
import subprocess
import sys
from pathlib import Path

import laspy
import numpy as np
import pytest

from pipeline.errors import InputDataError
from stages.parse.read_las import convert_las_files, read_las_files
from stages.parse.stage import distinct_files
from tests.shared_data import REAL as SHARED_REAL

SAMPLE = Path(__file__).resolve().parents[3] / "data_samples" / "las" / "sample.laz"
POINTS = 20_000


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> dict[str, Path]:
    """The sample's first points as LAS and as LAZ (two LAZ chunks of 10,000 points)."""
    las = laspy.read(SAMPLE)
    cut = laspy.LasData(las.header)
    cut.points = las.points[:POINTS].copy()
    folder = tmp_path_factory.mktemp("small")
    cut.write(folder / "small.las")
    with laspy.open(folder / "small.laz", mode="w", header=cut.header, do_compress=True) as writer:
        writer.write_points(cut.points[: POINTS // 2])
        writer.write_points(cut.points[POINTS // 2 :])
    return {"las": folder / "small.las", "laz": folder / "small.laz"}


def _convert(path: Path, tmp_path: Path):
    """The parse stage's conversion of one file; the points written and the report."""
    _, report, _ = convert_las_files(
        [path], tmp_path / "points.las", crs_setting="auto-utm", assign_crs=None, chunk_size=5000
    )
    return laspy.read(tmp_path / "points.las"), report


def _damaged(src: Path, dst: Path, edits: dict[int, bytes]) -> Path:
    blob = bytearray(src.read_bytes())
    for at, data in edits.items():
        blob[at : at + len(data)] = data
    dst.write_bytes(bytes(blob))
    return dst


def test_garbage_decoded_from_a_laz_chunk_is_refused_at_the_chunk(small, tmp_path):
    """Random bytes inside LAZ point records: refused at the LAZ chunk's byte, or read within the survey."""
    intact = laspy.read(small["laz"])
    lo, hi = (
        np.array([intact.x.min(), intact.y.min(), intact.z.min()]),
        np.array([intact.x.max(), intact.y.max(), intact.z.max()]),
    )
    header = laspy.open(small["laz"]).header
    start = header.offset_to_point_data + 8
    end = int.from_bytes(small["laz"].read_bytes()[start - 8 : start], "little")
    refused_at_chunk = 0
    for seed in range(12):
        rng = np.random.default_rng(seed)
        at = int(rng.integers(start, end - 16))
        path = _damaged(small["laz"], tmp_path / f"d{seed}.laz", {at: rng.integers(0, 256, 16, np.uint8).tobytes()})
        try:
            las, _ = _convert(path, tmp_path)
        except InputDataError as exc:
            assert f"d{seed}.laz, byte" in str(exc)
            refused_at_chunk += "LAZ chunk" in str(exc)
            continue
        xyz = np.column_stack((las.x, las.y, las.z))
        assert (xyz >= lo - 1).all() and (xyz <= hi + 1).all(), f"seed {seed}: points outside the survey"
    assert refused_at_chunk


def test_damaged_las_records_are_left_out_counted_and_the_extent_stays_the_survey(small, tmp_path):
    """Garbage x in one record and garbage z in another: both counted, neither in points.las."""
    header = laspy.open(small["las"]).header
    record, size = header.offset_to_point_data, header.point_format.size
    path = _damaged(
        small["las"],
        tmp_path / "records.las",
        {
            record + 100 * size: np.int32(2**31 - 1).tobytes(),  # X of record 100
            record + 7000 * size + 8: np.int32(-(2**31)).tobytes(),  # Z of record 7000
        },
    )
    las, report = _convert(path, tmp_path)
    assert report.outside_header_bounds == {str(path): 2} and len(las) == POINTS - 2
    assert np.ptp(las.x) < 1000 and np.ptp(las.z) < 100
    assert laspy.open(tmp_path / "points.las").header.maxs[0] < header.maxs[0] + 1


def test_a_z_offset_beyond_the_earth_is_refused_naming_the_field(small, tmp_path):
    path = _damaged(small["laz"], tmp_path / "zoffset.laz", {171: np.float64(1e300).tobytes()})
    with pytest.raises(InputDataError, match=r"zoffset.laz, byte 171: the z offset 1e\+300 lies beyond"):
        _convert(path, tmp_path)


def test_a_negative_scale_reads_as_the_positive_one(small, tmp_path):
    """LAS 1.4 does not forbid a negative scale factor: the same points, whatever the sign."""
    original = laspy.read(small["las"])
    las = laspy.LasData(original.header)
    las.points = original.points.copy()
    offset = float(original.header.offsets[0]) + 200.0
    las.header.offsets = np.array([offset, *original.header.offsets[1:]])
    las.header.scales = np.array([-0.001, *original.header.scales[1:]])
    las.points.array["X"] = np.round((np.asarray(original.x) - offset) / -0.001).astype(np.int32)
    las.update_header()
    las.write(tmp_path / "negative.las")
    assert laspy.open(tmp_path / "negative.las").header.scales[0] == -0.001
    read, report = _convert(tmp_path / "negative.las", tmp_path)
    assert not report.outside_header_bounds
    np.testing.assert_allclose(np.sort(read.x), np.sort(original.x), atol=1e-6)


def test_a_chunk_table_of_ff_bytes_is_refused_at_the_chunk(small, tmp_path):
    """lazrs panics (a BaseException) on it: one sentence naming the byte, exit 3."""
    blob = small["laz"].read_bytes()
    header = laspy.open(small["laz"]).header
    table = int.from_bytes(blob[header.offset_to_point_data : header.offset_to_point_data + 8], "little")
    path = _damaged(small["laz"], tmp_path / "ff.laz", {table + 8: b"\xff" * (len(blob) - table - 8)})
    with pytest.raises(InputDataError, match=r"ff.laz, byte \d+: the LAZ chunk table gives its chunks more than"):
        _convert(path, tmp_path)


def test_a_file_that_cannot_be_read_is_one_sentence(small, tmp_path, monkeypatch):
    real_open = builtins.open

    def denied(file, *args, **kw):
        if str(file) == str(small["las"]):
            raise PermissionError(errno.EACCES, "Permission denied", str(file))
        return real_open(file, *args, **kw)

    monkeypatch.setattr(builtins, "open", denied)
    with pytest.raises(InputDataError, match=r"small.las: permission denied; give the user"):
        read_las_files([small["las"]], crs_setting="auto-utm", assign_crs=None, chunk_size=5000)


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT, errno.EROFS])
@pytest.mark.parametrize("kind", ["las", "laz"])
def test_a_full_disk_while_writing_is_not_blamed_on_the_input(small, tmp_path, monkeypatch, code, kind):
    """The machine's error propagates untouched (the engine reports it, exit 4)."""

    def full(self, points):
        raise OSError(code, os.strerror(code))

    monkeypatch.setattr(laspy.LasWriter, "write_points", full)
    with pytest.raises(OSError) as caught:
        _convert(small[kind], tmp_path)
    assert caught.value.errno == code and not isinstance(caught.value, InputDataError)


def test_the_same_file_twice_is_read_once_with_a_warning(small, tmp_path, caplog, monkeypatch):
    """Two spellings (relative, absolute), a symbolic link and a repeat: one file."""
    link = tmp_path / "link.las"
    link.symlink_to(small["las"])
    monkeypatch.chdir(small["las"].parent)
    paths = [small["las"], Path("small.las"), link, small["laz"], small["las"]]
    log = logging.LoggerAdapter(logging.getLogger("test.parse"), {})
    with caplog.at_level(logging.WARNING):
        assert distinct_files(paths, log) == [small["las"], small["laz"]]
    assert len(caplog.records) == 3 and all("read once" in r.getMessage() for r in caplog.records)
    assert str(link) in caplog.text


def test_a_laz_chunk_size_beyond_the_file_is_refused_before_the_decoder_aborts(small, tmp_path):
    """A damaged LASzip VLR chunk size made lazrs allocate 48 GB and abort the process (run apart here)."""
    blob = small["laz"].read_bytes()
    data = blob.index(b"laszip encoded") - 2 + 54  # the LASzip VLR's data
    path = _damaged(small["laz"], tmp_path / "chunks.laz", {data + 12: (1_700_000_000).to_bytes(4, "little")})
    code = (
        "from pathlib import Path\n"
        "from stages.parse.read_las import read_las_files\n"
        "from pipeline.errors import InputDataError\n"
        "try:\n"
        f"    read_las_files([Path({str(path)!r})], crs_setting='auto-utm', assign_crs=None, chunk_size=5000)\n"
        "except InputDataError as exc:\n"
        "    print(exc)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-500:]
    assert f"chunks.laz, byte {data + 12}: the LASzip VLR announces chunks of 1,700,000,000 points" in proc.stdout


def test_a_scale_of_no_survey_is_refused_naming_its_byte(small, tmp_path):
    path = _damaged(small["las"], tmp_path / "tiny.las", {147: np.float64(-2.5e-251).tobytes()})  # z scale
    with pytest.raises(InputDataError, match=r"tiny.las, byte 147: the z scale factor -2.5e-251 makes a step"):
        _convert(path, tmp_path)


def test_header_bounds_of_no_survey_do_not_coarsen_the_points(tmp_path):
    """autzen's header max x damaged to 3.6e48: the points are written as read, not rounded to kilometres."""
    src = SHARED_REAL / "pdal" / "autzen_trim.las"
    las = laspy.read(src)
    cut = laspy.LasData(las.header)
    cut.points = las.points[:3000].copy()
    cut.update_header()
    cut.write(tmp_path / "cut.las")
    path = _damaged(tmp_path / "cut.las", tmp_path / "bounds.las", {179: np.float64(3.6e48).tobytes()})
    out, _ = _convert(path, tmp_path)
    np.testing.assert_allclose(np.sort(out.x), np.sort(laspy.read(tmp_path / "cut.las").x), atol=0.01)


def test_a_vlr_with_a_damaged_description_is_dropped_with_a_note(small, tmp_path):
    """laspy cannot write a description that is not ASCII: the record is dropped and named, the points read."""
    blob = small["las"].read_bytes()
    at = blob.index(b"LASF_Projection") - 2 + 22  # the description of the first VLR
    path = _damaged(small["las"], tmp_path / "vlr.las", {at: b"\xb8\xd5"})
    las, report = _convert(path, tmp_path)
    assert len(las) == POINTS and any("not ASCII" in note for note in report.dropped)
