"""Property-based fuzzing of the input parsers: the outcome is always a clean
ConfigError / InputDataError (one sentence) or a valid result — never another
exception (a traceback for the user)."""

from __future__ import annotations

import os
import re
from pathlib import Path

import laspy
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lidar.checkpoints import read_checkpoints
from pipeline.config import load_config
from pipeline.errors import ConfigError, InputDataError
from pipeline.stage import config_model
from stages.parse.read_ins import TrajectoryCounters, read_ins_csv, read_sbet, read_smrmsg
from stages.parse.read_las import convert_las_files, read_las_files
from stages.parse.read_ldmrs import Counters, read_ldmrs_mtig
from stages.parse.read_lmsq import LmsqCounters, read_lmsq
from stages.parse.read_nmea import NmeaCounters, read_nmea
from stages.plugin import plugin
from tests.flights import lines, simulate_flight
from tests.stages.parse.test_read_ldmrs import LOG

ROOT = Path(__file__).resolve().parents[3]
SAMPLE_CONFIG = (ROOT / "configs" / "las.yaml").read_text()
# Examples per test: the suite's defaults, times FUZZ_SCALE for a longer
# campaign (FUZZ_SCALE=20 pytest tests/stages/parse/test_fuzz_inputs.py).
SCALE = float(os.environ.get("FUZZ_SCALE", "1"))
FUZZ = settings(
    max_examples=int(150 * SCALE), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


@FUZZ
@given(data=st.data())
def test_config_mutations_fail_cleanly(tmp_path, data):
    text = SAMPLE_CONFIG
    kind = data.draw(st.sampled_from(["truncate", "flip", "insert", "garbage"]))
    if kind == "truncate":
        text = text[: data.draw(st.integers(0, len(text)))]
    elif kind == "flip":
        i = data.draw(st.integers(0, len(text) - 1))
        text = text[:i] + data.draw(st.characters(codec="utf-8")) + text[i + 1 :]
    elif kind == "insert":
        i = data.draw(st.integers(0, len(text)))
        text = text[:i] + data.draw(st.text(max_size=40)) + text[i:]
    else:
        text = data.draw(st.text(max_size=300))
    path = tmp_path / "configs" / "fuzz.yaml"
    path.parent.mkdir(exist_ok=True)
    path.write_text(text, encoding="utf-8", errors="surrogatepass")
    try:
        load_config(path, config_model(plugin))
    except ConfigError as exc:
        # One sentence, or (several problems) a heading and one sentence per line.
        lines = str(exc).split("\n")
        assert lines[0] and (len(lines) == 1 or lines[0].endswith("problems in the configuration:")), str(exc)
        assert all(line.startswith("  ") and line.endswith(".") for line in lines[1:]), str(exc)


@FUZZ
@given(rows=st.lists(st.lists(st.text(alphabet="0123456789.-eE,naif x", max_size=12), max_size=6), max_size=8))
def test_checkpoint_csv_fails_cleanly(tmp_path, rows):
    path = tmp_path / "cp.csv"
    path.write_text("x,y,z\n" + "\n".join(",".join(r) for r in rows))
    try:
        pts, _ = read_checkpoints(path)
        assert np.isfinite(pts).all()
    except InputDataError as exc:
        assert "cp.csv" in str(exc)


@pytest.fixture(scope="module")
def small_laz(tmp_path_factory):
    las = laspy.read(ROOT / "data_samples" / "las" / "sample.laz")
    small = laspy.LasData(las.header)
    small.points = las.points[:2000].copy()
    path = tmp_path_factory.mktemp("laz") / "small.laz"
    small.write(str(path))
    return path.read_bytes()


@settings(max_examples=int(60 * SCALE), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_damaged_las_fails_cleanly(tmp_path, small_laz, data):
    blob = bytearray(small_laz)
    kind = data.draw(st.sampled_from(["truncate", "bytes", "header"]))
    if kind == "truncate":
        blob = blob[: data.draw(st.integers(0, len(blob)))]
    elif kind == "bytes":
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(blob) - 1))
            blob[i] = data.draw(st.integers(0, 255))
    else:  # extreme values in the header's counts, scales, offsets and bounds
        for _ in range(data.draw(st.integers(1, 3))):
            field = data.draw(st.sampled_from(["count32", "count64", "double", "offset"]))
            if field == "count32":
                blob[107:111] = data.draw(st.sampled_from([0, 1, 2**31, 2**32 - 1])).to_bytes(4, "little")
            elif field == "count64":
                blob[247:255] = data.draw(st.sampled_from([0, 10**12, 2**63, 2**64 - 1])).to_bytes(8, "little")
            elif field == "offset":
                blob[96:100] = data.draw(st.sampled_from([0, 227, 2**31, 2**32 - 1])).to_bytes(4, "little")
            else:  # x/y/z scale, offset, max, min: 12 doubles from byte 131
                i = 131 + 8 * data.draw(st.integers(0, 11))
                value = data.draw(st.sampled_from([np.nan, np.inf, -np.inf, 0.0, 1e308, -1e308, 5e-324, 1e19]))
                blob[i : i + 8] = np.float64(value).tobytes()
    path = tmp_path / "damaged.laz"
    path.write_bytes(bytes(blob))
    try:
        las, _ = read_las_files([path], crs_setting="auto-utm", assign_crs=None, chunk_size=500)
    except InputDataError as exc:
        assert "damaged.laz" in str(exc)
    else:
        assert np.all(np.isfinite(las.x)) and np.all(np.isfinite(las.z))
    # the parse stage's streaming conversion (a record-for-record copy for this sample's format)
    try:
        convert_las_files([path], tmp_path / "out.las", crs_setting="auto-utm", assign_crs=None, chunk_size=500)
    except InputDataError as exc:
        assert "damaged.laz" in str(exc) or "bounds" in str(exc)
        return
    out = laspy.read(tmp_path / "out.las")
    assert np.all(np.isfinite(out.x)) and np.all(np.isfinite(out.z))


