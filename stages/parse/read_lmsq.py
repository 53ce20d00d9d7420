"""The ``.lmsq`` scanner stream of the seed-2 design (SPEC 3.B and 3.C), read in chunks.

A 16-byte header (``b"LMSQ"``, version 1, model 140 or 280), then records:
type 1, an 18-byte measurement (range, amplitude, mirror angle, quality and
echo, microseconds since the last PPS, RGB); type 2, an 11-byte PPS (GPS
seconds of week, GPS week).  A measurement belongs to the last PPS before
it; after a missed PPS the microsecond counter still dates it (kept, flagged
``recovered``) unless the counter wrapped or saturated or the next PPS
contradicts it (dropped, ``pps_ambiguous``).  Everything skipped is counted
(:class:`LmsqCounters`).  Runs of measurements are decoded as NumPy blocks,
so a file of millions of pulses reads at array speed.  The layout and the
rules in full: ``docs/stages/parse.md``.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.errors import InputDataError
from pipeline.log import Progress

HEADER = 16
MEASUREMENT = 18
PPS = 11
SECONDS_PER_WEEK = 604_800.0


@dataclass
class LmsqCounters:
    measurements: int = 0
    pps: int = 0
    before_first_pps: int = 0
    missed_pps: int = 0  # measurements after a missed PPS: 1 s or more after their PPS, or after a counter wrap
    pps_recovered: int = 0  # of those, dated exactly from the us counter and kept (flagged)
    pps_ambiguous: int = 0  # of those, dropped: the counter wrapped or saturated, or the next PPS contradicts them
    invalid_quality: int = 0
    truncated_bytes: int = 0


@dataclass(frozen=True)
class LmsqHeader:
    version: int
    model: int


def _u24(block: np.ndarray, col: int) -> np.ndarray:
    b = block[:, col : col + 3].astype(np.int64)
    return b[:, 0] | (b[:, 1] << 8) | (b[:, 2] << 16)


def decode_measurements(block: np.ndarray) -> dict[str, np.ndarray]:
    """Decode an (n, 18) uint8 block of type-1 records into columns."""
    angle = _u24(block, 5)
    angle = np.where(angle >= 1 << 23, angle - (1 << 24), angle)
    quality = block[:, 8]
    rgb = block[:, 12:18].copy().view("<u2").reshape(-1, 3)
    return {
        "range_m": _u24(block, 1) * 1e-3,
        "amplitude": block[:, 4].copy(),
        "angle_deg": angle * 1e-4,
        "quality": (quality & 0x3F).astype(np.uint8),
        "echo": (quality >> 6).astype(np.uint8),
        "offset_us": _u24(block, 9),
        "rgb": rgb,
    }


def read_header(path: Path) -> LmsqHeader:
    with open(path, "rb") as fh:
        head = fh.read(HEADER)
    if len(head) < HEADER or head[:4] != b"LMSQ":
        raise InputDataError(f"{path}, byte 0: not an .lmsq scanner stream (no LMSQ signature).")
    version, model = np.frombuffer(head[4:8], "<u2")
    if version != 1:
        raise InputDataError(f"{path}, byte 4: version {version} is not supported (only 1).")
    if model not in (140, 280):
        raise InputDataError(f"{path}, byte 6: scanner model {model} is not 140 or 280.")
    return LmsqHeader(int(version), int(model))


def read_lmsq(path: Path, counters: LmsqCounters, *, chunk_bytes: int = 1 << 24) -> Iterator[dict[str, np.ndarray]]:
    """Yield blocks of valid measurements with their GPS time, reading *chunk_bytes* at a time.

    Each block has the columns of :func:`decode_measurements` (less
    ``offset_us``) plus ``time`` (GPS seconds since the GPS epoch:
    week * 604800 + seconds of week + offset), ``recovered`` (True: dated
    from the counter after a missed PPS) and ``byte`` (the record's offset
    in the file, for error reports).  Measurements after a missed PPS are
    held until the next PPS record confirms them, so blocks stay in time
    order.
    """
    read_header(path)
    timer = _Timer(counters)
    with open(path, "rb") as fh:
        fh.seek(HEADER)
        base = HEADER  # file offset of buf[0]
        buf = fh.read(chunk_bytes)
        eof = len(buf) < chunk_bytes
        pos = 0
        while True:
            arr = np.frombuffer(buf, dtype=np.uint8)
            n_left = len(arr) - pos
            if n_left <= 0 and eof:
                break
            # A run of whole measurement records starting at pos.
            k = n_left // MEASUREMENT
            types = arr[pos : pos + k * MEASUREMENT : MEASUREMENT] if k else arr[:0]
            stop = np.flatnonzero(types != 1)
            run = int(stop[0]) if len(stop) else k
            if run:
                block = arr[pos : pos + run * MEASUREMENT].reshape(run, MEASUREMENT)
                yield from timer.measurements(block, base + pos)
                pos += run * MEASUREMENT
                continue
            if n_left > 0 and arr[pos] == 2 and n_left >= PPS:
                sow = float(np.frombuffer(buf, "<f8", 1, pos + 1)[0])
                week = int(np.frombuffer(buf, "<u2", 1, pos + 9)[0])
                if not (np.isfinite(sow) and 0.0 <= sow < SECONDS_PER_WEEK):
                    raise InputDataError(f"{path}, byte {base + pos}: PPS seconds of week {sow:g} out of 0-604800.")
                yield from timer.pps(week * SECONDS_PER_WEEK + sow)
                pos += PPS
                continue
            if n_left > 0 and arr[pos] not in (1, 2):
                raise InputDataError(
                    f"{path}, byte {base + pos}: unknown record type {int(arr[pos])} (the stream is corrupt)."
                )
            # A record cut by the chunk boundary (or by the end of the file).
            if eof:
                counters.truncated_bytes += n_left
                break
            more = fh.read(chunk_bytes)
            eof = len(more) < chunk_bytes
            buf = buf[pos:] + more
            base += pos
            pos = 0
    yield from timer.flush()


def read_streams(
    paths: list[Path], counters: LmsqCounters, progress: Progress | None = None
) -> Iterator[dict[str, np.ndarray]]:
    """Yield the blocks of :func:`read_lmsq` of a survey's streams in turn; *progress* advances by the bytes read."""
    for path in paths:
        last = 0
        for block in read_lmsq(path, counters):
            yield block
            done = int(block["byte"][-1])
            if progress is not None:
                progress.update(done - last)
            last = done


