"""NMEA 0183 navigation log of the seed-2 design (SPEC 3.B), as receivers write it.

Sentences from any talker: ``GGA`` positions (``GNS`` when the log has no
GGA), ``HDT`` headings, ``VTG`` courses, ``GST`` sigmas, ``ZDA`` and ``RMC``
dates, ``$PASHR`` attitudes; every checksum is verified.  Times of day are
dated by the ZDA/RMC anchors anywhere in the log (else from a configured
date, never guessed) and become GPS time with the leap seconds; ellipsoidal
height = MSL + geoid separation (from the sentence, the configuration or a
geoid grid, never 0).  Angles are valid modulo 360 degrees.  What cannot be
read is counted and skipped (:class:`NmeaCounters`), never raised.  The
rules in full: ``docs/stages/parse.md``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from datetime import UTC, date, datetime
from pathlib import Path

import numpy as np
import pyproj

from lidar.glossary import LEAP_SECONDS
from pipeline.errors import ConfigError
from stages.parse.read_ldmrs import GPS_EPOCH
from stages.parse.skiplog import SkipLog, open_text

#: GNS mode character -> GGA fix quality (NMEA 0183 v4.10); N: no fix
GNS_QUALITY = {"A": 1, "D": 2, "P": 3, "R": 4, "F": 5, "E": 6, "M": 7, "S": 8}
#: GNS quality used when several constellations give modes: the best one
_GNS_RANK = "RFPDAEMS"
DAY = 86400.0


@dataclass
class NmeaCounters(SkipLog):
    sentences: int = 0
    bad_checksum: int = 0
    malformed: int = 0
    no_fix: int = 0
    fixes_2d: int = 0
    rtk_fixes: int = 0  # quality 4 (fixed) or 5 (float)
    gns_positions: int = 0  # positions from GNS (the log has no GGA)
    attitude_epochs: int = 0  # $PASHR
    unknown: int = 0
    unread: dict[str, int] = field(default_factory=dict)  # sentence type -> count, types not read


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


def _finite(*values: float) -> None:
    if not all(math.isfinite(v) for v in values):
        raise ValueError("not finite")


def _angle(text: str) -> float:
    """A heading or course in degrees, any finite value, as [0, 360)."""
    value = float(text)
    _finite(value)
    value = math.fmod(value, 360.0)
    value = value + 360.0 if value < 0 else value
    return 0.0 if value >= 360.0 else value


def _position(f: list[str], lat_i: int, alt_i: int, sep_i: int) -> tuple[float, float, float | None, float | None]:
    """Latitude, longitude (degrees), MSL altitude and geoid separation (None when the field is empty)."""
    lat, lon = _degrees(f[lat_i], f[lat_i + 1], 2), _degrees(f[lat_i + 2], f[lat_i + 3], 3)
    msl = float(f[alt_i]) if f[alt_i].strip() else None
    sep = float(f[sep_i]) if len(f) > sep_i and f[sep_i].strip() else None
    _finite(lat, lon, *(v for v in (msl, sep) if v is not None))
    if abs(lat) > 90 or abs(lon) > 180 or (msl is not None and abs(msl) > 1e5) or (sep is not None and abs(sep) > 1e3):
        raise ValueError("out of range")
    return lat, lon, msl, sep


@dataclass
class NmeaLog:
    """Arrays of the navigation log (times in GPS seconds since 1980-01-06)."""

    position: dict[str, np.ndarray]  # time, lat, lon, h (ellipsoidal), msl, quality, satellites, hdop
    heading: dict[str, np.ndarray]  # time, heading_deg (true, clockwise from north)
    course: dict[str, np.ndarray]  # time, course_deg, speed_ms
    sigma: dict[str, np.ndarray]  # time, sigma_lat_m, sigma_lon_m, sigma_h_m
    attitude: dict[str, np.ndarray]  # time, roll_deg, pitch_deg, heading_deg ($PASHR; NED, aviation)


NAMES = {
    "position": ("time", "lat", "lon", "h", "msl", "quality", "satellites", "hdop"),
    "heading": ("time", "heading_deg"),
    "course": ("time", "course_deg", "speed_ms"),
    "sigma": ("time", "sigma_lat_m", "sigma_lon_m", "sigma_h_m"),
    "attitude": ("time", "roll_deg", "pitch_deg", "heading_deg"),
}


def read_nmea(
    path: Path,
    counters: NmeaCounters,
    *,
    day: date | None = None,
    leap_seconds: float = LEAP_SECONDS,
    separation_m: float | None = None,
    geoid: Path | None = None,
) -> NmeaLog:
    """Read an NMEA log: positions (GGA, or GNS without GGA), headings, courses, sigmas, attitudes.

    Parameters
    ----------
    path : Path
        The log (``.gz`` is decompressed on the fly); *counters* get everything counted and skipped.
    day : date, optional
        UTC date of the first time of a log without ZDA or RMC; *leap_seconds*: GPS - UTC, seconds.
    separation_m, geoid : float or Path, optional
        Geoid separation (metres) of fixes whose field is empty, or a PROJ ``vgridshift`` grid giving it.

    Raises
    ------
    ConfigError
        The log has no date and none is configured, or a fix has no separation and neither way is given.
    """
    log = _read_sentences(path, counters)
    source = "gga" if log.rows["gga"] else "gns"
    fixes = log.rows[source]
    if source == "gns":
        counters.gns_positions += len(fixes)
    gps = _gps_times(log, fixes, day, leap_seconds, path)
    out = {"position": _position_columns(fixes, gps["position"], separation_m, geoid, path, counters)}
    for key in ("sigma", "attitude"):
        table = np.array([r[0] for r in log.rows[key]], dtype=np.float64).reshape(-1, len(NAMES[key]) - 1)
        out[key] = dict(zip(NAMES[key], (gps[key], *table.T), strict=True))
    counters.attitude_epochs += len(log.rows["attitude"])
    column = 1 if source == "gga" else 2
    for key in ("heading", "course"):
        out[key] = _untimed_columns(key, log.untimed[key], column, gps["position"])
    return NmeaLog(**out)


@dataclass
class _Sentences:
    """The sentences of a log as read, before they are dated."""

    #: Each timed row: (values, time of day, index of the last anchor before it, line number)
    rows: dict[str, list] = field(default_factory=lambda: {"gga": [], "gns": [], "sigma": [], "attitude": []})
    #: HDT, VTG: (values, index of the last GGA, of the last GNS) -- they take that fix's time
    untimed: dict[str, list] = field(default_factory=lambda: {"heading": [], "course": []})
    #: ZDA, RMC: (time of day, UTC seconds since the GPS epoch of that instant)
    anchors: list[tuple[float, float]] = field(default_factory=list)
    first_timed: int | None = None  # line of the first timed sentence

    def timed(self, key: str, values: tuple, tod: float, lineno: int) -> None:
        self.rows[key].append((values, tod, len(self.anchors) - 1, lineno))
        self.first_timed = self.first_timed or lineno


def _read_sentences(path: Path, counters: NmeaCounters) -> _Sentences:
    """Every sentence of the log with a good checksum, parsed; the others counted."""
    log = _Sentences()
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
            address = fields[0]
            kind = address if address.startswith("P") else address[2:]
            try:
                _read_sentence(kind, fields[1:], log, counters, where, lineno)
            except (ValueError, IndexError, OverflowError):  # OverflowError: a 20-digit year
                counters.malformed += 1
                counters.note(f"{where}: malformed {kind} sentence")
    return log


def _read_sentence(kind: str, f: list[str], log: _Sentences, counters: NmeaCounters, where: str, lineno: int) -> None:
    """Add one sentence's fields *f* to *log*; raises ValueError or IndexError when it is malformed."""
    if kind in ("GGA", "GNS"):
        _read_fix(kind, f, log, counters, where, lineno)
    elif kind in ("HDT", "VTG"):
        key, values = ("heading", (_angle(f[0]),)) if kind == "HDT" else ("course", _course(f))
        log.untimed[key].append((values, len(log.rows["gga"]) - 1, len(log.rows["gns"]) - 1))
    elif kind == "GST":
        tod = _time_of_day(f[0])
        log.timed("sigma", _sigmas(f), tod, lineno)
    elif kind == "PASHR":
        tod = _time_of_day(f[0])
        log.timed("attitude", _pashr(f), tod, lineno)
    elif kind in ("ZDA", "RMC") and not (f[0].strip() and f[8 if kind == "RMC" else 3].strip()):
        counters.no_fix += 1  # no time or date yet (receivers write it before their first fix)
    elif kind in ("ZDA", "RMC"):
        log.anchors.append(_anchor(kind, f))
    else:
        counters.unknown += 1
        counters.unread[kind] = counters.unread.get(kind, 0) + 1


