"""Corrupted raw inputs, one family per format: a counted skip, or exit 3 with file and location.

Never a traceback, never a silent guess.  Inputs are a small simulated
flight, damaged by truncation, flipped bytes and inserted garbage.
"""

from __future__ import annotations

import gzip
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from pipeline.cli import main
from tests.flights import lines, simulate_flight, simulate_ldmrs_line


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    root = tmp_path_factory.mktemp("corrupt")
    simulate_ldmrs_line(root / "ld")
    scanner = {"preset": "q140", "pulse_rate_hz": 2000}
    flight = lines(100, 40, 1, 100, lead_in_m=10)
    simulate_flight(root / "rg", seed=5, formats=["lmsq_nmea", "lmsq_sbet"], scanner=scanner, flight=flight)
    return root


def _copy(flights: Path, tmp: Path, which: str) -> Path:
    shutil.copytree(flights / which, tmp / which)
    return tmp / which


def _parse(tmp: Path, block: str, capsys) -> tuple[int, dict, str]:
    config = tmp / "c.yaml"
    config.write_text(f"input:\n{block}\noutput: out\n")
    code = main(["run", str(config), "-q", "--until", "parse"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    metrics = {}
    if code == 0:
        stages = json.loads((tmp / "out" / "run.json").read_text())["stages"]
        metrics = next(s for s in stages if s["name"] == "parse")["metrics"]
    return code, metrics, err


LMSQ = "  paths: [{d}/lmsq/scan.lmsq]\n  boresight_deg: [0, 0, 0]\n  lever_arm_m: [0, 0, 0]\n"


def _nmea(d):
    return "  format: lmsq_nmea\n" + LMSQ.format(d=d) + f"  nmea: {d}/lmsq/nav.nmea\n  ins: {d}/lmsq/ins.csv"


def _sbet(d):
    return "  format: lmsq_sbet\n" + LMSQ.format(d=d) + f"  sbet: {d}/lmsq/trajectory.sbet"


def _ldmrs(d):
    return f"  format: ldmrs_mtig\n  paths: [{d}/ldmrs/acquisition.log.gz]\n  mounting: cb5000"


def test_ldmrs_truncated_gzip_is_counted(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "ld")
    log = d / "ldmrs" / "acquisition.log.gz"
    whole, _, _ = _parse(tmp_path, _ldmrs(flights / "ld"), capsys)
    log.write_bytes(log.read_bytes()[: log.stat().st_size // 2])
    code, m, _ = _parse(tmp_path, _ldmrs(d), capsys)
    assert code == 0 and m["malformed_scans"] >= 1 and 0 < m["scans_accepted"]
    assert any("damaged" in p or "ends inside" in p for p in m["problems"])


def test_ldmrs_garbage_lines_are_counted(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "ld")
    log = d / "ldmrs" / "acquisition.log.gz"
    lines = gzip.decompress(log.read_bytes()).decode().splitlines()
    lines.insert(40, "P 0 0 0x00 nan 1 2")  # inside a scan: that scan is malformed
    lines.insert(10, "\x00\x01garbage")
    log.write_bytes(gzip.compress(("\n".join(lines) + "\n").encode()))
    code, m, _ = _parse(tmp_path, _ldmrs(d), capsys)
    assert code == 0 and m["malformed_scans"] >= 1
    assert any("line 11" in p for p in m["problems"]) or any("line 41" in p for p in m["problems"])


def test_lmsq_truncated_stream_counts_the_cut_bytes(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "rg")
    scan = d / "lmsq" / "scan.lmsq"
    scan.write_bytes(scan.read_bytes()[:-7])
    code, m, _ = _parse(tmp_path, _sbet(d), capsys)
    assert code == 0 and m["scanner_truncated_bytes"] == 11  # the last 18-byte record lost 7 bytes


def test_lmsq_flipped_record_type_exits_3_with_byte_offset(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "rg")
    scan = d / "lmsq" / "scan.lmsq"
    data = bytearray(scan.read_bytes())
    offset = 16 + 11  # the first measurement, right after the first PPS
    assert data[offset] == 1
    data[offset] = 9
    scan.write_bytes(bytes(data))
    code, _, err = _parse(tmp_path, _sbet(d), capsys)
    assert code == 3 and f"byte {offset}" in err and "scan.lmsq" in err and err.count("\n") == 1


def test_lmsq_wrong_magic_exits_3(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "rg")
    scan = d / "lmsq" / "scan.lmsq"
    scan.write_bytes(b"XXXX" + scan.read_bytes()[4:])
    code, _, err = _parse(tmp_path, _sbet(d), capsys)
    assert code == 3 and "byte 0" in err


def test_nmea_and_ins_garbage_is_counted(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "rg")
    nmea = d / "lmsq" / "nav.nmea"
    lines = nmea.read_text().splitlines()
    lines[30] = lines[30][:-1] + ("0" if lines[30][-1] != "0" else "1")  # checksum broken
    lines.insert(50, "garbage,,,*ZZ")
    nmea.write_text("\r\n".join(lines) + "\r\n")
    ins = d / "lmsq" / "ins.csv"
    rows = ins.read_text().splitlines()
    rows.insert(20, "not,a,number,row")
    rows.insert(40, rows[38])  # a duplicate timestamp
    rows.insert(60, "nan,0,0,0")
    ins.write_text("\n".join(rows) + "\n")
    code, m, _ = _parse(tmp_path, _nmea(d), capsys)
    assert code == 0
    assert m["nmea_bad_checksum"] == 2
    assert m["navigation_malformed"] == 2 and m["navigation_not_increasing"] == 1
    assert any("ins.csv, line 21" in p for p in m["problems"])


def test_ins_csv_with_a_wrong_header_exits_3(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "rg")
    ins = d / "lmsq" / "ins.csv"
    ins.write_text("time,r,p,h\n" + "\n".join(ins.read_text().splitlines()[1:]) + "\n")
    code, _, err = _parse(tmp_path, _nmea(d), capsys)
    assert code == 3 and "ins.csv, line 1" in err


def test_sbet_damage_is_counted(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "rg")
    sbet = d / "lmsq" / "trajectory.sbet"
    rec = np.fromfile(sbet, "<f8").reshape(-1, 17)
    n = len(rec)
    rec[100, 1] = np.nan  # a non-finite latitude
    rec[200, 0] = rec[199, 0]  # a duplicate time
    sbet.write_bytes(rec.tobytes() + b"\x00" * 50)  # and a cut-off record
    code, m, _ = _parse(tmp_path, _sbet(d), capsys)
    assert code == 0
    assert m["navigation_malformed"] == 1 and m["navigation_not_increasing"] == 1
    assert m["navigation_truncated_bytes"] == 50 and m["trajectory_epochs"] == n - 2


def test_sbet_of_garbage_exits_3(flights, tmp_path, capsys):
    d = _copy(flights, tmp_path, "rg")
    (d / "lmsq" / "trajectory.sbet").write_bytes(b"\xff" * 136 * 3)
    code, _, err = _parse(tmp_path, _sbet(d), capsys)
    assert code == 3 and "trajectory.sbet, byte 0" in err