class _Timer:
    """Dates measurements from the last PPS; holds those after a missed PPS until the next PPS confirms them."""

    def __init__(self, counters: LmsqCounters):
        self.counters = counters
        self.pps_time: float | None = None
        self.top = -1  # largest counter value since the last PPS
        self.wrapped = False  # the counter fell back since the last PPS: nothing more is datable
        self.held: list[dict[str, np.ndarray]] = []  # recovered measurements awaiting the next PPS

    def pps(self, t: float):
        """A PPS record at GPS time *t*: release or drop the held measurements, restart the counter."""
        if self.held:
            step = t - self.pps_time
            whole = step >= 1.0 - 1e-6 and abs(step - round(step)) <= 1e-6
            for block in self.held:
                ok = (block["time"] < t) if whole else np.zeros(len(block["time"]), bool)
                yield from self._release(block, ok)
            self.held = []
        self.pps_time, self.top, self.wrapped = t, -1, False
        self.counters.pps += 1

    def flush(self):
        """End of the stream: nothing contradicts the held measurements."""
        for block in self.held:
            yield from self._release(block, np.ones(len(block["time"]), bool))
        self.held = []

    def _release(self, block: dict[str, np.ndarray], ok: np.ndarray):
        c = self.counters
        c.pps_ambiguous += int((~ok).sum())
        c.pps_recovered += int(ok.sum())
        good = ok & (block["quality"] != 0)
        c.invalid_quality += int((ok & ~good).sum())
        if good.any():
            yield {k: v[good] for k, v in block.items()}

    def measurements(self, block: np.ndarray, offset: int):
        cols = decode_measurements(block)
        n = len(block)
        c = self.counters
        c.measurements += n
        if self.pps_time is None:
            c.before_first_pps += n
            return
        us = cols.pop("offset_us")
        running = np.maximum.accumulate(np.concatenate(([self.top], us)))
        fell = us < running[:-1]  # the counter wrapped (or the stream is disordered)
        undatable = np.logical_or.accumulate(fell | (us >= 0xFFFFFF)) | self.wrapped
        self.wrapped = bool(undatable[-1])
        self.top = int(running[-1])
        late = us >= 1_000_000
        c.missed_pps += int((late | undatable).sum())
        c.pps_ambiguous += int(undatable.sum())
        cols["time"] = self.pps_time + us * 1e-6
        cols["recovered"] = late
        cols["byte"] = offset + np.arange(n) * MEASUREMENT
        on_time = ~late & ~undatable
        bad = on_time & (cols["quality"] == 0)
        c.invalid_quality += int(bad.sum())
        keep = on_time & ~bad
        if keep.any():
            yield {k: v[keep] for k, v in cols.items()}
        held = late & ~undatable
        if held.any():
            self.held.append({k: v[held] for k, v in cols.items()})


def write_lmsq(path: Path, model: int, records: list) -> None:
    """Write a stream from ``("pps", sow, week)`` and ``("m", range_m, amplitude, angle_deg,
    quality, echo, offset_us, (r, g, b))`` tuples (tests and the simulator)."""
    out = bytearray(b"LMSQ" + np.array([1, model], "<u2").tobytes() + bytes(8))
    for rec in records:
        if rec[0] == "pps":
            out += bytes([2]) + np.float64(rec[1]).tobytes() + np.uint16(rec[2]).tobytes()
            continue
        _, rng, amp, angle, quality, echo, offset_us, rgb = rec
        mm = int(round(rng * 1000))
        a = int(round(angle * 1e4)) & 0xFFFFFF
        out += bytes([1]) + mm.to_bytes(3, "little") + bytes([amp]) + a.to_bytes(3, "little")
        out += bytes([(quality & 0x3F) | (echo << 6)]) + int(offset_us).to_bytes(3, "little")
        out += np.array(rgb, "<u2").tobytes()
    Path(path).write_bytes(bytes(out))


def first_pps_week(path: Path, *, chunk_bytes: int = 1 << 22) -> int | None:
    """The GPS week of the stream's first PPS record (None when it has none before a corrupt record)."""
    read_header(path)
    with open(path, "rb") as fh:
        fh.seek(HEADER)
        buf = b""
        while True:
            more = fh.read(chunk_bytes)
            buf += more
            arr = np.frombuffer(buf, np.uint8)
            pos = 0
            while pos < len(arr):
                if arr[pos] == 2:
                    if len(arr) - pos < PPS:
                        break
                    return int(np.frombuffer(buf, "<u2", 1, pos + 9)[0])
                if arr[pos] != 1:
                    return None
                k = (len(arr) - pos) // MEASUREMENT
                types = arr[pos : pos + k * MEASUREMENT : MEASUREMENT]
                stop = np.flatnonzero(types != 1)
                if not len(stop):
                    pos += k * MEASUREMENT
                    break
                pos += int(stop[0]) * MEASUREMENT
            if not more:
                return None
            buf = buf[pos:]
