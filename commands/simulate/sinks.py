"""Where the echoes go, chunk by chunk: the truth, the 3.D LAS, the 3.A log and the 3.B/3.C scanner stream.

Each writer marks the echoes its faults touch (``FAULT_CODES``) and counts
what it wrote, for ``truth/faults.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np

from commands.simulate import scene as sc
from commands.simulate.faults import FAULT_CODES, FaultPlan
from commands.simulate.flight import DT, Flight
from commands.simulate.forward import D_FLIP, MapProjection, RecordedPose, attitude
from commands.simulate.navigation import Navigation
from commands.simulate.sensors import Scanner
from commands.simulate.settings import SimulateConfig
from commands.simulate.writers import LmsqWriter, create_text, utc_iso
from lidar.clouds import point_header

if TYPE_CHECKING:
    import pyproj

P_LINE = "P {} {} 0x{:02x} {:.4f} {:.4f} {:.4f}"


class LasSink:
    """A LAZ written chunk by chunk (laspy + lazrs), LAS 1.4 point format 6, 0.1 mm scale."""

    def __init__(self, path: Path, crs: pyproj.CRS, to_map: MapProjection, *, extra_fault: bool = False):
        self.path, self.crs, self.to_map, self.extra_fault = path, crs, to_map, extra_fault
        self.writer = None

    def add(
        self, xyz: np.ndarray, *, classification: np.ndarray, fault: np.ndarray | None = None, **cols: np.ndarray
    ) -> None:
        """Points at local ENU *xyz*, with their classes, their ``fault`` codes (the truth) and columns *cols*."""
        if len(xyz) == 0:
            return
        pts = self.to_map(xyz)  # local ENU -> output CRS
        if self.writer is None:
            self._open(pts)
        rec = laspy.ScaleAwarePointRecord.zeros(len(pts), header=self.header)
        rec.x, rec.y, rec.z = pts[:, 0], pts[:, 1], pts[:, 2]
        rec.gps_time = cols["gps_time"] - 1e9  # adjusted standard GPS time (LAS 1.4)
        rec.return_number = cols["return_number"]
        rec.number_of_returns = cols["number_of_returns"]
        rec.scan_angle = np.round(np.asarray(cols["scan_angle"]) / 0.006).astype(np.int16)
        rec.scanner_channel = cols["scanner_channel"]
        rec.point_source_id = cols["point_source_id"]
        rec.classification = classification
        if self.extra_fault:
            rec.fault = fault
        self.writer.write_points(rec)

    def _open(self, pts: np.ndarray) -> None:
        """The file, its header made for the first chunk's points (*pts*, output CRS)."""
        # later chunks lie elsewhere in the survey: a kilometre of margin below, and the scale
        # chosen for 200 km around the first chunk
        lo = pts.min(axis=0) - np.array([0.0, 0.0, 1000.0])
        header = point_header(self.crs, lo, pts.max(axis=0))
        if self.extra_fault:
            why = laspy.ExtraBytesParams(name="fault", type=np.uint8, description="simulator: why a reader drops it")
            header.add_extra_dim(why)
        header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
        self.writer = laspy.open(
            self.path, mode="w", header=header, do_compress=True, laz_backend=laspy.LazBackend.Lazrs
        )
        self.header = header

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


@dataclass
class _ScanChunk:
    """The echoes of one chunk as the 3.A log writes them, and their fault codes (updated in place)."""

    channel: np.ndarray
    echo: np.ndarray
    v_s: np.ndarray  # scanner-frame vectors (n, 3)
    fault: np.ndarray
    rng: np.random.Generator  # dirt and clutter


