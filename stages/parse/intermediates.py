"""The trajectory and pulses the raw formats become: schemas, conventions, and the rows of a scan or block.

Both are folders of ``.npy`` columns (:class:`lidar.columns.NpyColumns`)
whose ``meta.json`` states the conventions (time system, attitude frame,
mounting) that the ``georeference`` stage reads.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lidar.columns import NpyColumns
from lidar.rotation import euler_matrix, rot_y
from stages.parse.params import LdmrsInput, LmsqNmeaInput, LmsqSbetInput
from stages.parse.read_ldmrs import MOUNTINGS, Scan

#: The trajectory of 3.A: the scan's pose, velocity and MTi-G status.
LDMRS_TRAJECTORY_SCHEMA = {
    "time": "f8",
    "lat": "f8",
    "lon": "f8",
    "h": "f8",
    "roll": "f8",
    "pitch": "f8",
    "yaw": "f8",
    "scan": "u2",
    "vx": "f8",
    "vy": "f8",
    "vz": "f8",
    "status": "u1",
}
#: ``flags`` bit of an .lmsq measurement dated from the us counter after a missed PPS
RECOVERED_FLAG = 0x80
#: The pulses of every raw format.
PULSES_SCHEMA = {
    "time": "f8",
    "x": "f8",
    "y": "f8",
    "z": "f8",
    "echo": "u1",
    "channel": "u1",
    "angle": "f8",
    "amplitude": "u1",
    "flags": "u1",
    "scan": "u2",
}


def ldmrs_conventions(p: LdmrsInput) -> tuple[dict, dict]:
    """The ``meta.json`` of the trajectory and of the pulses of an LD-MRS survey (3.A)."""
    lever = MOUNTINGS[p.mounting] if isinstance(p.mounting, str) else p.mounting.lever_arm_m
    conventions = {
        "format": p.format,
        "time": "GPS seconds since 1980-01-06 (UTC + leap_seconds)",
        "leap_seconds": p.leap_seconds,
    }
    trajectory_meta = {
        **conventions,
        "convention": "NWU",
        "position": "WGS 84 latitude, longitude (deg), ellipsoidal height (m)",
        "attitude": "MTi-G body (x forward, y left, z up) vs local-level NWU: R = Rz(yaw) Ry(pitch) Rx(roll), "
        "degrees, yaw counter-clockwise from north",
        "velocity": "body frame, m/s",
    }
    pulses_meta = {
        **conventions,
        "frame": "LD-MRS: x optical axis, y left, z up; metres",
        "mounting": p.mounting if isinstance(p.mounting, str) else "custom",
        "rotation": rot_y(np.pi / 2).round(15).tolist(),
        "lever_arm": list(lever),
        "body_axes": "MTi-G: x forward, y left, z up",
    }
    return trajectory_meta, pulses_meta


def lmsq_conventions(p: LmsqNmeaInput | LmsqSbetInput, week: int) -> tuple[dict, dict]:
    """The ``meta.json`` of the trajectory and of the pulses of an .lmsq survey (3.B, 3.C)."""
    conventions = {"format": p.format, "time": "GPS seconds since 1980-01-06", "gps_week": week}
    trajectory_meta = {
        **conventions,
        "convention": "NED",
        "position": "WGS 84 latitude, longitude (deg), ellipsoidal height (m)",
        "attitude": "body (x forward, y right, z down) vs local-level NED: R = Rz(yaw) Ry(pitch) Rx(roll), degrees, "
        "yaw = true heading, clockwise from north",
    }
    pulses_meta = {
        **conventions,
        "frame": "scanner: x forward, y starboard, z down; a pulse at mirror angle t is range x (0, sin t, cos t)",
        "rotation": euler_matrix(*np.radians(p.boresight_deg)).tolist(),
        "boresight_deg": list(p.boresight_deg),
        "lever_arm": list(p.lever_arm_m),
        "body_axes": "x forward, y right, z down",
        "flags": "bits 0-5: the measurement's quality; bit 7 (0x80): time recovered from the us counter "
        "after a missed PPS",
    }
    return trajectory_meta, pulses_meta


def write_trajectory(folder: Path, trajectory: dict[str, np.ndarray], meta: dict) -> None:
    """Write a whole trajectory (every column float64) as ``.npy`` columns with its ``meta.json``."""
    schema = {name: "f8" for name in trajectory}
    with NpyColumns(folder, schema, meta) as columns:
        columns.append(**trajectory)


def scan_pose(scan: Scan) -> dict[str, list]:
    """The trajectory row of one LD-MRS scan (:data:`LDMRS_TRAJECTORY_SCHEMA`)."""
    lat, lon, h = scan.lla
    roll, pitch, yaw = scan.euler
    vx, vy, vz = scan.vel
    return {
        "scan": [scan.number],
        "time": [scan.time_gps],
        "lat": [lat],
        "lon": [lon],
        "h": [h],
        "roll": [roll],
        "pitch": [pitch],
        "yaw": [yaw],
        "vx": [vx],
        "vy": [vy],
        "vz": [vz],
        "status": [scan.status],
    }


def scan_pulses(scan: Scan) -> dict[str, np.ndarray]:
    """The pulses of one LD-MRS scan's valid points (:data:`PULSES_SCHEMA`; the angle from x and y)."""
    pts = scan.points
    n = len(pts)
    return {
        "time": np.full(n, scan.time_gps),
        "x": pts[:, 3],
        "y": pts[:, 4],
        "z": pts[:, 5],
        "echo": pts[:, 1],
        "channel": pts[:, 0],
        "angle": np.degrees(np.arctan2(pts[:, 4], pts[:, 3])),
        "amplitude": np.zeros(n),
        "flags": pts[:, 2],
        "scan": np.full(n, scan.number),
    }


def lmsq_pulses(block: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The pulses of a block of .lmsq measurements: range x (0, sin t, cos t) at mirror angle t."""
    th = np.radians(block["angle_deg"])
    r = block["range_m"]
    n = len(r)
    return {
        "time": block["time"],
        "x": np.zeros(n),
        "y": r * np.sin(th),
        "z": r * np.cos(th),
        "echo": block["echo"],
        "channel": np.zeros(n),
        "angle": block["angle_deg"],
        "amplitude": block["amplitude"],
        "flags": block["quality"] | np.where(block["recovered"], RECOVERED_FLAG, 0).astype(np.uint8),
        "scan": np.zeros(n),
    }
