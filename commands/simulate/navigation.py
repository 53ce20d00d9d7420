"""The recorded navigation: the true trajectory plus its errors, and the files that carry it.

Errors are smooth and stationary (sums of random-phase cosines with the
system's sigma at every instant) plus a bias per flight line; the files are
NMEA and the INS CSV (3.B), the SBET and its smrmsg (3.C).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from commands.simulate.flight import DT, Flight
from commands.simulate.forward import Earth
from commands.simulate.settings import SimulateConfig
from commands.simulate.writers import SECONDS_PER_WEEK, wrap_pi, write_ins_csv, write_nmea, write_sbet


@dataclass
class Navigation:
    """Recorded navigation at every truth sample (200 Hz): what the INS/GNSS files say."""

    t: np.ndarray
    lat: np.ndarray
    lon: np.ndarray
    h: np.ndarray
    roll: np.ndarray  # degrees, NED
    pitch: np.ndarray
    heading: np.ndarray  # degrees, clockwise from north (unwrapped)
    sigma_pos: float
    sigma_att: float

    def select(self, sel: slice) -> Navigation:
        """The epochs *sel* of this navigation."""
        epochs = (getattr(self, k)[sel] for k in ("t", "lat", "lon", "h", "roll", "pitch", "heading"))
        return Navigation(*epochs, self.sigma_pos, self.sigma_att)


def every(rate_hz: float) -> int:
    """Truth samples (DT seconds) between two records at *rate_hz*."""
    return max(1, int(round(1.0 / (rate_hz * DT))))


def smooth_noise(t: np.ndarray, sigma: float, tau: float, rng: np.random.Generator, dims: int = 3) -> np.ndarray:
    """A smooth, stationary random error: per axis, a sum of 16 cosines of random phase with periods
    between *tau* and 5 *tau* seconds, scaled so its variance is *sigma*^2 at every instant (over
    realisations): what a navigation solution's slowly wandering error looks like, and what the
    propagated per-point sigma must match."""
    if sigma == 0:
        return np.zeros((len(t), dims))
    k = 16
    out = np.zeros((len(t), dims))
    for d in range(dims):
        freq = rng.uniform(1 / (5 * tau), 1 / tau, k)
        phase = rng.uniform(0, 2 * np.pi, k)
        out[:, d] = sigma * np.sqrt(2.0 / k) * np.cos(2 * np.pi * np.outer(t, freq) + phase).sum(axis=1)
    return out


def line_biases(flight: Flight, size: float, rng: np.random.Generator, spare: list[int] = ()) -> np.ndarray:
    """Per-line bias (uniform in +-size per axis; zero on the *spare* lines), blended linearly through the turns."""
    lines = int(flight.line.max())
    if size == 0 or lines == 0:
        return np.zeros((len(flight.t), 3))
    values = rng.uniform(-size, size, (lines, 3))
    for k in spare:
        if 1 <= k <= lines:
            values[k - 1] = 0.0
    # constant from the first to the last epoch of each line, linear in between
    knots_t = np.concatenate(
        [[flight.t[flight.line == k].min(), flight.t[flight.line == k].max()] for k in range(1, lines + 1)]
    )
    knots_v = np.repeat(values, 2, axis=0)
    return np.column_stack([np.interp(flight.t, knots_t, knots_v[:, j]) for j in range(3)])


def bias_table(flight: Flight, bias: np.ndarray) -> dict[str, list[float]]:
    """The mean bias of each line, by line number (for faults.json)."""
    table = {}
    for k in range(1, int(flight.line.max()) + 1):
        sel = flight.line == k
        table[str(k)] = [round(float(v), 6) for v in bias[sel].mean(axis=0)]
    return table


def recorded_navigation(
    cfg: SimulateConfig,
    frame: Earth,
    flight: Flight,
    sigmas: tuple[float, float],
    rng: np.random.Generator,
    noise_rng: np.random.Generator,
) -> tuple[Navigation, np.ndarray, np.ndarray]:
    """The navigation the files record: the true trajectory plus smooth noise of *sigmas* (position m,
    attitude deg) and the per-line biases, cut to whole GNSS epochs when NMEA or SBET files are written.

    Returns the navigation and the per-line position and attitude biases at every truth sample.
    """
    sigma_pos, sigma_att = sigmas
    bias = line_biases(flight, cfg.faults.strip_bias_m, rng, cfg.faults.error_free_lines)
    tau = cfg.navigation.error_period_s
    pos_err = smooth_noise(flight.t, sigma_pos, tau, noise_rng) + bias
    lat_r, lon_r, h_r = frame.geodetic(flight.pos + pos_err)
    # roll and pitch only: over a straight line they tilt and shift the strip rigidly; a heading bias
    # shears it (along-track shift growing across track), which no rigid strip correction can undo
    att_bias = line_biases(flight, cfg.faults.strip_rotation_deg, rng, cfg.faults.error_free_lines)
    att_bias[:, 2] = 0.0
    att_err = smooth_noise(flight.t, sigma_att, tau / 4, noise_rng) + att_bias
    roll = np.degrees(flight.roll) + att_err[:, 0]
    pitch = np.degrees(flight.pitch) + att_err[:, 1]
    heading = np.degrees(flight.heading) + att_err[:, 2]
    nav = Navigation(flight.t, lat_r, lon_r, h_r, roll, pitch, heading, sigma_pos, sigma_att)
    if cfg.writes_lmsq:
        # every navigation file spans the same time: from the first to the last GNSS epoch
        step = every(cfg.navigation.gnss_rate_hz)
        end = (len(nav.t) - 1) // step * step + 1
        nav = nav.select(slice(None, end))
    return nav, bias, att_bias


def write_navigation(cfg: SimulateConfig, out: Path, nav: Navigation, flight: Flight, start: float) -> dict[str, str]:
    """NMEA, INS CSV, SBET and smrmsg from the recorded navigation (only with the RIEGL formats)."""
    files = {}
    if cfg.writes_lmsq:
        gps = start + nav.t
        sow = np.mod(gps, SECONDS_PER_WEEK)
        vel = flight.velocity(nav.t)
        _write_nmea(cfg, out / "lmsq" / "nav.nmea", nav, gps, vel)
        ins = slice(0, None, every(cfg.navigation.ins_rate_hz))
        unwrapped = cfg.navigation.unwrapped_heading
        write_ins_csv(
            out / "lmsq" / "ins.csv", sow[ins], nav.roll[ins], nav.pitch[ins], nav.heading[ins], unwrapped=unwrapped
        )
        files.update(nmea="lmsq/nav.nmea", ins="lmsq/ins.csv")
        _write_sbet(out / "lmsq", nav.select(ins), sow[ins], vel[ins], unwrapped)
        files.update(sbet="lmsq/trajectory.sbet", smrmsg="lmsq/trajectory.smrmsg")
    return files


def _write_nmea(cfg: SimulateConfig, path: Path, nav: Navigation, gps: np.ndarray, vel: np.ndarray) -> None:
    """The GNSS log at ``gnss_rate_hz``; ``nmea_bad_checksums`` corrupts GGA/HDT/VTG/GST sentences (never
    ZDA: without a date the log cannot be read at all)."""
    sel = slice(0, None, every(cfg.navigation.gnss_rate_hz))
    course = np.degrees(np.arctan2(vel[:, 0], vel[:, 1]))
    speed = np.hypot(vel[:, 0], vel[:, 1])
    sigma = np.full(len(gps), max(nav.sigma_pos, 0.01))
    rng = np.random.default_rng(cfg.seed + 11)
    k = cfg.faults.nmea_bad_checksums
    corrupt = set(rng.choice(4 * len(gps[sel]), k, replace=False).tolist()) if k else set()
    write_nmea(
        path,
        gps[sel],
        nav.lat[sel],
        nav.lon[sel],
        nav.h[sel],
        nav.heading[sel],
        course[sel],
        speed[sel],
        sigma[sel],
        leap_seconds=cfg.leap_seconds,
        corrupt=corrupt,
    )


def _write_sbet(folder: Path, nav: Navigation, sow: np.ndarray, vel: np.ndarray, unwrapped: bool) -> None:
    """``trajectory.sbet`` and ``trajectory.smrmsg`` at the INS epochs of *nav*."""
    wander = np.radians(10.0) + 1e-4 * nav.t  # a wander azimuth that drifts, as a wander-azimuth INS does
    sbet = np.zeros((len(sow), 17))
    sbet[:, 0] = sow
    sbet[:, 1], sbet[:, 2], sbet[:, 3] = np.radians(nav.lat), np.radians(nav.lon), nav.h
    sbet[:, 4], sbet[:, 5], sbet[:, 6] = vel[:, 1], vel[:, 0], -vel[:, 2]
    sbet[:, 7], sbet[:, 8] = np.radians(nav.roll), np.radians(nav.pitch)
    sbet[:, 9] = np.radians(nav.heading) + wander  # platform heading = true heading + wander
    sbet[:, 10] = wander
    if not unwrapped:  # as an SBET holds them: (-pi, pi]
        sbet[:, 9:11] = wrap_pi(sbet[:, 9:11])
    write_sbet(folder / "trajectory.sbet", sbet)
    smr = np.zeros((len(sow), 10))
    smr[:, 0] = sow
    smr[:, 1:4] = max(nav.sigma_pos, 0.01)
    smr[:, 4:7] = 0.01
    smr[:, 7:10] = max(nav.sigma_att, 1e-4) * 60.0  # arc-minutes
    write_sbet(folder / "trajectory.smrmsg", smr)
