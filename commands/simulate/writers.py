"""Writers of the raw formats (SPEC 3.A-3.C), vectorised, for the simulator and the tests."""

from __future__ import annotations

import gzip
import io
from datetime import UTC, datetime, timedelta
from pathlib import Path

import numpy as np

from commands.simulate.reference import GPS_EPOCH, nmea_sentence

SECONDS_PER_WEEK = 604_800.0


def create_text(path: Path):
    """A new text file to write, gzip by the suffix (``.gz``); reading is ``stages.parse.skiplog.open_text``."""
    path = Path(path)
    if path.suffix == ".gz":
        # mtime=0: the same content gives the same bytes (reproducible samples)
        return io.TextIOWrapper(gzip.GzipFile(path, "wb", mtime=0), encoding="ascii", newline="\n")
    return open(path, "w", encoding="ascii", newline="\n")


def gps_to_utc(gps: float, leap_seconds: float) -> datetime:
    return GPS_EPOCH + timedelta(seconds=gps - leap_seconds)


class LmsqWriter:
    """Appends measurement blocks to an ``.lmsq`` stream, with a PPS record at each new second.

    ``skip_pps``: GPS seconds whose PPS record is left out (the PPS-gap
    fault); their measurements then carry offsets of 1 s or more from the
    last PPS written, as a real stream does after a missed PPS (the uint24
    counter saturates at 0xFFFFFF us, 16.78 s: beyond, a time is lost).
    ``skipped_measurements`` counts the measurements written after a missed
    PPS, ``recoverable`` those of them the counter still dates.
    """

    def __init__(self, path: Path, model: int, skip_pps: set[int] | None = None):
        self.fh = open(path, "wb")  # noqa: SIM115 - closed in close()
        self.fh.write(b"LMSQ" + np.array([1, model], "<u2").tobytes() + bytes(8))
        self.skip = skip_pps or set()
        self.last_pps: int | None = None
        self.current: int | None = None
        self.skipped_measurements = 0
        self.recoverable = 0

    def add(self, gps_us: np.ndarray, range_m, amplitude, angle_deg, quality, echo) -> None:
        """Measurements in time order; ``gps_us``: integer microseconds since the GPS epoch."""
        second = gps_us // 1_000_000
        bounds = np.flatnonzero(np.diff(second)) + 1
        starts = np.concatenate(([0], bounds))
        stops = np.concatenate((bounds, [len(second)]))
        for a, b in zip(starts, stops, strict=True):
            s = int(second[a])
            if s != self.current:
                self.current = s
                if s in self.skip:
                    pass
                else:
                    sow = float(s % int(SECONDS_PER_WEEK))
                    week = s // int(SECONDS_PER_WEEK)
                    self.fh.write(bytes([2]) + np.float64(sow).tobytes() + np.uint16(week).tobytes())
                    self.last_pps = s
            if self.last_pps is None:
                continue
            offset = np.minimum(gps_us[a:b] - self.last_pps * 1_000_000, 0xFFFFFF)
            if s in self.skip or int(offset[-1]) >= 1_000_000:
                self.skipped_measurements += int(b - a)
                self.recoverable += int(np.sum(offset < 0xFFFFFF))
            self.fh.write(
                encode_measurements(
                    range_m[a:b], amplitude[a:b], angle_deg[a:b], quality[a:b], echo[a:b], offset
                ).tobytes()
            )

    def close(self) -> None:
        self.fh.close()


def encode_measurements(range_m, amplitude, angle_deg, quality, echo, offset_us) -> np.ndarray:
    """(n, 18) uint8 type-1 records."""
    n = len(range_m)
    rec = np.zeros((n, 18), np.uint8)
    rec[:, 0] = 1
    mm = np.clip(np.round(np.asarray(range_m) * 1000), 0, 0xFFFFFF).astype(np.int64)
    ang = np.round(np.asarray(angle_deg) * 1e4).astype(np.int64) & 0xFFFFFF
    off = np.asarray(offset_us, np.int64)
    for col, val in ((1, mm), (5, ang), (9, off)):
        rec[:, col] = val & 0xFF
        rec[:, col + 1] = (val >> 8) & 0xFF
        rec[:, col + 2] = (val >> 16) & 0xFF
    rec[:, 4] = amplitude
    rec[:, 8] = (np.asarray(quality, np.int64) & 0x3F) | (np.asarray(echo, np.int64) << 6)
    return rec


