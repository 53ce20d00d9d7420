"""INS attitude log of format 3.B, and the SBET / smrmsg trajectory files of format 3.C.

INS CSV: ``gps_sow,roll_deg,pitch_deg,heading_deg`` (body vs local-level
NED, heading clockwise from north).  SBET: records of 17 little-endian
float64; smrmsg: 10 float64.  Times are GPS seconds of week: the week is
given (never guessed), a rollover inside the file adds one.  Angles are
valid modulo 360 degrees and come out canonical (:func:`canonical_attitude`).
Lines or records that do not parse or hold impossible values, and epochs
whose time does not increase, are counted and skipped
(:class:`TrajectoryCounters`).  The rules in full: ``docs/stages/parse.md``.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import InputDataError
from stages.parse.skiplog import SkipLog, open_text

SECONDS_PER_WEEK = 604_800.0
INS_HEADER = "gps_sow,roll_deg,pitch_deg,heading_deg"


@dataclass
class TrajectoryCounters(SkipLog):
    epochs: int = 0
    malformed: int = 0
    not_increasing: int = 0
    truncated_bytes: int = 0


def absolute_time(sow: np.ndarray, week: int) -> np.ndarray:
    """GPS seconds since 1980-01-06 from seconds of week, adding a week at each rollover."""
    sow = np.asarray(sow, dtype=np.float64)
    rollover = np.concatenate(([0], np.cumsum(np.diff(sow) < -SECONDS_PER_WEEK / 2)))
    return (week + rollover) * SECONDS_PER_WEEK + sow


def wrap_degrees(angle: np.ndarray, low: float = -180.0) -> np.ndarray:
    """*angle* (degrees, any finite value) in [low, low + 360).

    >>> wrap_degrees(np.array([540.0, -190.0, 720.0])).tolist()
    [-180.0, 170.0, 0.0]
    """
    return np.mod(np.asarray(angle, dtype=np.float64) - low, 360.0) + low


def canonical_attitude(
    roll: np.ndarray, pitch: np.ndarray, heading: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The same rotation Rz(heading) Ry(pitch) Rx(roll) with roll in (-180, 180], pitch in [-90, 90],
    heading in [0, 360) (degrees; any finite input).

    A pitch beyond +-90 degrees is the identity Rz(h + 180) Ry(180 - p) Rx(r + 180) = Rz(h) Ry(p) Rx(r)
    applied once.
    """
    roll = np.asarray(roll, dtype=np.float64)
    pitch = -wrap_degrees(-np.asarray(pitch, dtype=np.float64))  # (-180, 180]
    heading = np.asarray(heading, dtype=np.float64)
    over = np.abs(pitch) > 90.0
    pitch = np.where(over, np.copysign(180.0, pitch) - pitch, pitch)
    roll = -wrap_degrees(-(roll + np.where(over, 180.0, 0.0)))
    heading = wrap_degrees(heading + np.where(over, 180.0, 0.0), 0.0)
    return roll, pitch, np.where(heading >= 360.0, 0.0, heading)


def increasing(t: np.ndarray, counters: TrajectoryCounters, what: str, where: Callable[[int], str]) -> np.ndarray:
    """Mask of epochs kept: each strictly later than the last kept one."""
    keep = np.ones(len(t), bool)
    if len(t) < 2:
        return keep
    running = np.maximum.accumulate(t)
    keep[1:] = t[1:] > running[:-1]
    bad = np.flatnonzero(~keep)
    counters.not_increasing += len(bad)
    for i in bad[:3]:
        counters.note(f"{where(i)}: {what} time {t[i]:.6f} does not increase; epoch skipped")
    return keep


def read_ins_csv(path: Path, week: int, counters: TrajectoryCounters) -> dict[str, np.ndarray]:
    """Time (GPS s since 1980-01-06), roll, pitch, heading (degrees, NED) of the INS log.

    Read line by line into compact arrays (8 bytes a value), so a long
    flight's log costs what its columns cost and no more.
    """
    cols = [array("d") for _ in range(4)]
    lines = array("q")
    with open_text(path, "ascii") as fh:
        first = fh.readline().strip()
        if first.replace(" ", "") != INS_HEADER:
            raise InputDataError(f"{path}, line 1: header must be '{INS_HEADER}' (found '{first[:60]}').")
        for lineno, raw in enumerate(fh, 2):
            line = raw.strip()
            if not line:
                continue
            parts = line.split(",")
            try:
                if len(parts) != 4:
                    raise ValueError
                values = [float(p) for p in parts]
                if not all(math.isfinite(v) for v in values) or not 0 <= values[0] < SECONDS_PER_WEEK:
                    raise ValueError
            except ValueError:
                counters.malformed += 1
                counters.note(
                    f"{path}, line {lineno}: not four finite numbers with gps_sow in 0-604800 (angles may be "
                    "any finite number of degrees); line skipped"
                )
                continue
            for col, value in zip(cols, values, strict=True):
                col.append(value)
            lines.append(lineno)
    table = [np.frombuffer(c, dtype=np.float64) if len(c) else np.zeros(0) for c in cols]
    t = absolute_time(table[0], week)
    keep = increasing(t, counters, "INS", lambda i: f"{path}, line {lines[i]}")
    counters.epochs += int(keep.sum())
    roll, pitch, heading = canonical_attitude(table[1][keep], table[2][keep], table[3][keep])
    return {"time": t[keep], "roll": roll, "pitch": pitch, "heading": heading}