class LdmrsLog:
    """The 3.A acquisition log: one record per LD-MRS scan with the MTi-G's state, and the scan faults."""

    def __init__(
        self,
        path: Path,
        cfg: SimulateConfig,
        scanner: Scanner,
        plan: FaultPlan,
        start: float,
        nav: Navigation,
        flight: Flight,
    ):
        self.plan, self.start, self.nav, self.flight = plan, start, nav, flight
        self.seed, self.leap = cfg.seed, cfg.leap_seconds
        self.period = 1.0 / scanner.scan_rate_hz
        self.fh = create_text(path)
        date = cfg.start_utc[:10]
        self.fh.write(
            f"# LDMRS-MTIG acquisition log v1\n# date: {date}\n# simulated by pipeline simulate, seed {cfg.seed}\n"
        )
        self.counts = {
            "scans_written": 0,
            "invalid_scans": 0,
            "bad_gps": 0,
            "lost_scans": 0,
            "empty_scans": 0,
            "rejected_clutter": 0,
            "rejected_dirt": 0,
        }
        self.dirt_left = plan.dirt_count

    def add(self, pat: dict, e: dict, v_s: np.ndarray, fault: np.ndarray) -> np.ndarray:
        """Write the scans of one chunk; which echoes were recorded (the truth keeps only those)."""
        plan = self.plan
        keep = np.ones(len(e["pulse"]), bool)
        scan_of_echo = pat["scan"][e["pulse"]]
        scans = np.unique(pat["scan"])
        chunk = _ScanChunk(pat["channel"][e["pulse"]], e["echo"], v_s, fault, np.random.default_rng(self.seed + 7))
        bounds = np.searchsorted(scan_of_echo, scans), np.searchsorted(scan_of_echo, scans, side="right")
        for s, a, b in zip(scans, *bounds, strict=True):
            s = int(s)
            if s in plan.lost_scans:
                keep[a:b] = False  # never recorded: not in the truth either
                self.counts["lost_scans"] += 1
                continue
            self.counts["scans_written"] += 1
            valid, status, utc = self._status(s, a, b, fault)
            accepted = s not in plan.invalid_scans and s not in plan.bad_gps_scans  # as the reader will judge
            points = []
            if s in plan.empty_scans:
                keep[a:b] = False
            else:
                points = self._points(s, a, b, chunk, accepted)
            valid_points = (b - a) - int(np.sum(fault[a:b] == FAULT_CODES["dirt"]))
            if accepted and (s in plan.empty_scans or valid_points <= 0):
                self.counts["empty_scans"] += 1
            self._write_scan(s, valid, status, utc, points)
        return keep

    def _status(self, s: int, a: int, b: int, fault: np.ndarray) -> tuple[int, int, str]:
        """VALID, STATUS and UTC of scan *s*, as its faults make them (its echoes a:b marked)."""
        valid, status, utc = 1, 0x07, utc_iso(self.start + s * self.period, self.leap)
        if s in self.plan.invalid_scans:
            self.counts["invalid_scans"] += 1
            if len(self.plan.invalid_scans) > 1 and s % 2:
                utc = utc[:11] + "25" + utc[13:]  # hour 25: unparseable
            else:
                valid = 0
            fault[a:b] = FAULT_CODES["invalid_scan"]
        elif s in self.plan.bad_gps_scans:
            self.counts["bad_gps"] += 1
            status = 0x01 if s % 2 else 0x05
            fault[a:b] = FAULT_CODES["bad_gps"]
        return valid, status, utc

    def _points(self, s: int, a: int, b: int, chunk: _ScanChunk, accepted: bool) -> list[str]:
        """The P lines of scan *s* (echoes a:b): a dirt flag on one point, then the clutter the scanner flags."""
        flags = np.zeros(b - a, np.int64)
        # dirt only in scans the reader accepts (an invalid or bad-GPS scan is skipped whole)
        if self.dirt_left and b > a and accepted:
            j = int(chunk.rng.integers(a, b))
            flags[j - a] = 0x08
            chunk.fault[j] = FAULT_CODES["dirt"]
            self.dirt_left -= 1
            self.counts["rejected_dirt"] += 1
        # plain Python numbers: formatting NumPy scalars one by one is several times slower
        columns = (chunk.channel[a:b].tolist(), chunk.echo[a:b].tolist(), flags.tolist(), *chunk.v_s[a:b].T.tolist())
        points = [P_LINE.format(*row) for row in zip(*columns, strict=True)]
        n_clutter = int(np.sum(self.plan.clutter_scans == s))
        for _ in range(n_clutter):  # dust seen by the scanner and flagged by it (not in the truth)
            rr = chunk.rng.uniform(1.0, 8.0)
            al = np.radians(chunk.rng.uniform(-30, 30))
            points.append(f"P {chunk.rng.integers(0, 4)} 0 0x02 {rr * np.cos(al):.4f} {rr * np.sin(al):.4f} 0.0000")
        if n_clutter and accepted:
            self.counts["rejected_clutter"] += n_clutter
        return points

    def _write_scan(self, s: int, valid: int, status: int, utc: str, points: list[str]) -> None:
        """One scan record: its header lines, the MTi-G's state, its points."""
        lat, lon, h, roll, pitch, yaw, vel = self._mtig_record(s * self.period)
        fh = self.fh
        fh.write(f"SCAN {s % 65536}\nUTC {utc}\nSTATUS 0x{status:02X}\nVALID {valid}\n")
        fh.write(f"LLA {lat:.10f} {lon:.10f} {h:.4f}\nEULER {roll:.7f} {pitch:.7f} {yaw:.7f}\n")
        fh.write(f"VEL {vel[0]:.3f} {vel[1]:.3f} {vel[2]:.3f}\nNPOINTS {len(points)}\n")
        if points:
            fh.write("\n".join(points) + "\n")
        fh.write("END\n")

    def _mtig_record(self, t_rel: float):
        """What the MTi-G reports at a scan: LLA, Euler angles in its NWU convention, body velocity."""
        i = int(round(t_rel / DT))
        nav = self.nav
        roll, pitch, heading = nav.roll[i], nav.pitch[i], nav.heading[i]
        yaw = -((heading + 180.0) % 360.0 - 180.0)  # counter-clockwise from north
        v_enu = self.flight.velocity(t_rel)
        v_ned = np.array([v_enu[1], v_enu[0], -v_enu[2]])
        v_frd = attitude(*np.radians([roll, pitch, heading])).inv().apply(v_ned)[0]
        return nav.lat[i], nav.lon[i], nav.h[i], roll, -pitch, yaw, D_FLIP @ v_frd

    def close(self) -> dict:
        self.fh.close()
        return self.counts


