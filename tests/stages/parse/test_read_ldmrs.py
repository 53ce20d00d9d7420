"""Format 3.A (LD-MRS + MTi-G acquisition log): validity rules, counters, QC files."""

from __future__ import annotations

import json
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from lidar.columns import read_columns
from pipeline.cli import main
from stages.parse.read_ldmrs import Counters, read_ldmrs_mtig, utc_to_gps


def scan(number, *, utc=None, status="0x07", valid=1, points=None, npoints=None, extra=""):
    if utc is None:  # scans 0.1 s apart, scan 125 at 10:32:15.25 (times must increase: TimeOrder)
        t = datetime(2011, 6, 21, 10, 32, 15, 250000) + timedelta(seconds=0.1 * (number - 125))
        utc = t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
    points = [(0, 0, 0x00, 12.345, 0.512, -0.034), (2, 1, 0x02, 3.1, -0.2, 0.05)] if points is None else points
    lines = [
        f"SCAN {number}",
        f"UTC {utc}",
        f"STATUS {status}",
        f"VALID {valid}",
        "LLA 40.4168123 -3.7038456 652.31",
        "EULER 1.204 -0.512 87.330",
        "VEL 12.10 0.31 -0.12",
        f"NPOINTS {len(points) if npoints is None else npoints}",
        *[f"P {la} {e} 0x{f:02x} {x} {y} {z}" for la, e, f, x, y, z in points],
    ]
    return "\n".join(lines) + extra + "\nEND\n"


LOG = (
    "# LDMRS-MTIG acquisition log v1\n# date: 2011-06-21\n"
    + scan(125)  # good: 1 valid point, 1 clutter
    + scan(126, utc="2011-06-21T25:00:00Z")  # invalid UTC
    + scan(127, valid=0)  # invalid
    + scan(128, status="0x03")  # no GPS fix -> bad GPS
    + scan(129, status="0x05")  # Kalman filter not valid -> bad GPS
    + scan(131, points=[(0, 0, 0x08, 1.0, 1.0, 1.0), (1, 0, 0x00, 0.0, 0.0, 0.0)])  # lost 130; empty
    + scan(132, npoints=5)  # malformed: count mismatch
    + scan(133, points=[(1, 2, 0x04, 20.0, 1.5, -3.0), (3, 0, 0x01, 21.0, -1.5, -3.5)])  # good, 2 points
    + "SCAN 134\nUTC 2011-06-21T10:32:16Z\nLLA 1 2\n"  # truncated + malformed LLA
)


def test_every_rule_and_counter(tmp_path):
    path = tmp_path / "acq.log"
    path.write_text(LOG)
    counters = Counters()
    scans = list(read_ldmrs_mtig(path, counters, leap_seconds=18))
    assert [s.number for s in scans] == [125, 131, 133]
    c = counters
    assert (c.scans_total, c.scans_accepted, c.invalid_scans, c.bad_gps) == (9, 3, 2, 2)
    assert (c.lost_scans, c.empty_scans, c.malformed_scans) == (1, 1, 2)
    assert (c.rejected_clutter, c.rejected_dirt, c.rejected_zero) == (1, 1, 1)
    assert (c.points_total, c.points_valid) == (6, 3)
    assert any("announces 5 points but has 2" in where for where in c.locations)
    assert any("acq.log, line" in where and "file ends" in where for where in c.locations)
    first = scans[0]
    assert first.points.tolist() == [[0, 0, 0, 12.345, 0.512, -0.034]]
    assert first.lla == (40.4168123, -3.7038456, 652.31) and first.euler == (1.204, -0.512, 87.33)
    assert first.time_gps == pytest.approx(utc_to_gps("2011-06-21T10:32:15.25Z", 18))


def test_counter_wraps_at_65535(tmp_path):
    path = tmp_path / "wrap.log"
    path.write_text(scan(65534) + scan(65535) + scan(0) + scan(3))
    counters = Counters()
    assert len(list(read_ldmrs_mtig(path, counters))) == 4
    assert counters.lost_scans == 2  # 1 and 2


def test_gps_time_from_utc():
    # 2011-06-21 10:32:15 UTC: GPS week 1641, leap seconds then 15
    t = utc_to_gps("2011-06-21T10:32:15Z", 15)
    assert t // 604800 == 1641
    assert t % 604800 == pytest.approx(2 * 86400 + 10 * 3600 + 32 * 60 + 15 + 15)


def _config(tmp_path: Path, log_text: str) -> Path:
    (tmp_path / "acq.log").write_text(log_text)
    config = tmp_path / "flight.yaml"
    config.write_text(
        "input: {format: ldmrs_mtig, paths: [acq.log], mounting: pilatus, leap_seconds: 15}\noutput: out\n"
    )
    return config


def test_parse_stage_writes_columns_and_qc_files(tmp_path):
    config = _config(tmp_path, LOG)
    assert main(["run", str(config), "-q", "--until", "parse"]) == 0
    qc = tmp_path / "out" / "qc"
    debug = (qc / "debug.txt").read_text()
    for line in (
        "scans_total 9",
        "invalid_scans 2",
        "bad_gps 2",
        "lost_scans 1",
        "empty_scans 1",
        "malformed_scans 2",
    ):
        assert line in debug
    assert (qc / "scans.txt").read_text().split() == ["125", "133"]
    rows = (qc / "lla_eul_vel.csv").read_text().splitlines()
    assert rows[0].startswith("scan,time_gps,lat_deg") and len(rows) == 4
    manifest = json.loads((tmp_path / "out" / "run.json").read_text())
    parse = next(s for s in manifest["stages"] if s["name"] == "parse")
    traj, meta = read_columns(parse["outputs"]["trajectory"]["file"])
    assert traj["scan"].tolist() == [125, 131, 133] and meta["convention"] == "NWU"
    assert "NWU" in meta["attitude"]
    pulses, pmeta = read_columns(parse["outputs"]["pulses"]["file"])
    assert pmeta["mounting"] == "pilatus" and pmeta["lever_arm"] == [-0.023, 0.0514, -0.1365]
    assert pulses["scan"].tolist() == [125, 133, 133]
    np.testing.assert_allclose(pulses["x"], [12.345, 20.0, 21.0])
    assert pulses["flags"].tolist() == [0, 4, 1]


def test_log_with_no_usable_scan_exits_3(tmp_path, capsys):
    config = _config(tmp_path, scan(1, valid=0) + scan(2, status="0x01"))
    assert main(["run", str(config), "-q", "--until", "parse"]) == 3
    assert "no usable scan" in capsys.readouterr().err


def test_mounting_must_be_stated(tmp_path, capsys):
    (tmp_path / "acq.log").write_text(scan(1))
    config = tmp_path / "flight.yaml"
    config.write_text("input: {format: ldmrs_mtig, paths: [acq.log]}\noutput: out\n")
    assert main(["validate", str(config)]) == 2
    assert "input.mounting: required key is missing" in capsys.readouterr().err