def _read_fix(kind: str, f: list[str], log: _Sentences, counters: NmeaCounters, where: str, lineno: int) -> None:
    """A GGA or GNS: a 3-D fix added to *log*; no fix and 2-D fixes counted."""
    if kind == "GGA":
        quality = int(f[5] or 0)
    else:
        ranks = [_GNS_RANK.index(c) for c in f[5].strip().upper() if c in _GNS_RANK]
        quality = GNS_QUALITY[_GNS_RANK[min(ranks)]] if ranks else 0
    if quality == 0:  # receivers write it with empty fields before their first fix
        counters.no_fix += 1
        return
    tod = _time_of_day(f[0])
    lat, lon, msl, sep = _position(f, 1, 8, 10 if kind == "GGA" else 9)
    sats = int(f[6]) if f[6].strip() else 0
    hdop = float(f[7]) if f[7].strip() else math.nan  # empty: not given (NaN)
    if f[7].strip():
        _finite(hdop)
    if msl is None:
        counters.fixes_2d += 1
        counters.note(f"{where}: 2-D fix ({kind} without altitude); not a 3-D position")
        return
    sep = math.nan if sep is None else sep
    log.timed(kind.lower(), (lat, lon, msl, sep, quality, sats, hdop), tod, lineno)


def _course(f: list[str]) -> tuple[float, float]:
    """VTG: course over ground (degrees) and speed (m/s, from knots)."""
    knots = float(f[4])
    if not (0.0 <= knots < 1e4):  # also rejects NaN
        raise ValueError("speed out of range")
    return _angle(f[0]), knots * 1852.0 / 3600.0


