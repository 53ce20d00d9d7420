"""NMEA log (SPEC 3.B): checksums, positions, heights, dates, counted faults."""

from __future__ import annotations

from datetime import date

import numpy as np
import pytest

from pipeline.errors import InputDataError
from stages.readers.ldmrs import utc_to_gps
from stages.readers.nmea import NmeaCounters, read_nmea, with_checksum


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
    with pytest.raises(InputDataError, match=r"nav.nmea, line 1: the date of the NMEA times is unknown"):
        read_nmea(path, NmeaCounters())
