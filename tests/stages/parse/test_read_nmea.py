"""NMEA log (SPEC 3.B): checksums, positions, heights, dates, counted faults, as receivers write it."""

from __future__ import annotations

import json
from datetime import date
from pathlib import Path

import numpy as np
import pytest

from lidar.columns import read_columns
from pipeline.cli import main
from pipeline.errors import ConfigError
from stages.parse.read_ldmrs import utc_to_gps
from stages.parse.read_nmea import NmeaCounters, read_nmea, with_checksum
from tests.conftest import constant_geoid


def gga(tod: str, lat="4025.0087", ns="N", lon="00342.2307", ew="W", quality=2, msl="598.20", sep="51.30"):
    return with_checksum(f"INGGA,{tod},{lat},{ns},{lon},{ew},{quality},12,0.8,{msl},M,{sep},M,1.0,0100")


LOG = "\n".join(
    [
        with_checksum("INZDA,103215.00,21,06,2011,00,00"),
        gga("103215.00"),
        with_checksum("INHDT,87.33,T"),
        with_checksum("INVTG,87.10,T,85.00,M,23.5,N,43.5,K,D"),
        with_checksum("INGST,103215.00,0.9,0.5,0.4,10.0,0.021,0.018,0.035"),
        gga("103215.50", lat="3325.0000", ns="S", lon="07030.0000", ew="E"),
        "$INHDT,87.40,T*00",  # bad checksum
        "$INHDT,87.40,T",  # missing checksum
        gga("103216.00", quality=0),  # no fix
        with_checksum("INGGA,103216.50,4025.0087,N"),  # malformed
        with_checksum("INXYZ,1,2,3"),  # unknown
    ]
)


def test_positions_heights_and_counters(tmp_path):
    path = tmp_path / "nav.nmea"
    path.write_text(LOG + "\n")
    c = NmeaCounters()
    log = read_nmea(path, c, leap_seconds=15)
    assert (c.sentences, c.bad_checksum, c.no_fix, c.malformed, c.unknown) == (11, 2, 1, 1, 1)
    p = log.position
    np.testing.assert_allclose(p["lat"], [40 + 25.0087 / 60, -(33 + 25 / 60)])
    np.testing.assert_allclose(p["lon"], [-(3 + 42.2307 / 60), 70.5])
    np.testing.assert_allclose(p["h"], [598.2 + 51.3] * 2)  # ellipsoidal = MSL + geoid separation
    t0 = utc_to_gps("2011-06-21T10:32:15Z", 15)
    np.testing.assert_allclose(p["time"], [t0, t0 + 0.5])
    assert log.heading["heading_deg"].tolist() == [87.33] and log.heading["time"].tolist() == [t0]
    np.testing.assert_allclose(log.course["speed_ms"], [23.5 * 1852 / 3600])
    np.testing.assert_allclose(log.sigma["sigma_h_m"], [0.035])


def test_date_from_config_and_midnight_rollover(tmp_path):
    path = tmp_path / "nav.nmea"
    path.write_text("\n".join([gga("235959.50"), gga("000000.00")]) + "\n")
    log = read_nmea(path, NmeaCounters(), day=date(2011, 6, 21), leap_seconds=15)
    t = log.position["time"]
    assert t[1] - t[0] == pytest.approx(0.5)
    assert t[1] == pytest.approx(utc_to_gps("2011-06-22T00:00:00Z", 15))


def test_unknown_date_is_an_error_not_a_guess(tmp_path):
    path = tmp_path / "nav.nmea"
    path.write_text(gga("103215.00") + "\n")
    with pytest.raises(ConfigError, match=r"nav.nmea, line 1: the date of the NMEA times is unknown.*nmea_date"):
        read_nmea(path, NmeaCounters())


def _read(tmp_path, lines: list[str], **kwargs):
    path = tmp_path / "nav.nmea"
    path.write_text("\r\n".join(lines) + "\r\n")
    counters = NmeaCounters()
    return read_nmea(path, counters, **kwargs), counters


def test_zda_after_the_first_gga_dates_it(tmp_path):
    """Many receivers write the second's ZDA after its GGA: the first GGA is dated by the ZDA after it."""
    log, c = _read(
        tmp_path,
        [
            gga("103215.00"),
            with_checksum("GPHDT,87.33,T"),
            with_checksum("GPZDA,103215.00,21,06,2011,00,00"),
            gga("103216.00"),
            with_checksum("GPZDA,103216.00,21,06,2011,00,00"),
        ],
        leap_seconds=15,
    )
    t0 = utc_to_gps("2011-06-21T10:32:15Z", 15)
    np.testing.assert_allclose(log.position["time"], [t0, t0 + 1])
    assert log.heading["time"].tolist() == [t0]
    assert c.malformed == c.unknown == 0