def _dm(value: float, width: int, pos: str, neg: str, decimals: int = 8) -> tuple[str, str]:
    hemi = pos if value >= 0 else neg
    v = abs(value)
    d = int(v)
    m = (v - d) * 60.0
    if round(m, decimals) >= 60.0:
        d, m = d + 1, 0.0
    return f"{d:0{width}d}{m:0{3 + decimals}.{decimals}f}", hemi


def write_nmea(
    path: Path,
    gps: np.ndarray,
    lat: np.ndarray,
    lon: np.ndarray,
    h: np.ndarray,
    heading_deg: np.ndarray,
    course_deg: np.ndarray,
    speed_ms: np.ndarray,
    sigma_m: np.ndarray,
    *,
    leap_seconds: float,
    separation_m: float = 50.0,
    corrupt: set[int] | None = None,
) -> int:
    """An ``$IN`` NMEA log: ZDA at each new second, then GGA, HDT, VTG, GST per epoch.

    Latitude and longitude carry 8 decimals of minutes (0.02 mm; receivers
    write 4-7, the reader takes any), heights 4 decimals.  ``corrupt``:
    indices of sentences whose checksum is broken.  Returns the number of
    sentences written.
    """
    corrupt = corrupt or set()
    k = 0
    last_second = None
    with create_text(path) as fh:
        data = 0  # index among the sentences that may be corrupted (not ZDA)

        def put(body: str) -> None:
            nonlocal k, data
            s = nmea_sentence(body)
            if not body.startswith("INZDA"):
                if data in corrupt:
                    s = s[:-2] + ("00" if s[-2:] != "00" else "01")
                data += 1
            fh.write(s + "\r\n")
            k += 1

        for i in range(len(gps)):
            utc = gps_to_utc(float(gps[i]), leap_seconds)
            sec = int(np.floor(gps[i]))
            if sec != last_second:
                last_second = sec
                put(f"INZDA,{utc:%H%M%S}.000,{utc.day:02d},{utc.month:02d},{utc.year:04d},00,00")
            tod = f"{utc:%H%M%S}.{utc.microsecond // 1000:03d}"
            la, ns = _dm(float(lat[i]), 2, "N", "S")
            lo, ew = _dm(float(lon[i]), 3, "E", "W")
            msl = float(h[i]) - separation_m
            put(f"INGGA,{tod},{la},{ns},{lo},{ew},4,12,0.8,{msl:.4f},M,{separation_m:.4f},M,1.0,0001")
            put(f"INHDT,{float(heading_deg[i]) % 360.0:.4f},T")
            knots = float(speed_ms[i]) * 3600.0 / 1852.0
            put(f"INVTG,{float(course_deg[i]) % 360.0:.4f},T,,M,{knots:.4f},N,{knots * 1.852:.4f},K,D")
            s = float(sigma_m[i])
            put(f"INGST,{tod},{s:.4f},{s:.4f},{s:.4f},0.0,{s:.4f},{s:.4f},{s:.4f}")
    return k


def wrap_pi(angle: np.ndarray) -> np.ndarray:
    """Radians in (-pi, pi], as an Applanix SBET writes its angles."""
    return -(np.mod(-np.asarray(angle, dtype=np.float64) + np.pi, 2 * np.pi) - np.pi)


def write_ins_csv(
    path: Path, sow: np.ndarray, roll: np.ndarray, pitch: np.ndarray, heading: np.ndarray, *, unwrapped: bool = False
) -> None:
    """``gps_sow,roll_deg,pitch_deg,heading_deg`` (NED, heading clockwise from north, in [0, 360); with
    *unwrapped*, as given: continuous through north)."""
    table = np.column_stack((sow, roll, pitch, heading if unwrapped else np.mod(heading, 360.0)))
    with create_text(path) as fh:
        fh.write("gps_sow,roll_deg,pitch_deg,heading_deg\n")
        np.savetxt(fh, table, fmt=["%.6f", "%.9f", "%.9f", "%.9f"], delimiter=",")


def write_sbet(path: Path, columns: np.ndarray) -> None:
    """SBET: (n, 17) float64 records, little-endian."""
    np.ascontiguousarray(columns, dtype="<f8").tofile(path)


def utc_iso(gps: float, leap_seconds: float) -> str:
    t = gps_to_utc(gps, leap_seconds)
    return t.astimezone(UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")