@FUZZ
@given(data=st.data())
def test_ldmrs_log_mutations_are_counted_never_raised(tmp_path, data):
    lines = LOG.splitlines()
    for _ in range(data.draw(st.integers(1, 6))):
        i = data.draw(st.integers(0, len(lines) - 1))
        action = data.draw(st.sampled_from(["drop", "dup", "garble", "cut"]))
        if action == "drop":
            del lines[i]
        elif action == "dup":
            lines.insert(i, lines[i])
        elif action == "garble":
            lines[i] = data.draw(st.text(max_size=30))
        else:
            lines[i] = lines[i][: data.draw(st.integers(0, len(lines[i])))]
        if not lines:
            break
    path = tmp_path / "acq.log"
    path.write_text("\n".join(lines), encoding="utf-8", errors="surrogatepass")
    counters = Counters()
    scans = list(read_ldmrs_mtig(path, counters))
    assert counters.scans_accepted == len(scans) <= counters.scans_total
    skipped = counters.invalid_scans + counters.bad_gps + counters.malformed_scans
    assert counters.scans_accepted + skipped <= counters.scans_total + 1  # + a garbled SCAN line
    for s in scans:
        assert np.isfinite(s.points).all()


# Raw formats 3.B and 3.C: one small simulated flight, damaged at random.


