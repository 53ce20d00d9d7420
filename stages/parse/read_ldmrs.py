"""Format 3.A: the acquisition log of the seed-0 system (SICK LD-MRS + Xsens MTi-G).

One text file, scan after scan (``SCAN n``, then ``UTC``, ``STATUS``,
``VALID``, ``LLA``, ``EULER``, ``VEL``, ``NPOINTS`` and ``P`` lines, then
``END``), read line by line: memory does not grow with its length.
:func:`read_ldmrs_mtig` yields a file's accepted scans and counts the others
(:class:`Counters`: lost, invalid, bad-GPS, malformed and empty scans;
clutter, dirt and zero points); :class:`TimeOrder` keeps a survey's scans in
time order, skipping and counting the unambiguous faults (repeated scans, a
single scan out of line); :func:`read_survey` does both across the files of
a survey.  The validity rules and an example: ``docs/stages/parse.md``.
"""

from __future__ import annotations

import hashlib
import math
import zlib
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np

from lidar.glossary import LEAP_SECONDS
from pipeline.errors import InputDataError
from pipeline.log import Progress
from stages.parse.skiplog import SkipLog, open_text

#: Seed 0, Table 15: lever arm MPOS (m, MTi-G axes) of each mounting; LD-MRS -> MTi-G is Ry(+90 deg) first.
MOUNTINGS = {
    "laboratorio": (-0.0027, -0.0221, -0.0535),
    "pilatus": (-0.023, 0.0514, -0.1365),
    "cb5000": (0.013, 0.0299, -0.0565),
}
STATUS_XKF_VALID = 0b010
STATUS_GPS_FIX = 0b100
FLAG_CLUTTER = 0b0010
FLAG_DIRT = 0b1000
GPS_EPOCH = datetime(1980, 1, 6, tzinfo=UTC)


@dataclass
class Scan:
    """One accepted scan: its pose and its valid points."""

    number: int
    time_gps: float  # seconds since the GPS epoch (1980-01-06), from UTC + leap seconds
    status: int
    lla: tuple[float, float, float]  # deg, deg, m (ellipsoidal)
    euler: tuple[float, float, float]  # roll, pitch, yaw in deg, MTi-G NWU convention
    vel: tuple[float, float, float]  # m/s, body frame
    points: np.ndarray  # (n, 6): layer, echo, flags, x, y, z (LD-MRS frame, m)
    line: int
    lost: int = 0  # scan numbers missing just before this one (counted in lost_scans)
    where: str = ""  # "file, line N"


@dataclass
class Counters(SkipLog):
    """What the reader saw and skipped; nothing is dropped without a count."""

    scans_total: int = 0
    scans_accepted: int = 0
    lost_scans: int = 0
    invalid_scans: int = 0
    bad_gps: int = 0
    malformed_scans: int = 0
    empty_scans: int = 0
    points_total: int = 0
    points_valid: int = 0
    rejected_clutter: int = 0
    rejected_dirt: int = 0
    rejected_zero: int = 0
    duplicate_scans: int = 0
    out_of_order_scans: int = 0


class _Bad(Exception):
    """A malformed scan: the message names the line and the field."""


class TimeOrderError(ValueError):
    """The scans' times go backwards in a way that cannot be repaired: the message names the line."""


def utc_to_gps(text: str, leap_seconds: float) -> float:
    """ISO-8601 UTC time -> seconds since the GPS epoch (GPS = UTC + leap seconds).

    >>> utc_to_gps("1980-01-06T00:00:00Z", 0)
    0.0
    >>> utc_to_gps("2017-01-01T00:00:00.5Z", 18) - utc_to_gps("2017-01-01T00:00:00Z", 18)
    0.5
    """
    stamp = datetime.fromisoformat(text.replace("Z", "+00:00"))
    if stamp.tzinfo is None:
        raise ValueError("no time zone (UTC times end in Z)")
    return (stamp - GPS_EPOCH).total_seconds() + leap_seconds


def _floats(parts: list[str], n: int, key: str, where: str) -> tuple[float, ...]:
    if len(parts) != n + 1:
        raise _Bad(f"{where}: {key} needs {n} numbers")
    try:
        values = tuple(float(p) for p in parts[1:])
    except ValueError:
        raise _Bad(f"{where}: {key} has a value that is not a number") from None
    if not all(math.isfinite(v) for v in values):
        raise _Bad(f"{where}: {key} has a value that is not finite")
    return values