class LmsqStream:
    """The 3.B/3.C scanner stream (``scan.lmsq``), with the invalid-quality and missed-PPS faults."""

    def __init__(self, path: Path, scanner: Scanner, plan: FaultPlan, start: float):
        self.plan, self.start = plan, start
        skip = {int(start) + s for s in plan.pps_gaps}
        self.writer = LmsqWriter(path, scanner.model, skip)
        self.counts = {"invalid_quality": 0, "dust_echoes": 0}

    def add(self, pat: dict, e: dict, gps: np.ndarray, fault: np.ndarray) -> np.ndarray:
        """Write one chunk's echoes; their fault codes."""
        plan = self.plan
        n = len(e["pulse"])
        quality = np.full(n, 40, np.int64)
        bad = np.isin(e["pulse_id"], list(plan.invalid_pulses)) if plan.invalid_pulses else np.zeros(n, bool)
        quality[bad] = 0
        fault[bad] = FAULT_CODES["invalid_quality"]
        gps_us = np.round(gps * 1e6).astype(np.int64)
        second = gps_us // 1_000_000
        gap = np.isin(second - int(self.start), list(plan.pps_gaps)) if plan.pps_gaps else np.zeros(n, bool)
        fault[gap] = FAULT_CODES["pps_gap"]
        # what a reader sees: a measurement after a missed PPS is still dated by the us counter
        self.counts["invalid_quality"] += int(bad.sum())
        self.counts["dust_echoes"] += int((e["dust"] & ~bad).sum())
        amplitude = np.where(e["cls"] == sc.WATER, 20, np.where(e["cls"] == sc.VEGETATION, 90, 160))
        amplitude = (amplitude * (1 - 0.3 * e["echo"])).astype(np.uint8)
        self.writer.add(gps_us, e["range"], amplitude, pat["angle"][e["pulse"]], quality, e["echo"])
        return fault

    def close(self) -> dict:
        self.writer.close()
        return {
            **self.counts,
            "pps_gaps": len(self.plan.pps_gaps),
            "missed_pps": self.writer.skipped_measurements,
            "pps_recovered": self.writer.recoverable,
        }