@pytest.fixture(scope="module")
def raw_flight(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz_raw")
    simulate_flight(
        root,
        seed=9,
        formats=["lmsq_nmea", "lmsq_sbet"],
        scanner={"preset": "q140", "pulse_rate_hz": 1000},
        navigation={"preset": "pos-av-410", "ins_rate_hz": 50},
        flight=lines(100, 40, 1, 80),
    )
    return root / "lmsq"


def _damage(data, blob: bytes) -> bytes:
    out = bytearray(blob)
    for _ in range(data.draw(st.integers(1, 5))):
        action = data.draw(st.sampled_from(["truncate", "flip", "insert", "delete"]))
        if not out:
            break
        i = data.draw(st.integers(0, len(out) - 1))
        if action == "truncate":
            del out[i:]
        elif action == "flip":
            out[i] ^= data.draw(st.integers(1, 255))
        elif action == "insert":
            out[i:i] = data.draw(st.binary(min_size=1, max_size=40))
        else:
            del out[i : i + data.draw(st.integers(1, 40))]
    return bytes(out)


RAW_FUZZ = settings(
    max_examples=int(60 * SCALE), deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)


# One check per reader, shared by the damage and the extreme-value tests: the
# outcome is a count or an InputDataError naming the file and line/byte, and
# every value that comes out is finite and physically possible.


def _check_lmsq(path: Path) -> None:
    counters = LmsqCounters()
    n = 0
    try:
        for b in read_lmsq(path, counters, chunk_bytes=4096):
            n += len(b["time"])
            assert all(np.all(np.isfinite(v)) for v in b.values() if np.asarray(v).dtype.kind == "f")
    except InputDataError as exc:
        assert f"{path.name}, byte" in str(exc)
        return
    assert n <= counters.measurements and all(v >= 0 for v in vars(counters).values())


def _check_text_navigation(path: Path) -> None:
    """nav.nmea or ins.csv."""
    try:
        if path.suffix == ".nmea":
            log = read_nmea(path, NmeaCounters())
            for column in log.position.values():
                if np.asarray(column).dtype.kind == "f":
                    assert np.all(np.isfinite(column))
            assert np.all(np.abs(log.position["lat"]) <= 90) and np.all(np.abs(log.position["lon"]) <= 180)
            for column in log.sigma.values():
                assert np.all(np.isfinite(column))
            assert all(np.all(log.sigma[k] >= 0) for k in log.sigma if k.startswith("sigma"))
        else:
            ins = read_ins_csv(path, 2400, TrajectoryCounters())
            assert np.all(np.diff(ins["time"]) > 0)
            assert all(np.all(np.isfinite(ins[k])) for k in ins)
            assert np.all(np.abs(ins["roll"]) <= 360) and np.all(np.abs(ins["pitch"]) <= 90)
            assert np.all(np.abs(ins["heading"]) <= 720)
    except (InputDataError, ConfigError) as exc:  # ConfigError: a log left without its date (set nmea_date)
        assert path.name in str(exc) and "line" in str(exc)


def _check_binary_trajectory(path: Path) -> None:
    """An SBET or an smrmsg file: damage is counted, never raised."""
    counters = TrajectoryCounters()
    sbet = path.suffix == ".sbet"
    out = (read_sbet if sbet else read_smrmsg)(path, 2400, counters)
    assert np.all(np.diff(out["time"]) > 0)
    assert all(np.all(np.isfinite(v)) for v in out.values())
    if sbet:
        assert np.all(np.abs(out["lat"]) <= 90) and np.all(np.abs(out["h"]) < 1e5)
        assert counters.epochs == len(out["time"])
    else:  # a sigma is never negative, nor beyond any survey
        assert all(np.all((out[k] >= 0) & (out[k] < 1e6)) for k in out if k.startswith("sigma"))


@RAW_FUZZ
@pytest.mark.parametrize(
    "name, check",
    [
        ("scan.lmsq", _check_lmsq),
        ("nav.nmea", _check_text_navigation),
        ("ins.csv", _check_text_navigation),
        ("trajectory.sbet", _check_binary_trajectory),
    ],
)
@given(data=st.data())
def test_raw_stream_damage_is_counted_or_located(tmp_path, raw_flight, data, name, check):
    path = tmp_path / name
    path.write_bytes(_damage(data, (raw_flight / name).read_bytes()))
    check(path)


# Extreme values in otherwise well-formed records: a numeric field of a line
# (NMEA with its checksum recomputed, so the sentence is parsed, not just
# rejected) or a binary field replaced by NaN, infinities, huge, tiny or
# negative numbers.  Outcome: a count or a located error, and every value that
# comes out is finite.

EXTREME = ["nan", "NaN", "inf", "-inf", "1e308", "-1e308", "1e-320", "-0", "0", "99999999999999999999", "-1", "1e19"]
_NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?(?![\w.])")


def _extreme_lines(data, lines: list[str], first: int = 0) -> list[str]:
    lines = list(lines)
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(first, len(lines) - 1))
        numbers = list(_NUMBER.finditer(lines[i]))
        if not numbers:
            continue
        m = numbers[data.draw(st.integers(0, len(numbers) - 1))]
        lines[i] = lines[i][: m.start()] + data.draw(st.sampled_from(EXTREME)) + lines[i][m.end() :]
    return lines


def _nmea_checksum(sentence: str) -> str:
    body = sentence.split("*")[0]
    crc = 0
    for ch in body[1:]:
        crc ^= ord(ch)
    return f"{body}*{crc:02X}"


@RAW_FUZZ
@given(data=st.data())
def test_extreme_values_in_text_records(tmp_path, raw_flight, data):
    which = data.draw(st.sampled_from(["nav.nmea", "ins.csv", "acq.log"]))
    path = tmp_path / which
    if which == "acq.log":
        path.write_text("\n".join(_extreme_lines(data, LOG.splitlines(), first=2)))
        counters = Counters()
        scans = list(read_ldmrs_mtig(path, counters))
        assert counters.scans_accepted == len(scans)
        for s in scans:
            assert np.isfinite(s.points).all()
        return
    lines = (raw_flight / which).read_text().splitlines()[:400]
    lines = _extreme_lines(data, lines, first=1 if which == "ins.csv" else 0)
    if which == "nav.nmea":
        lines = [_nmea_checksum(s) if s.startswith("$") and "*" in s else s for s in lines]
    path.write_text("\n".join(lines) + "\n")
    _check_text_navigation(path)


@RAW_FUZZ
@given(data=st.data())
def test_extreme_values_in_binary_records(tmp_path, raw_flight, data):
    which = data.draw(st.sampled_from(["trajectory.sbet", "trajectory.smrmsg", "scan.lmsq"]))
    blob = bytearray((raw_flight / which).read_bytes())
    width = 8 if which != "scan.lmsq" else data.draw(st.sampled_from([2, 4, 8]))
    for _ in range(data.draw(st.integers(1, 6))):
        i = data.draw(st.integers(0, len(blob) // width - 1)) * width
        if width == 8:
            value = data.draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e308, -1e308, 5e-324, -0.0, 1e19]))
            blob[i : i + 8] = np.float64(value).tobytes()
        else:
            blob[i : i + width] = data.draw(st.sampled_from([b"\xff", b"\x00", b"\x7f", b"\x80"])) * width
    path = tmp_path / which
    path.write_bytes(bytes(blob))
    if which == "scan.lmsq":
        _check_lmsq(path)
    else:
        _check_binary_trajectory(path)