def _sigmas(f: list[str]) -> tuple[float, float, float]:
    """GST: sigma of latitude, longitude and height (metres)."""
    sl, so, sh = float(f[5]), float(f[6]), float(f[7])
    if not all(0.0 <= v <= 1e4 for v in (sl, so, sh)):  # also rejects NaN
        raise ValueError("sigma out of range")
    return sl, so, sh


def _pashr(f: list[str]) -> tuple[float, float, float]:
    """$PASHR: roll, pitch and true heading (degrees)."""
    heading, roll, pitch = _angle(f[1]), float(f[3]), float(f[4])
    _finite(roll, pitch)
    return roll, pitch, heading


def _anchor(kind: str, f: list[str]) -> tuple[float, float]:
    """ZDA or RMC: the time of day and the UTC seconds since the GPS epoch of that instant."""
    tod = _time_of_day(f[0])
    if kind == "ZDA":
        the_day = date(int(f[3]), int(f[2]), int(f[1]))
    else:
        ddmmyy = f[8].strip()
        if len(ddmmyy) != 6:
            raise ValueError("bad RMC date")
        yy = int(ddmmyy[4:6])  # GPS began in 1980: 80-99 are 19yy
        the_day = date(2000 + yy if yy < 80 else 1900 + yy, int(ddmmyy[2:4]), int(ddmmyy[0:2]))
    midnight = datetime(the_day.year, the_day.month, the_day.day, tzinfo=UTC)
    return tod, (midnight - GPS_EPOCH).total_seconds() + tod


def _gps_times(log: _Sentences, fixes: list, day: date | None, leap_seconds: float, path: Path) -> dict:
    """GPS times of the fixes, sigmas and attitudes: dated by the anchors, else by the configured *day*."""
    timed = {"position": fixes, "sigma": log.rows["sigma"], "attitude": log.rows["attitude"]}
    if log.anchors:
        utc = _anchored(timed, log.anchors)
    else:
        utc = _chain_dates(timed, day, f"{path}, line {log.first_timed}")
    return {k: v + leap_seconds for k, v in utc.items()}


def _anchored(timed: dict[str, list], anchors: list[tuple[float, float]]) -> dict[str, np.ndarray]:
    """Each time of day dated by the last anchor before it (the first one when none precedes), within 12 hours."""
    a = np.array(anchors, dtype=np.float64)
    utc = {}
    for key, items in timed.items():
        tod = np.array([r[1] for r in items], dtype=np.float64)
        k = np.maximum(np.array([r[2] for r in items], dtype=np.int64), 0)  # none before: the first after
        utc[key] = a[k, 1] + np.mod(tod - a[k, 0] + DAY / 2, DAY) - DAY / 2 if len(items) else np.zeros(0)
    return utc


