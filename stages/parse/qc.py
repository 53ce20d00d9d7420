"""The ``qc/`` files of the raw formats and the figures they hold.

``debug.txt``: every counter, the input size and the first problems with
their locations; ``lla_eul_vel.csv``: the trajectory as text; for 3.A also
``scans.txt``, the numbers of the scans that gave pulses (the seed's files).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from stages.parse.read_ins import TrajectoryCounters
from stages.parse.read_ldmrs import Counters, Scan
from stages.parse.read_lmsq import LmsqCounters

LDMRS_CSV_HEADER = "scan,time_gps,lat_deg,lon_deg,h_m,roll_deg,pitch_deg,yaw_deg,vx_ms,vy_ms,vz_ms\n"


def write_debug(qc: Path, figures: dict, locations: list[str], size: int) -> None:
    """``qc/debug.txt``: every counter, the input size, the first problems with their locations."""
    lines = [f"{k} {v}" for k, v in figures.items()]
    lines += ["", f"input bytes {size}", "first problems:" if locations else "problems: none"]
    lines += [f"  {where}" for where in locations]
    (qc / "debug.txt").write_text("\n".join(lines) + "\n", encoding="utf-8")


def write_trajectory_csv(path: Path, traj: dict[str, np.ndarray]) -> None:
    """``lla_eul_vel.csv`` of 3.B and 3.C: the trajectory's columns, named in the first line."""
    names = list(traj)
    table = np.column_stack([traj[n] for n in names])
    fmt = ["%.6f", "%.10f", "%.10f", "%.4f"] + ["%.7f"] * (len(names) - 4)
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(names) + "\n")
        np.savetxt(fh, table, fmt=fmt, delimiter=",")


class ScanQc:
    """``qc/scans.txt`` and ``qc/lla_eul_vel.csv`` of an LD-MRS survey (3.A), written scan by scan."""

    def __init__(self, qc: Path):
        self.qc = qc

    def __enter__(self) -> ScanQc:
        self.scans_txt = open(self.qc / "scans.txt", "w", encoding="utf-8")
        self.lla_csv = open(self.qc / "lla_eul_vel.csv", "w", encoding="utf-8")
        self.lla_csv.write(LDMRS_CSV_HEADER)
        return self

    def __exit__(self, *exc) -> None:
        self.lla_csv.close()
        self.scans_txt.close()

    def write(self, scan: Scan) -> None:
        """One scan's pose in the CSV; its number in ``scans.txt`` when it has valid points."""
        lat, lon, h = scan.lla
        roll, pitch, yaw = scan.euler
        vx, vy, vz = scan.vel
        self.lla_csv.write(
            f"{scan.number},{scan.time_gps:.6f},{lat:.10f},{lon:.10f},{h:.4f},"
            f"{roll:.7f},{pitch:.7f},{yaw:.7f},{vx:.3f},{vy:.3f},{vz:.3f}\n"
        )
        if len(scan.points):
            self.scans_txt.write(f"{scan.number}\n")


def ldmrs_figures(counters: Counters) -> dict:
    """The LD-MRS reader's counters as figures."""
    return {k: v for k, v in vars(counters).items() if k != "locations"}


def lmsq_figures(counters: LmsqCounters, pulses: int, navigation: TrajectoryCounters, extra: dict, epochs: int) -> dict:
    """The figures of an .lmsq survey: scanner counters, pulses kept, navigation counters and figures."""
    figures = {f"scanner_{k}": v for k, v in vars(counters).items()}
    figures["pulses_read"] = pulses
    figures.update({f"navigation_{k}": v for k, v in vars(navigation).items() if k != "locations"})
    figures.update(extra)
    figures["trajectory_epochs"] = epochs
    return figures
