"""NMEA 0183 navigation log of the seed-2 design (SPEC 3.B).

Sentences read (any talker, ``IN`` in the seed): ``GGA`` (time, position,
fix quality, satellites, HDOP, height above mean sea level and geoid
separation: ellipsoidal height = MSL + separation), ``HDT`` (true heading),
``VTG`` (course over ground, speed), ``GST`` (sigma of latitude, longitude,
height in metres), ``ZDA`` (date).  Every checksum is verified.

Times: NMEA gives UTC time of day.  The date comes from the latest ``ZDA``,
else from the configured date; with neither, reading stops with an error
(never guessed).  With a configured date, a time of day that falls back by
more than 12 hours is the next day.  UTC becomes GPS time (seconds since
1980-01-06) with the configured leap seconds.  ``HDT`` and ``VTG`` carry no
time: they take the time of the last ``GGA`` of the same epoch.

Counted and skipped, never raised: bad or missing checksums, malformed
sentences, GGA without a fix (quality 0), unknown sentence types.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, date, datetime, timedelta
from pathlib import Path

import numpy as np

from pipeline.errors import InputDataError
from stages.readers import SkipLog, open_text
from stages.readers.ldmrs import GPS_EPOCH


@dataclass
class NmeaCounters(SkipLog):
    sentences: int = 0
    bad_checksum: int = 0
    malformed: int = 0
    no_fix: int = 0
    unknown: int = 0


def checksum_ok(sentence: str) -> bool:
    """``$...*hh``: hh is the XOR of every character between ``$`` and ``*``.

    >>> checksum_ok("$GPHDT,274.07,T*03")
    True
    >>> checksum_ok("$GPHDT,274.08,T*03")
    False
    """
    if not sentence.startswith("$") or "*" not in sentence:
        return False
    body, _, given = sentence[1:].rpartition("*")
    value = 0
    for ch in body:
        value ^= ord(ch)
    try:
        return int(given.strip()[:2], 16) == value
    except ValueError:
        return False


def with_checksum(body: str) -> str:
    """``$`` + body + ``*hh`` (for writers and tests)."""
    value = 0
    for ch in body:
        value ^= ord(ch)
    return f"${body}*{value:02X}"


def _degrees(value: str, hemisphere: str, width: int) -> float:
    """``ddmm.mmmm`` (width 2) or ``dddmm.mmmm`` (width 3) with N/S/E/W -> signed degrees."""
    if len(value) < width + 2 or hemisphere not in ("N", "S", "E", "W"):
        raise ValueError("bad coordinate")
    deg = int(value[:width]) + float(value[width:]) / 60.0
    return -deg if hemisphere in ("S", "W") else deg


def _time_of_day(text: str) -> float:
    h, m, s = int(text[0:2]), int(text[2:4]), float(text[4:])
    if not (0 <= h < 24 and 0 <= m < 60 and 0 <= s < 61):
        raise ValueError("bad time")
    return h * 3600 + m * 60 + s


@dataclass
class NmeaLog:
    """Arrays of the navigation log (times in GPS seconds since 1980-01-06)."""

    position: dict[str, np.ndarray]  # time, lat, lon, h (ellipsoidal), msl, quality, satellites, hdop
    heading: dict[str, np.ndarray]  # time, heading_deg (true, clockwise from north)
    course: dict[str, np.ndarray]  # time, course_deg, speed_ms
    sigma: dict[str, np.ndarray]  # time, sigma_lat_m, sigma_lon_m, sigma_h_m


def read_nmea(path: Path, counters: NmeaCounters, *, day: date | None = None, leap_seconds: float = 18.0) -> NmeaLog:
    """Read an NMEA log (see the module's notes for the rules)."""
    rows = {"position": [], "heading": [], "course": [], "sigma": []}
    current_day = day
    zda_day: date | None = None
    last_tod: float | None = None
    epoch_time: float | None = None

    def gps(tod: float, where: str) -> float:
        nonlocal current_day, last_tod
        the_day = zda_day or current_day
        if the_day is None:
            raise InputDataError(
                f"{where}: the date of the NMEA times is unknown (no $xxZDA sentence before it and no input.nmea_date)."
            )
        if zda_day is None and last_tod is not None and tod < last_tod - 43200:
            current_day = the_day = the_day + timedelta(days=1)  # midnight passed
        last_tod = tod
        stamp = datetime(the_day.year, the_day.month, the_day.day, tzinfo=UTC) + timedelta(seconds=tod)
        return (stamp - GPS_EPOCH).total_seconds() + leap_seconds

    with open_text(path, "ascii") as fh:
        for lineno, raw in enumerate(fh, 1):
            line = raw.strip()
            if not line:
                continue
            where = f"{path}, line {lineno}"
            counters.sentences += 1
            if not checksum_ok(line):
                counters.bad_checksum += 1
                counters.note(f"{where}: bad or missing checksum")
                continue
            fields = line[1:].rpartition("*")[0].split(",")
            kind = fields[0][2:] if len(fields[0]) == 5 else fields[0]
            f = fields[1:]
            try:
                if kind == "GGA":
                    tod = _time_of_day(f[0])
                    quality = int(f[5])
                    if quality == 0:
                        counters.no_fix += 1
                        continue
                    lat, lon = _degrees(f[1], f[2], 2), _degrees(f[3], f[4], 3)
                    msl, sep = float(f[8]), float(f[10])
                    values = (lat, lon, msl, sep, float(f[7]))
                    if (
                        not all(math.isfinite(v) for v in values)
                        or abs(lat) > 90
                        or abs(lon) > 180
                        or abs(msl) > 1e5
                        or abs(sep) > 1e3
                    ):
                        raise ValueError("out of range")
                    epoch_time = gps(tod, where)
                    rows["position"].append((epoch_time, lat, lon, msl + sep, msl, quality, int(f[6]), float(f[7])))
                elif kind == "HDT":
                    heading = float(f[0])
                    if not (0.0 <= heading <= 360.0):
                        raise ValueError("heading out of range")
                    if epoch_time is not None:
                        rows["heading"].append((epoch_time, heading))
                elif kind == "VTG":
                    course, knots = float(f[0]), float(f[4])
                    if not (0.0 <= course <= 360.0 and 0.0 <= knots < 1e4):
                        raise ValueError("course or speed out of range")
                    if epoch_time is not None:
                        rows["course"].append((epoch_time, course, knots * 1852.0 / 3600.0))
                elif kind == "GST":
                    tod = _time_of_day(f[0])
                    sl, so, sh = float(f[5]), float(f[6]), float(f[7])
                    if not all(0.0 <= v <= 1e4 for v in (sl, so, sh)):  # also rejects NaN
                        raise ValueError("sigma out of range")
                    rows["sigma"].append((gps(tod, where), sl, so, sh))
                elif kind == "ZDA":
                    zda_day = date(int(f[3]), int(f[2]), int(f[1]))
                else:
                    counters.unknown += 1
            except InputDataError:
                raise
            except (ValueError, IndexError, OverflowError):  # OverflowError: a 20-digit year
                counters.malformed += 1
                counters.note(f"{where}: malformed {kind} sentence")
    names = {
        "position": ("time", "lat", "lon", "h", "msl", "quality", "satellites", "hdop"),
        "heading": ("time", "heading_deg"),
        "course": ("time", "course_deg", "speed_ms"),
        "sigma": ("time", "sigma_lat_m", "sigma_lon_m", "sigma_h_m"),
    }
    out = {}
    for key, cols in names.items():
        table = np.array(rows[key], dtype=np.float64).reshape(-1, len(cols))
        out[key] = {c: table[:, i] for i, c in enumerate(cols)}
    return NmeaLog(**out)