def _position_columns(
    fixes: list, times: np.ndarray, separation_m: float | None, geoid: Path | None, path: Path, counters: NmeaCounters
) -> dict[str, np.ndarray]:
    """The fixes' columns; ellipsoidal height = MSL + separation (from the sentence, the configuration or the geoid)."""
    pos = np.array([r[0] for r in fixes], dtype=np.float64).reshape(-1, 7)
    sep = pos[:, 3]
    missing = np.isnan(sep)
    if missing.any():
        first = fixes[int(np.flatnonzero(missing)[0])][3]
        if separation_m is not None:
            sep = np.where(missing, separation_m, sep)
        elif geoid is not None:
            sep = np.where(missing, geoid_separation(geoid, pos[:, 0], pos[:, 1]), sep)
        else:
            raise ConfigError(
                f"{path}, line {first}: {int(missing.sum())} fixes have an empty geoid-separation field, so their "
                "ellipsoidal height is unknown; set stages.georeference.geoid (a geoid grid) or "
                "input.geoid_separation_m (metres)."
            )
    counters.rtk_fixes += int(np.isin(pos[:, 4], (4, 5)).sum())
    columns = (times, pos[:, 0], pos[:, 1], pos[:, 2] + sep, pos[:, 2], pos[:, 4], pos[:, 5], pos[:, 6])
    return dict(zip(NAMES["position"], columns, strict=True))


def _untimed_columns(key: str, items: list, column: int, fix_times: np.ndarray) -> dict[str, np.ndarray]:
    """HDT or VTG columns, timed by the fix before them (*column*: 1 for GGA, 2 for GNS); none before the first fix."""
    items = [r for r in items if r[column] >= 0]
    idx = np.array([r[column] for r in items], dtype=np.int64)
    table = np.array([r[0] for r in items], dtype=np.float64).reshape(-1, len(NAMES[key]) - 1)
    return dict(zip(NAMES[key], (fix_times[idx], *table.T), strict=True))


def _chain_dates(timed: dict[str, list], day: date | None, first: str) -> dict[str, np.ndarray]:
    """A log without ZDA or RMC: the configured date for its first time, a day more each time the
    time of day falls back by more than 12 hours (in the order of the lines)."""
    order = sorted((r[3], key, i, r[1]) for key, items in timed.items() for i, r in enumerate(items))
    out = {key: np.zeros(len(items)) for key, items in timed.items()}
    if not order:
        return out
    if day is None:
        raise ConfigError(
            f"{first}: the date of the NMEA times is unknown (the log has no $xxZDA or $xxRMC sentence); "
            "set input.nmea_date."
        )
    midnight = (datetime(day.year, day.month, day.day, tzinfo=UTC) - GPS_EPOCH).total_seconds()
    tod = np.array([r[3] for r in order])
    days = np.concatenate(([0], np.cumsum(np.diff(tod) < -DAY / 2)))
    for (_, key, i, _), value in zip(order, midnight + days * DAY + tod, strict=True):
        out[key][i] = value
    return out


def geoid_separation(grid: Path, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """Geoid height N (metres) of a PROJ ``vgridshift`` grid at latitudes and longitudes in degrees.

    Raises
    ------
    ConfigError
        The grid does not cover a position (or cannot be read).
    """
    pipeline = (
        "+proj=pipeline +step +proj=unitconvert +xy_in=deg +xy_out=rad "
        f"+step +proj=vgridshift +grids={grid} +multiplier=1 +step +proj=unitconvert +xy_in=rad +xy_out=deg"
    )
    try:
        tr = pyproj.Transformer.from_pipeline(pipeline)
        _, _, n = tr.transform(np.asarray(lon, float), np.asarray(lat, float), np.zeros(len(lat)), errcheck=True)
    except pyproj.exceptions.ProjError as exc:
        raise ConfigError(f"{grid}: the geoid grid gives no separation at the NMEA positions ({exc}).") from None
    n = np.asarray(n, dtype=np.float64)
    if not np.all(np.isfinite(n)):
        raise ConfigError(f"{grid}: the geoid grid does not cover every NMEA position.")
    return n