def test_date_from_rmc_alone(tmp_path):
    """$xxRMC carries the date (ddmmyy) most receivers give; no ZDA and no configured date needed."""
    rmc = with_checksum("GPRMC,235959.50,A,4025.0087,N,00342.2307,W,45.1,87.3,210611,1.1,W,A")
    log, c = _read(tmp_path, [gga("235959.00"), rmc, gga("235959.50")], leap_seconds=15)
    t = utc_to_gps("2011-06-21T23:59:59Z", 15)
    np.testing.assert_allclose(log.position["time"], [t, t + 0.5])
    rmc99 = with_checksum("GPRMC,120000.00,A,4025.0087,N,00342.2307,W,45.1,87.3,311299,,,A")
    log, _ = _read(tmp_path, [rmc99, gga("120000.00")], leap_seconds=13)
    assert log.position["time"][0] == utc_to_gps("1999-12-31T12:00:00Z", 13)  # yy 80-99: 19yy


def test_midnight_with_zda_after_gga(tmp_path):
    """A GGA at 00:00:00 after the 23:59:59 ZDA is the next day; one before the next day's ZDA too."""
    log, _ = _read(
        tmp_path,
        [
            gga("235959.00"),
            with_checksum("INZDA,235959.00,30,06,2026,00,00"),
            gga("235959.50"),
            gga("000000.00"),
            with_checksum("INZDA,000000.00,01,07,2026,00,00"),
            gga("000000.50"),
        ],
        leap_seconds=18,
    )
    t = utc_to_gps("2026-06-30T23:59:59Z", 18)
    np.testing.assert_allclose(log.position["time"], t + np.array([0.0, 0.5, 1.0, 1.5]))
    before = with_checksum("INZDA,235959.00,30,06,2026,00,00")
    after = with_checksum("INZDA,000000.00,01,07,2026,00,00")
    # ZDA first, then a fix after midnight before the next day's ZDA;
    # a ZDA that comes after the first fix of a new day, and a log whose first ZDA is late
    for lines in ([before, gga("235959.50"), gga("000000.00")], [gga("235959.50"), gga("000000.00"), after]):
        log, _ = _read(tmp_path, lines, leap_seconds=18)
        np.testing.assert_allclose(log.position["time"], t + np.array([0.5, 1.0]))


def test_talkers_gns_rtk_and_other_sentences(tmp_path):
    """GN/GP talkers; GNS positions where the log has no GGA (modes R/F are RTK); the rest counted by type."""
    gns = "GNGNS,{},4025.0087,N,00342.2307,W,{},14,0.7,598.20,51.30,1.0,0100,V"
    log, c = _read(
        tmp_path,
        [
            with_checksum("GNZDA,103215.00,21,06,2011,00,00"),
            with_checksum(gns.format("103215.00", "RRN")),
            with_checksum("GPHDT,87.33,T"),
            with_checksum("GPGSV,3,1,12,01,40,083,46,02,17,308,41,12,07,344,39,14,22,228,45"),
            with_checksum(gns.format("103215.50", "FAN")),
            with_checksum("GNVTG,87.10,T,85.00,M,23.5,N,43.5,K,D"),
            with_checksum(gns.format("103216.00", "NNN")),  # no fix
            with_checksum("GLGSA,A,3,65,66,,,,,,,,,,,1.5,0.7,1.3,2"),
            with_checksum("PASHR,103215.50,87.40,T,-1.25,2.50,0.01,0.02,0.02,0.10,1,0"),
        ],
        leap_seconds=15,
    )
    t0 = utc_to_gps("2011-06-21T10:32:15Z", 15)
    np.testing.assert_allclose(log.position["time"], [t0, t0 + 0.5])
    np.testing.assert_allclose(log.position["h"], [598.2 + 51.3] * 2)
    assert log.position["quality"].tolist() == [4, 5] and c.rtk_fixes == 2 and c.gns_positions == 2
    assert log.position["satellites"].tolist() == [14, 14]
    assert log.heading["time"].tolist() == [t0] and log.course["time"].tolist() == [t0 + 0.5]
    assert c.no_fix == 1 and c.unread == {"GSV": 1, "GSA": 1} and c.unknown == 2
    assert log.attitude["time"].tolist() == [t0 + 0.5] and c.attitude_epochs == 1
    np.testing.assert_allclose(
        [log.attitude[k][0] for k in ("roll_deg", "pitch_deg", "heading_deg")], [-1.25, 2.5, 87.4]
    )
    # with GGA in the log, GNS epochs are the same fixes again: GGA is used, GNS not
    log, c = _read(
        tmp_path,
        [
            with_checksum("GNZDA,103215.00,21,06,2011,00,00"),
            gga("103215.00", quality=4),
            with_checksum(gns.format("103215.00", "RR")),
        ],
    )
    assert len(log.position["time"]) == 1 and c.gns_positions == 0 and c.rtk_fixes == 1


