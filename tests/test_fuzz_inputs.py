"""Property-based fuzzing of the input parsers: the outcome is always a clean
ConfigError / InputDataError (one sentence) or a valid result — never another
exception (a traceback for the user)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.config import load_config
from pipeline.errors import ConfigError, InputDataError
from pipeline.stage import config_model
from stages import plugin
from stages.accuracy import read_checkpoints
from stages.readers.las import read_las_files

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_CONFIG = (ROOT / "configs" / "las.yaml").read_text()
# Examples per test: the suite's defaults, times FUZZ_SCALE for a longer
# campaign (FUZZ_SCALE=20 pytest tests/test_fuzz_inputs.py).
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
        assert str(exc) and "\n" not in str(exc)


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
    import laspy

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
    if data.draw(st.booleans()):
        blob = blob[: data.draw(st.integers(0, len(blob)))]
    else:
        for _ in range(data.draw(st.integers(1, 8))):
            i = data.draw(st.integers(0, len(blob) - 1))
            blob[i] = data.draw(st.integers(0, 255))
    path = tmp_path / "damaged.laz"
    path.write_bytes(bytes(blob))
    try:
        las, _ = read_las_files([path], crs_setting="auto-utm", assign_crs=None, chunk_size=500)
    except InputDataError as exc:
        assert "damaged.laz" in str(exc)


@FUZZ
@given(data=st.data())
def test_ldmrs_log_mutations_are_counted_never_raised(tmp_path, data):
    from stages.readers.ldmrs import Counters, read_ldmrs_mtig
    from tests.stages.test_read_ldmrs import LOG

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
    from stages.sim.config import SimulateConfig
    from stages.sim.simulate import simulate

    root = tmp_path_factory.mktemp("fuzz_raw")
    simulate(SimulateConfig(output=root, seed=9, formats=["lmsq_nmea", "lmsq_sbet"], checkpoints=0,
                            scanner={"preset": "q140", "pulse_rate_hz": 1000},
                            navigation={"preset": "pos-av-410", "ins_rate_hz": 50},
                            flight={"altitude_m": 100, "speed_ms": 40, "lines": 1, "line_length_m": 80,
                                    "cross_line": False, "lead_in_m": 0}))  # fmt: skip
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


@RAW_FUZZ
@given(data=st.data())
def test_lmsq_stream_damage_is_counted_or_located(tmp_path, raw_flight, data):
    from stages.readers.lmsq import LmsqCounters, read_lmsq

    path = tmp_path / "scan.lmsq"
    path.write_bytes(_damage(data, (raw_flight / "scan.lmsq").read_bytes()))
    counters = LmsqCounters()
    try:
        n = sum(len(b["time"]) for b in read_lmsq(path, counters, chunk_bytes=4096))
    except InputDataError as exc:
        assert "scan.lmsq, byte" in str(exc)
        return
    assert n <= counters.measurements and all(v >= 0 for v in vars(counters).values())


@RAW_FUZZ
@given(data=st.data())
def test_nmea_and_ins_damage_is_counted_or_located(tmp_path, raw_flight, data):
    from stages.readers.ins import TrajectoryCounters, read_ins_csv
    from stages.readers.nmea import NmeaCounters, read_nmea

    which = data.draw(st.sampled_from(["nav.nmea", "ins.csv"]))
    path = tmp_path / which
    path.write_bytes(_damage(data, (raw_flight / which).read_bytes()))
    try:
        if which == "nav.nmea":
            log = read_nmea(path, NmeaCounters())
            assert np.all(np.isfinite(log.position["lat"]))
        else:
            ins = read_ins_csv(path, 2400, TrajectoryCounters())
            assert np.all(np.diff(ins["time"]) > 0)
    except InputDataError as exc:
        assert which in str(exc) and "line" in str(exc)


@RAW_FUZZ
@given(data=st.data())
def test_sbet_damage_is_counted(tmp_path, raw_flight, data):
    from stages.readers.ins import TrajectoryCounters, read_sbet

    path = tmp_path / "t.sbet"
    path.write_bytes(_damage(data, (raw_flight / "trajectory.sbet").read_bytes()))
    counters = TrajectoryCounters()
    sb = read_sbet(path, 2400, counters)
    assert np.all(np.diff(sb["time"]) > 0) and np.all(np.isfinite(sb["lat"])) and np.all(np.isfinite(sb["heading"]))
    assert counters.epochs == len(sb["time"])
