"""The .lmsq scanner stream (SPEC 3.B/3.C): exact decoding, PPS timing, counted faults."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.errors import InputDataError
from stages.parse.read_lmsq import LmsqCounters, read_header, read_lmsq, write_lmsq

WEEK = 2100


def _records():
    recs = [("m", 10.0, 9, 0.0, 5, 0, 0, (0, 0, 0))]  # before the first PPS: no time
    recs.append(("pps", 345600.0, WEEK))
    recs.append(("m", 612.345, 200, -22.4999, 63, 0, 125, (1, 2, 3)))
    recs.append(("m", 598.001, 180, 0.0001, 40, 2, 250_000, (65535, 0, 7)))
    recs.append(("m", 605.0, 10, 10.0, 0, 1, 300_000, (0, 0, 0)))  # quality 0: invalid
    recs.append(("m", 607.0, 10, 11.0, 12, 0, 1_000_001, (0, 0, 0)))  # 1 s after its PPS: missed PPS
    recs.append(("pps", 345601.0, WEEK))
    recs += [("m", 600.0 + i, i, -30.0 + i, 20, 1, 1000 * i, (i, i, i)) for i in range(40)]
    return recs


@pytest.mark.parametrize("chunk", [1 << 20, 50, 19])
def test_decoding_timing_and_counters(tmp_path, chunk):
    path = tmp_path / "s.lmsq"
    write_lmsq(path, 280, _records())
    path.write_bytes(path.read_bytes() + b"\x01\x02\x03")  # a cut-off last record
    c = LmsqCounters()
    blocks = list(read_lmsq(path, c, chunk_bytes=chunk))
    cols = {k: np.concatenate([b[k] for b in blocks]) for k in blocks[0]}
    assert (c.measurements, c.pps, c.before_first_pps, c.invalid_quality, c.missed_pps) == (45, 2, 1, 1, 1)
    assert c.truncated_bytes == 3
    assert len(cols["time"]) == 42
    np.testing.assert_allclose(cols["range_m"][:2], [612.345, 598.001], atol=1e-9)
    np.testing.assert_allclose(cols["angle_deg"][:2], [-22.4999, 0.0001], atol=1e-9)
    assert cols["echo"][:2].tolist() == [0, 2] and cols["quality"][:2].tolist() == [63, 40]
    assert cols["rgb"][1].tolist() == [65535, 0, 7]
    t0 = WEEK * 604800.0 + 345600.0
    np.testing.assert_allclose(cols["time"][:2], [t0 + 125e-6, t0 + 0.25], atol=1e-7)
    np.testing.assert_allclose(cols["time"][2:], t0 + 1.0 + np.arange(40) * 1e-3, atol=1e-7)
    assert cols["byte"][0] == 16 + 18 + 11  # after the header, one measurement and a PPS


def test_corrupt_stream_and_bad_header_are_one_sentence(tmp_path):
    path = tmp_path / "s.lmsq"
    write_lmsq(path, 140, [("pps", 10.0, WEEK), ("m", 5.0, 1, 0.0, 5, 0, 10, (0, 0, 0))])
    blob = bytearray(path.read_bytes())
    blob[16 + 11] = 7  # the measurement's type byte
    path.write_bytes(bytes(blob))
    with pytest.raises(InputDataError, match=r"s.lmsq, byte 27: unknown record type 7"):
        list(read_lmsq(path, LmsqCounters()))
    path.write_bytes(b"LMSQ" + np.array([1, 999], "<u2").tobytes() + bytes(8))
    with pytest.raises(InputDataError, match="byte 6: scanner model 999"):
        read_header(path)
    path.write_bytes(b"RIFF0000")
    with pytest.raises(InputDataError, match="byte 0: not an .lmsq"):
        read_header(path)


def test_a_long_stream_reads_in_blocks(tmp_path):
    # one minute at 10 kHz: 600,000 measurements, 60 PPS
    n_per_s = 10_000
    rng = np.random.default_rng(0)
    path = tmp_path / "long.lmsq"
    head = b"LMSQ" + np.array([1, 140], "<u2").tobytes() + bytes(8)
    rec = np.zeros((n_per_s, 18), np.uint8)
    rec[:, 0] = 1
    mm = rng.integers(100_000, 700_000, n_per_s)
    rec[:, 1], rec[:, 2], rec[:, 3] = mm & 255, (mm >> 8) & 255, mm >> 16
    rec[:, 8] = 30
    off = np.arange(n_per_s) * 100
    rec[:, 9], rec[:, 10], rec[:, 11] = off & 255, (off >> 8) & 255, off >> 16
    parts = [head]
    for s in range(60):
        parts.append(bytes([2]) + np.float64(1000.0 + s).tobytes() + np.uint16(WEEK).tobytes() + rec.tobytes())
    path.write_bytes(b"".join(parts))
    c = LmsqCounters()
    total = sum(len(b["time"]) for b in read_lmsq(path, c, chunk_bytes=1 << 20))
    assert total == c.measurements == 600_000 and c.pps == 60


def _m(offset_us: int, quality: int = 20) -> tuple:
    return ("m", 100.0, 1, 0.0, quality, 0, offset_us, (0, 0, 0))


def _times(tmp_path, records, chunk=1 << 20):
    path = tmp_path / "s.lmsq"
    write_lmsq(path, 140, records)
    c = LmsqCounters()
    blocks = list(read_lmsq(path, c, chunk_bytes=chunk))
    t = np.concatenate([b["time"] for b in blocks]) if blocks else np.zeros(0)
    flag = np.concatenate([b["recovered"] for b in blocks]) if blocks else np.zeros(0, bool)
    return t - (WEEK * 604800.0 + 1000.0), flag, c


@pytest.mark.parametrize("chunk", [1 << 20, 37])
def test_one_missed_pps_is_dated_by_the_counter(tmp_path, chunk):
    """PPS 1001 missed: the counter keeps counting from PPS 1000, so 1.25 s and 1.999999 s are exact."""
    recs = [
        ("pps", 1000.0, WEEK),
        _m(0),
        _m(500_000),
        _m(1_250_000),
        _m(1_999_999, quality=0),
        _m(1_999_999),
        ("pps", 1002.0, WEEK),
        _m(10),
    ]
    t, flag, c = _times(tmp_path, recs, chunk)
    np.testing.assert_allclose(t, [0.0, 0.5, 1.25, 1.999999, 2.00001], atol=5e-7)  # float64 at 1.3e9 s: 0.24 us
    assert flag.tolist() == [False, False, True, True, False]
    assert (c.missed_pps, c.pps_recovered, c.pps_ambiguous, c.invalid_quality) == (3, 3, 0, 1)


def test_what_the_counter_cannot_date_is_dropped(tmp_path):
    """Ambiguous only: a counter that falls back (wrapped), one at 0xFFFFFF (saturated), times the next PPS
    contradicts, and everything after a PPS that is not a whole number of seconds later."""
    recs = [
        ("pps", 1000.0, WEEK),
        _m(900_000),
        _m(16_000_000),
        _m(3_000),
        _m(4_000),  # wrapped: 2 dropped
        ("pps", 1017.0, WEEK),
        _m(1_100_000),
        _m(0xFFFFFF),  # 1018.1 is before PPS 1019; saturated: dropped
        ("pps", 1019.0, WEEK),
        _m(1_100_000),  # 1020.1, but the next PPS is 1020: contradicted, dropped
        ("pps", 1020.0, WEEK),
        _m(1_200_000),  # the next PPS is 1.5 s later: which edge was missed? dropped
        ("pps", 1021.5, WEEK),
        _m(0),
        _m(2_000_000),  # at the end nothing contradicts 1023.5
    ]
    t, flag, c = _times(tmp_path, recs)
    np.testing.assert_allclose(t, [0.9, 16.0, 18.1, 21.5, 23.5], atol=5e-7)
    assert flag.tolist() == [False, True, True, False, True]
    assert c.missed_pps == 8 and c.pps_recovered == 3 and c.pps_ambiguous == 5