def test_empty_geoid_separation_needs_a_geoid(tmp_path):
    """An empty separation field is a valid fix: h = MSL + a stated separation or the geoid's; never 0."""
    lines = [with_checksum("GPZDA,103215.00,21,06,2011,00,00"), gga("103215.00", sep=""), gga("103216.00")]
    with pytest.raises(
        ConfigError,
        match=r"nav.nmea, line 2: 1 fixes have an empty geoid-separation.*"
        r"stages.georeference.geoid.*input.geoid_separation_m",
    ):
        _read(tmp_path, lines)
    log, _ = _read(tmp_path, lines, separation_m=49.0)
    np.testing.assert_allclose(log.position["h"], [598.2 + 49.0, 598.2 + 51.3])  # the sentence's own wins
    grid = constant_geoid(tmp_path / "geoid.tif", 50.5)
    log, _ = _read(tmp_path, lines, geoid=grid)
    np.testing.assert_allclose(log.position["h"], [598.2 + 50.5, 598.2 + 51.3], atol=1e-6)
    np.testing.assert_allclose(log.position["msl"], [598.2, 598.2])


def test_2d_fix_and_any_finite_heading(tmp_path):
    """A GGA without altitude is a 2-D fix, counted; a heading of 361 or -90 degrees is a heading; the empty
    sentences a receiver writes before its first fix are no fix, not malformed."""
    log, c = _read(
        tmp_path,
        [
            "$GPRMC,,V,,,,,,,,,,N*53",
            "$GPGGA,,,,,,0,00,99.99,,,,,,*48",
            "$GPZDA,,,,,00,00*48",
            with_checksum("GPZDA,103215.00,21,06,2011,00,00"),
            gga("103215.00", msl="", sep=""),
            gga("103216.00"),
            with_checksum("GPHDT,361.5,T"),
            with_checksum("GPHDT,-90.0,T"),
        ],
    )
    assert c.fixes_2d == 1 and c.malformed == 0 and c.bad_checksum == 0 and c.no_fix == 3
    assert len(log.position["time"]) == 1
    np.testing.assert_allclose(log.heading["heading_deg"], [1.5, 270.0])


def test_geoid_of_the_georeference_stage_gives_the_separation(tmp_path, capsys):
    """The 3.B sample with every separation field emptied: exit 2 with one sentence; with
    stages.georeference.geoid (N = 50 m here) or input.geoid_separation_m the trajectory is the original's."""
    root = Path(__file__).resolve().parents[3]
    lines = (root / "data_samples" / "flight_lmsq" / "lmsq" / "nav.nmea").read_text().splitlines()
    emptied = [with_checksum(s[1:].split("*")[0].replace(",M,50.0000,M,", ",M,,M,")) for s in lines[:400]]
    (tmp_path / "nav.nmea").write_text("\r\n".join(emptied) + "\r\n")
    grid = constant_geoid(tmp_path / "geoid.tif", 50.0)
    base = [
        "run",
        str(root / "configs" / "flight_nmea.yaml"),
        "-q",
        "--until",
        "parse",
        "--set",
        f"cache={tmp_path / 'cache'}",
    ]
    assert main([*base, "--set", f"output={tmp_path / 'a'}"]) == 0
    capsys.readouterr()
    nmea = f"input.nmea={tmp_path / 'nav.nmea'}"
    assert main([*base, "--set", f"output={tmp_path / 'b'}", "--set", nmea]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nav.nmea, line 2: " in err[0] and "empty geoid-separation field" in err[0]
    for name, extra in (("c", f"stages.georeference.geoid={grid}"), ("d", "input.geoid_separation_m=50")):
        assert main([*base, "--set", f"output={tmp_path / name}", "--set", nmea, "--set", extra]) == 0

    def heights(name):
        run = json.loads((tmp_path / name / "run.json").read_text())
        parse = next(s for s in run["stages"] if s["name"] == "parse")
        return read_columns(parse["outputs"]["trajectory"]["file"])[0]["h"]

    a = heights("a")
    for name in ("c", "d"):
        h = heights(name)
        np.testing.assert_allclose(h, a[: len(h)], atol=1e-6)
        assert len(h) > 100