def read_ldmrs_mtig(
    path: Path,
    counters: Counters,
    *,
    leap_seconds: float = LEAP_SECONDS,
    advance: Callable[[int], object] | None = None,
) -> Iterator[Scan]:
    """Yield the accepted scans of one log, updating *counters*.

    Parameters
    ----------
    path : Path
        The acquisition log (UTF-8 or ASCII text).
    counters : Counters
        Updated in place (shared across the files of a survey).
    leap_seconds : float
        GPS - UTC in seconds (18 since 2017-01-01).
    advance : callable, optional
        Told at the end of each scan how many more bytes of the file (as stored, compressed or not) were read.
    """
    previous: int | None = None
    scan: dict | None = None
    with open_text(path) as fh:
        stored = getattr(fh.buffer, "fileobj", fh.buffer)  # a .gz file's compressed stream, else the file
        read = 0
        for lineno, raw in enumerate(fh, 1):
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            where = f"{path}, line {lineno}"
            parts = line.split()
            key = parts[0]
            if key == "SCAN":
                if scan is not None:  # the previous scan never ended
                    counters.malformed_scans += 1
                    counters.note(f"{scan['where']}: scan {scan.get('number')} has no END")
                scan = _start_scan(parts, where, lineno, previous, counters)
                previous = scan.get("number", previous)
            elif scan is None:
                counters.note(f"{where}: '{key}' outside a scan, line skipped")
            elif scan["error"]:
                if key == "END":
                    counters.malformed_scans += 1
                    counters.note(scan["error"])
                    scan = None
            elif key == "END":
                accepted = _finish(scan, counters, leap_seconds, where)
                scan = None
                if advance is not None and stored.tell() > read:
                    advance(stored.tell() - read)
                    read = stored.tell()
                if accepted is not None:
                    yield accepted
            else:
                try:
                    _read_field(scan, key, parts, where)
                except _Bad as exc:
                    scan["error"] = str(exc)
    if scan is not None:
        counters.malformed_scans += 1
        counters.note(f"{scan['where']}: the file ends inside this scan")


def _start_scan(parts: list[str], where: str, lineno: int, previous: int | None, counters: Counters) -> dict:
    """A new scan from its ``SCAN n`` line; the scan numbers skipped since *previous* are counted lost."""
    counters.scans_total += 1
    scan = {"where": where, "line": lineno, "points": [], "error": None}
    try:
        number = int(parts[1]) if len(parts) == 2 else -1
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        scan["error"] = f"{where}: SCAN needs a counter from 0 to 65535"
        return scan
    scan["number"] = number
    scan["lost"] = 0
    if previous is not None:
        jump = (number - previous) % 65536
        if jump > 1:
            counters.lost_scans += jump - 1
            scan["lost"] = jump - 1
    return scan


def _read_field(scan: dict, key: str, parts: list[str], where: str) -> None:
    """Store one line's field in *scan*; :class:`_Bad` names what does not parse."""
    if key == "UTC":
        scan["utc"] = parts[1] if len(parts) == 2 else None
    elif key == "STATUS":
        try:
            scan["status"] = int(parts[1], 16) if len(parts) == 2 else None
        except ValueError:
            raise _Bad(f"{where}: STATUS is not a hexadecimal byte") from None
    elif key == "VALID":
        if len(parts) != 2 or parts[1] not in ("0", "1"):
            raise _Bad(f"{where}: VALID must be 0 or 1")
        scan["valid"] = parts[1] == "1"
    elif key in ("LLA", "EULER", "VEL"):
        scan[key.lower()] = _floats(parts, 3, key, where)
    elif key == "NPOINTS":
        try:
            scan["npoints"] = int(parts[1]) if len(parts) == 2 else None
        except ValueError:
            raise _Bad(f"{where}: NPOINTS is not a whole number") from None
    elif key == "P":
        scan["points"].append(_point(parts, where))
    else:
        raise _Bad(f"{where}: unknown field '{key}'")


def _point(parts: list[str], where: str) -> tuple[int, int, int, float, float, float]:
    """A ``P layer echo flags x y z`` line."""
    if len(parts) != 7:
        raise _Bad(f"{where}: P needs layer, echo, flags, x, y, z")
    try:
        layer, echo, flags = int(parts[1]), int(parts[2]), int(parts[3], 16)
        x, y, z = float(parts[4]), float(parts[5]), float(parts[6])
    except ValueError:
        raise _Bad(f"{where}: a field of P does not parse") from None
    if not (0 <= layer <= 3 and 0 <= echo <= 2 and 0 <= flags <= 255):
        raise _Bad(f"{where}: P layer 0-3, echo 0-2 and flags 0x00-0xff expected")
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        raise _Bad(f"{where}: P coordinates must be finite")
    return layer, echo, flags, x, y, z


