"""The faults the simulator injects: their codes in the truth, and which scans, pulses and seconds get them.

Every fault is chosen up front, before a pulse is cast, so the counts
written to ``truth/faults.json`` are exact.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from commands.simulate.flight import Flight, recorded
from commands.simulate.sensors import Scanner
from commands.simulate.settings import SimConfigError, SimulateConfig

#: truth/points.laz extra dimension ``fault``: why the reader will drop the echo (0: it will not)
FAULT_CODES = {
    "none": 0,
    "invalid_scan": 1,
    "bad_gps": 2,
    "clutter": 3,
    "dirt": 4,
    "pps_gap": 5,
    "invalid_quality": 6,
    "dust": 7,
}
#: seconds of flight whose pulses are made at a time
CHUNK_S = 2.0


@dataclass
class FaultPlan:
    """Which scans / pulses / seconds get which fault."""

    invalid_scans: set = field(default_factory=set)
    bad_gps_scans: set = field(default_factory=set)
    lost_scans: set = field(default_factory=set)
    empty_scans: set = field(default_factory=set)
    clutter_scans: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    dirt_count: int = 0
    dust_pulses: set = field(default_factory=set)
    invalid_pulses: set = field(default_factory=set)
    pps_gaps: set = field(default_factory=set)


def fault_plan(
    cfg: SimulateConfig, scanner: Scanner, flight: Flight, recording: np.ndarray, rng: np.random.Generator
) -> FaultPlan:
    """The faults of the survey: scan faults for the LD-MRS log (3.A), pulse and PPS faults for the RIEGL stream."""
    if scanner.kind == "ldmrs":
        return _scan_faults(cfg, scanner, flight, recording, rng)
    return _pulse_faults(cfg, scanner, flight, recording, rng)


def _scan_faults(
    cfg: SimulateConfig, scanner: Scanner, flight: Flight, recording: np.ndarray, rng: np.random.Generator
) -> FaultPlan:
    """Invalid, bad-GPS, lost and empty scans drawn among the recorded ones (never the first or the last)."""
    fl = cfg.faults
    plan = FaultPlan()
    period = 1.0 / scanner.scan_rate_hz
    scans = np.unique(np.ceil(flight.t[recording] / period - 1e-9).astype(np.int64))
    scans = scans[scans * period <= flight.duration]
    need = fl.invalid_utc_scans + fl.bad_gps_scans + fl.lost_scans + fl.empty_scans
    if need > len(scans) // 2:
        raise SimConfigError(f"{need} faulty scans asked for, but the flight records only {len(scans)} scans")
    pick = rng.choice(scans[1:-1], need, replace=False)
    a, b, c = fl.invalid_utc_scans, fl.bad_gps_scans, fl.lost_scans
    plan.invalid_scans = set(pick[:a].tolist())
    plan.bad_gps_scans = set(pick[a : a + b].tolist())
    plan.lost_scans = set(pick[a + b : a + b + c].tolist())
    plan.empty_scans = set(pick[a + b + c :].tolist())
    bad = plan.invalid_scans | plan.bad_gps_scans | plan.lost_scans | plan.empty_scans
    good = np.array(sorted(set(scans.tolist()) - bad))
    plan.clutter_scans = (
        np.sort(rng.choice(good, fl.clutter_points, replace=True)) if fl.clutter_points else plan.clutter_scans
    )
    plan.dirt_count = fl.dirt_points
    return plan


def _pulse_faults(
    cfg: SimulateConfig, scanner: Scanner, flight: Flight, recording: np.ndarray, rng: np.random.Generator
) -> FaultPlan:
    """Dust and invalid-quality pulses drawn by index among the recorded pulses; missed PPS seconds inside."""
    fl = cfg.faults
    plan = FaultPlan()
    # count the pulses to choose the faulty ones by index
    total = 0
    for t0 in np.arange(0.0, flight.duration, CHUNK_S):
        pat_t = scanner.pattern(t0, min(t0 + CHUNK_S, flight.duration))["t"]
        total += int(recorded(recording, pat_t).sum())
    if fl.dust_echoes + fl.invalid_quality > total // 10:
        raise SimConfigError(f"too many faulty pulses asked for ({total} pulses in the flight)")
    pick = rng.choice(total, fl.dust_echoes + fl.invalid_quality, replace=False)
    plan.dust_pulses = set(pick[: fl.dust_echoes].tolist())
    plan.invalid_pulses = set(pick[fl.dust_echoes :].tolist())
    seconds = np.unique(np.floor(flight.t[recording]).astype(np.int64))
    if fl.pps_gaps:
        interior = seconds[(seconds > seconds[0] + 1) & (seconds < seconds[-1] - 1)]
        plan.pps_gaps = set(rng.choice(interior, fl.pps_gaps, replace=False).tolist())
    return plan
