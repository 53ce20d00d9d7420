"""The pipeline's LAS writer (``lidar.clouds.open_las_writer``) writes laspy's own bytes.

Its header grows by :func:`lidar.clouds.grow_header` instead of laspy's
``LasHeader.grow`` (the returns counted with ``bincount``, not a sort per
chunk); the files written in chunks must be byte for byte those of laspy's
writer, on real files (LAS 1.2 with 5 return slots, LAS 1.4 with 15) and on
return numbers laspy skips (0, and numbers above the header's slots).
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from lidar.clouds import open_las_writer
from tests.shared_data import REAL

ROOT = Path(__file__).resolve().parents[2]


def _write(path: Path, header, chunks, ours: bool, **options) -> bytes:
    opened = (
        open_las_writer(path, header, **options) if ours else laspy.open(str(path), mode="w", header=header, **options)
    )
    with opened as writer:
        for chunk in chunks:
            writer.write_points(chunk)
    return path.read_bytes()


@pytest.mark.parametrize("name", ["pdal/autzen_trim.las", "laspy/simple1_4.las", "lidR/Topography.laz"])
def test_same_bytes_as_laspy_on_real_files(tmp_path, name):
    path = REAL / name
    assert path.exists(), f"{path} is missing: the real-data tests need ../shared/data/real beside the clone"
    with laspy.open(str(path)) as reader:
        header = reader.header
        chunks = list(reader.chunk_iterator(7_919))  # several chunks, the last one short
    ours = _write(tmp_path / "ours.las", header, chunks, True)
    theirs = _write(tmp_path / "laspy.las", header, chunks, False)
    assert ours == theirs
    back = laspy.read(tmp_path / "ours.las").header
    assert back.point_count == sum(len(c) for c in chunks)
    returns = np.concatenate([np.asarray(c.return_number) for c in chunks])
    slots = 15 if back.version.minor >= 4 else 5  # what the file holds
    expected = np.bincount(returns, minlength=slots + 1)[1 : slots + 1]
    assert back.number_of_points_by_return[:slots].tolist() == expected.tolist()


@pytest.mark.parametrize(("version", "fmt", "slots"), [("1.2", 1, 5), ("1.4", 6, 15)])
def test_return_numbers_laspy_does_not_count(tmp_path, version, fmt, slots):
    """Return 0 and returns past the header's slots are not counted; the others are, chunk after chunk."""
    rng = np.random.default_rng(3)
    header = laspy.LasHeader(point_format=fmt, version=version)
    header.scales = np.array([0.01, 0.01, 0.01])
    header.offsets = np.array([500_000.0, 4_000_000.0, 0.0])
    chunks = []
    top = 7 if version == "1.2" else 15  # the largest return number the format can hold
    for n in (1_000, 1, 2_500):
        las = laspy.LasData(header)
        las.x = 500_000.0 + rng.uniform(-50, 50, n)
        las.y = 4_000_000.0 + rng.uniform(-50, 50, n)
        las.z = rng.uniform(-10, 300, n)
        las.return_number = rng.integers(0, top + 1, n)
        las.gps_time = rng.uniform(1e8, 2e8, n)
        chunks.append(las.points)
    ours = _write(tmp_path / "ours.las", header, chunks, True)
    theirs = _write(tmp_path / "laspy.las", header, chunks, False)
    assert ours == theirs
    back = laspy.read(tmp_path / "ours.las").header
    every = np.concatenate([np.asarray(c.return_number) for c in chunks])
    expected = np.bincount(every, minlength=slots + 1)[1 : slots + 1]
    assert back.number_of_points_by_return[:slots].tolist() == expected.tolist()
    assert back.maxs[2] == pytest.approx(max(float(np.max(c.z)) for c in chunks), abs=0.005)


def test_compressed_writer_same_bytes(tmp_path):
    path = REAL / "pdal" / "autzen_trim.las"
    assert path.exists(), f"{path} is missing: the real-data tests need ../shared/data/real beside the clone"
    with laspy.open(str(path)) as reader:
        header = reader.header
        chunks = list(reader.chunk_iterator(50_000))
    options = {"do_compress": True, "laz_backend": laspy.LazBackend.Lazrs}
    assert _write(tmp_path / "a.laz", header, chunks, True, **options) == _write(
        tmp_path / "b.laz", header, chunks, False, **options
    )