def _records(path: Path, width: int, counters: TrajectoryCounters) -> np.ndarray:
    size = Path(path).stat().st_size
    n = size // (8 * width)
    counters.truncated_bytes += size - n * 8 * width
    if size - n * 8 * width:
        counters.note(f"{path}, byte {n * 8 * width}: last record cut off ({size - n * 8 * width} bytes ignored)")
    if n == 0:
        return np.zeros((0, width))
    return np.memmap(path, dtype="<f8", mode="r", shape=(n, width))


def read_sbet(path: Path, week: int, counters: TrajectoryCounters) -> dict[str, np.ndarray]:
    """Time, lat, lon (degrees), h, roll, pitch, true heading (degrees, NED) of an SBET.

    True heading = platform heading - wander angle (SPEC 3.C).  Every angle is valid modulo 2 pi;
    a record is impossible only with a non-finite value, |latitude| > pi/2, |longitude| > 2 pi,
    |height| >= 100 km or a time outside the week.
    """
    rec = _records(path, 17, counters)
    finite = np.all(np.isfinite(rec), axis=1) if len(rec) else np.zeros(0, bool)
    if len(rec):
        # physically possible values only: a flipped byte can make any float64 finite but absurd
        sane = finite & (np.abs(rec[:, 1]) <= np.pi / 2) & (np.abs(rec[:, 2]) <= 2 * np.pi)
        sane &= (rec[:, 0] >= 0) & (rec[:, 0] < SECONDS_PER_WEEK) & (np.abs(rec[:, 3]) < 1e5)
    else:
        sane = finite
    bad = np.flatnonzero(~sane)
    counters.malformed += len(bad)
    for i in bad[:3]:
        counters.note(f"{path}, byte {i * 136}: record with a non-finite or impossible value; skipped")
    idx = np.flatnonzero(sane)
    t = absolute_time(rec[idx, 0], week)
    keep = increasing(t, counters, "SBET", lambda i: f"{path}, byte {idx[i] * 136}")
    idx = idx[keep]
    counters.epochs += len(idx)
    r = np.asarray(rec[idx])

    def deg(rad: np.ndarray) -> np.ndarray:  # wrapped first: np.degrees(1e308) would overflow
        return np.degrees(np.mod(rad + np.pi, 2 * np.pi) - np.pi)

    roll, pitch, heading = canonical_attitude(deg(r[:, 7]), deg(r[:, 8]), deg(r[:, 9]) - deg(r[:, 10]))
    return {
        "time": t[keep],
        "lat": np.degrees(r[:, 1]),
        "lon": np.degrees(r[:, 2]),
        "h": r[:, 3],
        "roll": roll,
        "pitch": pitch,
        "heading": heading,
    }


def read_smrmsg(path: Path, week: int, counters: TrajectoryCounters) -> dict[str, np.ndarray]:
    """Time and sigmas of an smrmsg file: position (m), attitude (converted to degrees)."""
    rec = _records(path, 10, counters)
    ok = (
        np.all(np.isfinite(rec), axis=1) & (rec[:, 0] >= 0) & (rec[:, 0] < SECONDS_PER_WEEK)
        if len(rec)
        else np.zeros(0, bool)
    )
    if len(rec):  # a sigma is never negative; none beyond 10 km or 180 degrees (10,800 arc minutes) is real
        ok &= np.all((rec[:, 1:] >= 0) & (rec[:, 1:] <= 1e4), axis=1) & np.all(rec[:, 7:] <= 10_800, axis=1)
    bad = np.flatnonzero(~ok)
    for i in bad[:3]:
        counters.note(f"{path}, byte {i * 80}: smrmsg record with a non-finite or impossible value; skipped")
    counters.malformed += len(bad)
    idx = np.flatnonzero(ok)
    t = absolute_time(rec[idx, 0], week)
    keep = increasing(t, counters, "smrmsg", lambda i: f"{path}, byte {idx[i] * 80}")
    r = np.asarray(rec[idx[keep]])
    return {
        "time": t[keep],
        "sigma_north_m": r[:, 1],
        "sigma_east_m": r[:, 2],
        "sigma_down_m": r[:, 3],
        "sigma_roll_deg": r[:, 7] / 60.0,
        "sigma_pitch_deg": r[:, 8] / 60.0,
        "sigma_heading_deg": r[:, 9] / 60.0,
    }
