"""Sensor presets of the two seeds, and the pulse patterns of the scanners.

Pulse directions are unit vectors in the scanner's own frame:

- LD-MRS (seed 0): x along the optical axis, y left, z up; four layers
  0.8 degrees apart (+-0.4, +-1.2), horizontal angle alpha:
  ``(cos l cos a, cos l sin a, sin l)``.  All points of a scan share the
  scan's time (the format has one time per scan).
- RIEGL line scanners (seed 2, SPEC 3.B): x forward, y starboard, z down;
  mirror angle theta (0 = nadir, positive to starboard): ``(0, sin t,
  cos t)``; a saw-tooth sweep (rotating polygon mirror).  Times are on the
  microsecond grid and angles on the 1e-4 degree grid of the ``.lmsq``
  format, so what is written is what was simulated.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from commands.budget.model import load_catalogue
from commands.simulate.settings import NavigationConfig, ScannerConfig

#: Seed 0: the SICK LD-MRS.  Range noise: the data sheet's 10 cm is
#: statistical (1 sigma) error; layers and steps as configured there.
LDMRS = {
    "scan_rate_hz": 12.5,
    "half_angle_deg": 40.0,
    "range_noise_m": 0.05,
    "max_range_m": 200.0,
    "layers_deg": (-1.2, -0.4, 0.4, 1.2),
}
#: Seed 0: the Xsens MTi-G (data sheet: 2.5 m CEP position, 0.5 deg roll/pitch, 1 deg heading).
MTIG = {"position_noise_m": 2.5, "attitude_noise_deg": 0.5}
RIEGL = {"q140": "LMS-Q140i", "q280": "LMS-Q280"}
INS = {
    "igg": ("IGg", "ProPack-G2"),
    "novatel-bds": ("Novatel-BDS", "BDS-GPS"),
    "pos-av-310": ("POS-AV-310", "POS-AV-GPS"),
    "pos-av-410": ("POS-AV-410", "POS-AV-GPS"),
    "pos-av-510": ("POS-AV-510", "POS-AV-GPS"),
}


@dataclass
class Scanner:
    kind: str  # "ldmrs" | "line"
    model: int  # .lmsq header model (140, 280); 0 for the LD-MRS
    pulse_rate_hz: float
    scan_rate_hz: float
    half_angle_deg: float
    range_noise_m: float
    max_range_m: float
    angle_step_deg: float = 0.5
    layers_deg: tuple[float, ...] = ()

    def pattern(self, t0: float, t1: float) -> dict[str, np.ndarray]:
        """Pulses with t0 <= time < t1 (seconds from the flight's start): time, direction, channel, angle, scan."""
        if self.kind == "ldmrs":
            period = 1.0 / self.scan_rate_hz
            k = np.arange(np.ceil(t0 / period - 1e-9), np.ceil(t1 / period - 1e-9)).astype(np.int64)
            alpha = np.arange(-self.half_angle_deg, self.half_angle_deg + 1e-9, self.angle_step_deg)
            layers = np.asarray(self.layers_deg)
            per = len(alpha) * len(layers)
            scan = np.repeat(k, per)
            a = np.tile(np.tile(alpha, len(layers)), len(k))
            ch = np.tile(np.repeat(np.arange(len(layers)), len(alpha)), len(k))
            lr, ar = np.radians(layers[ch]), np.radians(a)
            d = np.column_stack((np.cos(lr) * np.cos(ar), np.cos(lr) * np.sin(ar), np.sin(lr)))
            return {"t": scan * period, "dir": d, "channel": ch.astype(np.uint8), "angle": a, "scan": scan}
        period_us = int(round(1e6 / self.pulse_rate_hz))
        k = np.arange(int(np.ceil(t0 * 1e6 / period_us)), int(np.ceil(t1 * 1e6 / period_us)), dtype=np.int64)
        us = k * period_us
        t = us * 1e-6
        phase = (us % int(round(1e6 / self.scan_rate_hz))) / (1e6 / self.scan_rate_hz)
        theta = np.round((-self.half_angle_deg + 2 * self.half_angle_deg * phase) * 1e4) / 1e4
        th = np.radians(theta)
        d = np.column_stack((np.zeros_like(th), np.sin(th), np.cos(th)))
        return {"t": t, "dir": d, "channel": np.zeros(len(t), np.uint8), "angle": theta, "scan": k}


def make_scanner(cfg: ScannerConfig) -> Scanner:
    """The configured scanner: preset values, overridden by any key set in the config."""
    if cfg.preset == "ldmrs":
        base = dict(LDMRS, kind="ldmrs", model=0, pulse_rate_hz=0.0)
    else:
        spec = load_catalogue(None).scanners[RIEGL[cfg.preset]]
        base = {
            "kind": "line",
            "model": 140 if cfg.preset == "q140" else 280,
            "pulse_rate_hz": float(spec.pulse_rate_hz),
            "scan_rate_hz": 40.0,
            "half_angle_deg": float(spec.half_scan_angle_deg),
            "range_noise_m": float(spec.range_precision_m),
            "max_range_m": float(spec.max_range_m),
        }
    for key in ("pulse_rate_hz", "scan_rate_hz", "half_angle_deg", "range_noise_m", "max_range_m"):
        value = getattr(cfg, key)
        if value is not None:
            base[key] = float(value)
    base["angle_step_deg"] = cfg.angle_step_deg
    return Scanner(**base)


def navigation_sigmas(cfg: NavigationConfig) -> tuple[float, float]:
    """(position sigma m, attitude sigma deg) of the configured navigation system."""
    if cfg.preset == "mtig":
        pos, att = MTIG["position_noise_m"], MTIG["attitude_noise_deg"]
    else:
        cat = load_catalogue(None)
        ins, gps = INS[cfg.preset]
        pos, att = float(cat.gps[gps].accuracy_m), float(cat.ins[ins].attitude_deg)
    if cfg.position_noise_m is not None:
        pos = cfg.position_noise_m
    if cfg.attitude_noise_deg is not None:
        att = cfg.attitude_noise_deg
    return pos, att