def read_survey(
    paths: list[Path], counters: Counters, *, leap_seconds: float = LEAP_SECONDS, progress: Progress | None = None
) -> Iterator[Scan]:
    """Yield the accepted scans of a survey's logs in time order (:class:`TimeOrder`, across the files).

    *progress* (optional) advances by the bytes of the files read (as
    stored, compressed or not).  A damaged compressed stream ends its file
    with a note (``malformed_scans``), not a traceback.

    Raises
    ------
    InputDataError
        When the time goes backwards in a way that cannot be repaired.
    """
    order = TimeOrder(counters)
    try:
        for path in paths:
            read = [0]

            def advance(n: int, read: list[int] = read) -> None:
                read[0] += n
                if progress is not None:
                    progress.update(n)

            scans = read_ldmrs_mtig(path, counters, leap_seconds=leap_seconds, advance=advance)
            for scan in _guard_stream(scans, path, counters):
                yield from order.feed(scan)
            if progress is not None:  # the rest of the file: its last lines, or past a damaged stream
                progress.update(max(Path(path).stat().st_size - read[0], 0))
        yield from order.flush()
    except TimeOrderError as exc:
        raise InputDataError(f"{exc}.") from None


def _guard_stream(iterator: Iterator[Scan], path: Path, counters: Counters) -> Iterator[Scan]:
    """Iterate a reader; a damaged compressed stream ends the file with a note, not a traceback."""
    try:
        yield from iterator
    except (EOFError, zlib.error, OSError) as exc:
        counters.malformed_scans += 1
        counters.note(f"{path}: the compressed stream is damaged ({exc}); the rest of the file is unreadable")


def _finish(scan: dict, counters: Counters, leap_seconds: float, where: str) -> Scan | None:
    """The scan ended at *where*, if it is complete, valid and has a GPS fix (else counted, None)."""
    missing = [k for k in ("utc", "status", "valid", "lla", "euler", "vel", "npoints") if scan.get(k) is None]
    if missing:
        counters.malformed_scans += 1
        counters.note(f"{scan['where']}: scan {scan['number']} lacks {', '.join(missing)}")
        return None
    if scan["npoints"] != len(scan["points"]):
        counters.malformed_scans += 1
        counters.note(
            f"{where}: scan {scan['number']} announces {scan['npoints']} points but has {len(scan['points'])}"
        )
        return None
    try:
        time_gps = utc_to_gps(scan["utc"], leap_seconds)
    except ValueError:
        time_gps = None
    if time_gps is None or not scan["valid"]:
        counters.invalid_scans += 1
        return None
    status = scan["status"]
    if (status & STATUS_XKF_VALID) == 0 or (status & STATUS_GPS_FIX) == 0:
        counters.bad_gps += 1
        return None
    pts = np.array(scan["points"], dtype=np.float64).reshape(-1, 6)
    keep = _valid_points(pts, counters)
    if not keep.any():
        counters.empty_scans += 1
    counters.scans_accepted += 1
    return Scan(
        number=scan["number"],
        time_gps=time_gps,
        status=status,
        lla=scan["lla"],
        euler=scan["euler"],
        vel=scan["vel"],
        points=pts[keep],
        line=scan["line"],
        lost=scan.get("lost", 0),
        where=scan["where"],
    )


def _valid_points(pts: np.ndarray, counters: Counters) -> np.ndarray:
    """Mask of the points kept: not clutter, not dirt, not at (0, 0, 0); the others counted by reason."""
    counters.points_total += len(pts)
    flags = pts[:, 2].astype(np.int64)
    clutter = (flags & FLAG_CLUTTER) != 0
    dirt = ((flags & FLAG_DIRT) != 0) & ~clutter
    zero = ~clutter & ~dirt & np.all(pts[:, 3:6] == 0.0, axis=1)
    counters.rejected_clutter += int(clutter.sum())
    counters.rejected_dirt += int(dirt.sum())
    counters.rejected_zero += int(zero.sum())
    keep = ~(clutter | dirt | zero)
    counters.points_valid += int(keep.sum())
    return keep