class Sinks:
    """Streams every chunk of echoes to the formats' files and the truth; ``files``: what is written."""

    def __init__(
        self,
        cfg: SimulateConfig,
        out: Path,
        to_map: MapProjection,
        scanner: Scanner,
        plan: FaultPlan,
        start: float,
        nav: Navigation,
        flight: Flight,
    ):
        self.start, self.flight = start, flight
        crs = to_map.crs
        self.files: dict[str, str] = {}
        self.counts = {"pulses": 0, "echoes": 0, "echoes_by_class": {}}
        self.ground_on_lines: list[np.ndarray] = []  # local (e, n) of recorded ground echoes on the lines
        (out / "truth").mkdir(parents=True, exist_ok=True)
        self.truth = LasSink(out / "truth" / "points.laz", crs, to_map, extra_fault=True)
        self.files["truth_points"] = "truth/points.laz"
        self.las = self.ldmrs = self.lmsq = None
        if "las" in cfg.formats:
            (out / "las").mkdir(exist_ok=True)
            self.las = LasSink(out / "las" / "points.laz", crs, to_map)
            self.files["las"] = "las/points.laz"
        if "ldmrs_mtig" in cfg.formats:
            (out / "ldmrs").mkdir(exist_ok=True)
            self.ldmrs = LdmrsLog(out / "ldmrs" / "acquisition.log.gz", cfg, scanner, plan, start, nav, flight)
            self.files["ldmrs_mtig"] = "ldmrs/acquisition.log.gz"
        if cfg.writes_lmsq:
            (out / "lmsq").mkdir(exist_ok=True)
            self.lmsq = LmsqStream(out / "lmsq" / "scan.lmsq", scanner, plan, start)
            self.files["lmsq"] = "lmsq/scan.lmsq"

    def add(self, pat: dict, e: dict, nav_traj: RecordedPose, mounting_nominal: tuple) -> None:
        """One chunk: the pulses of *pat* and their echoes *e*; the 3.D LAS georeferenced by *nav_traj*."""
        n = len(e["pulse"])
        self._count(pat, e)
        p = e["pulse"]
        t_rel = pat["t"][p]
        gps = self.start + t_rel
        v_s = pat["dir"][p] * e["range"][:, None]
        fault = np.zeros(n, np.uint8)
        fault[e["dust"]] = FAULT_CODES["dust"]
        strip = self.flight.line_at(t_rel).astype(np.uint16)
        keep = np.ones(n, bool)
        if self.ldmrs is not None:
            keep = self.ldmrs.add(pat, e, v_s, fault)
        if self.lmsq is not None:
            fault = self.lmsq.add(pat, e, gps, fault)
        cols = {
            "gps_time": gps,
            "return_number": e["echo"] + 1,
            "number_of_returns": e["n"],
            "scan_angle": pat["angle"][p],
            "scanner_channel": pat["channel"][p],
            "point_source_id": strip,
        }
        sel = {k: v[keep] for k, v in cols.items()}
        self.truth.add(e["hit"][keep], classification=e["cls"][keep], fault=fault[keep], **sel)
        self.ground_on_lines.append(e["hit"][keep & (e["cls"] == sc.GROUND) & (strip > 0), :2])
        if self.las is not None:
            ok_for_las = keep & (fault != FAULT_CODES["invalid_quality"])  # after a missed PPS: dated by the counter
            # what the vendor's software wrote: the echoes georeferenced from the recorded navigation
            xyz = nav_traj.points(gps[ok_for_las], v_s[ok_for_las], *mounting_nominal)
            s2 = {k: v[ok_for_las] for k, v in cols.items()}
            self.las.add(xyz, classification=np.zeros(len(xyz), np.uint8), **s2)

    def _count(self, pat: dict, e: dict) -> None:
        """Pulses, echoes and echoes by class."""
        self.counts["pulses"] += len(pat["t"])
        self.counts["echoes"] += len(e["pulse"])
        for c, k in zip(*np.unique(e["cls"], return_counts=True), strict=True):
            name = sc.CLASS_NAMES[int(c)]
            self.counts["echoes_by_class"][name] = self.counts["echoes_by_class"].get(name, 0) + int(k)

    def close(self) -> dict:
        """Close every file; the counts for faults.json."""
        self.truth.close()
        if self.las is not None:
            self.las.close()
        result = dict(self.counts)
        if self.ldmrs is not None:
            result["ldmrs_mtig"] = self.ldmrs.close()
        if self.lmsq is not None:
            result["lmsq"] = self.lmsq.close()
        return result
