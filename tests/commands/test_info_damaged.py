"""``pipeline info`` runs the run's checks on damaged files: it warns or exits 3 the same way (issue 38)."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest

from pipeline.cli import main

SAMPLE = Path(__file__).resolve().parents[2] / "data_samples" / "las" / "sample.laz"


@pytest.fixture(scope="module")
def small(tmp_path_factory) -> dict[str, Path]:
    las = laspy.read(SAMPLE)
    cut = laspy.LasData(las.header)
    cut.points = las.points[:5000].copy()
    folder = tmp_path_factory.mktemp("info")
    cut.write(folder / "small.las")
    cut.write(folder / "small.laz")
    return {"las": folder / "small.las", "laz": folder / "small.laz"}


def _damaged(src: Path, dst: Path, at: int, data: bytes) -> Path:
    blob = bytearray(src.read_bytes())
    blob[at : at + len(data)] = data
    dst.write_bytes(bytes(blob))
    return dst


def test_info_refuses_garbage_decoded_from_a_laz_chunk(small, tmp_path, capsys):
    """Z bytes overwritten early in the chunk: the decoder runs on into heights far outside the header's."""
    header = laspy.open(small["laz"]).header
    start = header.offset_to_point_data + 8
    refused = 0
    for k in range(6):
        path = _damaged(small["laz"], tmp_path / f"z{k}.laz", start + 4000 + 997 * k, bytes(range(200, 232)))
        code = main(["info", str(path), "--json"])
        out, err = capsys.readouterr()
        assert "Traceback" not in err and code in (0, 3)
        if code == 0:  # what it reads is the survey
            [summary] = json.loads(out)
            assert summary["bounds"]["max"][2] <= header.maxs[2] and summary["bounds"]["min"][2] >= header.mins[2]
        else:
            assert f"z{k}.laz, byte" in err and "LAZ chunk 0" in err and err.count("\n") == 1
            refused += 1
    assert refused


def test_info_refuses_a_chunk_table_of_ff_bytes(small, tmp_path, capsys):
    blob = small["laz"].read_bytes()
    header = laspy.open(small["laz"]).header
    table = int.from_bytes(blob[header.offset_to_point_data : header.offset_to_point_data + 8], "little")
    path = _damaged(small["laz"], tmp_path / "ff.laz", table + 8, b"\xff" * (len(blob) - table - 8))
    assert main(["info", str(path)]) == 3
    err = capsys.readouterr().err
    assert "ff.laz, byte" in err and "LAZ chunk table" in err and "Traceback" not in err


def test_info_warns_of_a_damaged_las_record_as_the_run_does(small, tmp_path, capsys):
    header = laspy.open(small["las"]).header
    at = header.offset_to_point_data + 123 * header.point_format.size + 8  # Z of record 123
    path = _damaged(small["las"], tmp_path / "record.las", at, np.int32(2**31 - 1).tobytes())
    assert main(["info", str(path)]) == 0
    out, err = capsys.readouterr()
    assert "record.las: 1 points lie outside the header's bounds" in err
    assert "warning: 1 points lie outside" in out


def test_info_on_a_folder_says_it_is_one(tmp_path, capsys):
    assert main(["info", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"{tmp_path}: a folder; give its LAS/LAZ files (pipeline info {tmp_path}/*.laz)." in err
    assert "file not found" not in err