class TimeOrder:
    """Pass on scans whose times increase strictly; skip and count the unambiguous faults.

    Holds back at most two scans (streaming).  ``feed(scan)`` returns the
    scans now known to be in order; ``flush()`` the last ones.  A scan equal
    in every field to one already passed (or held) is a duplicate; a single
    scan out of line with the scans on both sides of it is out of order.  Two
    scans in a row going back in time are a fault that cannot be told apart
    from a clock error, and raise :class:`TimeOrderError` naming the line.
    The first and the last scan, with one neighbour only, are judged by
    :class:`_Ends` (three more scans held back at the start).
    """

    def __init__(self, counters: Counters):
        self.counters = counters
        self.ends = _Ends(self._skip)
        self.last: float | None = None  # time of the last scan passed on
        self.held: Scan | None = None  # the newest scan in order, not yet passed on
        self.suspect: Scan | None = None  # a scan earlier than ``held`` and than ``last``
        self.seen: set[tuple[float, bytes]] = set()

    @staticmethod
    def _digest(scan: Scan) -> bytes:
        head = np.array([scan.number, scan.time_gps, scan.status, *scan.lla, *scan.euler, *scan.vel])
        return hashlib.sha1(head.tobytes() + scan.points.tobytes()).digest()

    def _skip(self, scan: Scan, why: str) -> None:
        self.counters.out_of_order_scans += 1
        self.counters.scans_accepted -= 1
        self.counters.points_valid -= len(scan.points)
        self.counters.note(f"{scan.where}: scan {scan.number} skipped: {why}")

    def feed(self, scan: Scan) -> list[Scan]:
        key = (scan.time_gps, self._digest(scan))
        if key in self.seen:
            self.counters.duplicate_scans += 1
            self.counters.scans_accepted -= 1
            self.counters.points_valid -= len(scan.points)
            self.counters.lost_scans -= scan.lost  # the jump back to the repeated block loses nothing
            if self.counters.duplicate_scans == 1:
                self.counters.note(f"{scan.where}: scan {scan.number} repeats a scan already read; skipped")
            return []
        self.seen.add(key)
        out: list[Scan] = []
        if self.suspect is not None:
            suspect, self.suspect = self.suspect, None
            if scan.time_gps > self.held.time_gps:  # the suspect alone was out of line
                self._skip(suspect, "its time is earlier than the scans before and after it")
            else:
                raise TimeOrderError(
                    f"{suspect.where}: the time goes backwards (scan {suspect.number} is earlier than scan "
                    f"{self.held.number} at {self.held.where}, and the scans after it too); the log's clock or "
                    "order is wrong: give the files in time order or remove the scans that go back"
                )
        if self.held is None:
            self.held = scan
        elif scan.time_gps > self.held.time_gps:
            out.append(self.held)
            self.last, self.held = self.held.time_gps, scan
        elif self.last is None or scan.time_gps > self.last:
            # ``held`` jumped ahead of both neighbours (one far-future stamp): it is the odd one.
            self._skip(self.held, "its time is later than the scans after it")
            self.held = scan
        else:
            self.suspect = scan  # earlier than the two before it: the next scan tells
        return self.ends.feed(out)

    def flush(self) -> list[Scan]:
        """The scans still held, once the survey's last file is read."""
        if self.suspect is not None:
            self._skip(self.suspect, "its time is earlier than the scans before it")
            self.suspect = None
        out = [self.held] if self.held is not None else []
        self.held = None
        return self.ends.flush(out)


#: A first or last scan (one neighbour only) is out of line when its step to that neighbour is longer, by
#: more than this many of the log's scan intervals, than the scan numbers between them account for.
FAR_INTERVALS = 100


class _Ends:
    """Skip a first or last scan far in time from its single neighbour (counted as out of order).

    The log's scan interval is the median time per scan number over the last
    64 steps in order; "far" is :data:`FAR_INTERVALS` of them beyond what the
    scan numbers between the two scans account for (scans lost in between
    are not a fault).  The first scan is held until two steps after it are
    known; with fewer than three scans nothing is judged.
    """

    def __init__(self, skip):
        self.skip = skip
        self.early: list[Scan] | None = []  # the first scans, until the first one is judged
        self.prev: Scan | None = None
        self.steps: deque[float] = deque(maxlen=64)

    def _far(self, a: Scan, b: Scan, interval: float) -> str | None:
        """Why *b* is out of line with *a* (or *a* with *b*), or None."""
        numbers = (b.number - a.number) % 65536
        gap = b.time_gps - a.time_gps
        if not interval > 0 or gap - numbers * interval <= FAR_INTERVALS * interval:
            return None
        return (
            f"{gap:.3f} s between it and its one neighbour (scan numbers {a.number} and {b.number}), "
            f"far from the log's {interval:.3f} s scan interval"
        )

    def feed(self, scans: list[Scan]) -> list[Scan]:
        """The scans of *scans* (in order) that can be passed on now."""
        out: list[Scan] = []
        for scan in scans:
            if self.prev is not None and (scan.number - self.prev.number) % 65536:
                self.steps.append((scan.time_gps - self.prev.time_gps) / ((scan.number - self.prev.number) % 65536))
            self.prev = scan
            if self.early is None:
                out.append(scan)
                continue
            self.early.append(scan)
            if len(self.early) == 3:
                first, second, third = self.early
                self.early = None
                why = self._far(first, second, self.steps[-1] if self.steps else 0.0)
                if why:
                    self.skip(first, why)
                out += [second, third] if why else [first, second, third]
        return out

    def flush(self, last: list[Scan]) -> list[Scan]:
        """The scans still held, the survey's last one judged against the scan before it."""
        if last and self.prev is not None and len(self.steps):
            why = self._far(self.prev, last[0], float(np.median(self.steps)))
            if why:
                self.skip(last[0], why)
                last = []
        out = self.feed(last)
        out += self.early or []
        self.early = None
        return out
