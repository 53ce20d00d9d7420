"""The simulator's flight: a flight plan flown smoothly, and the true pose at any time.

Lines are flown in order, joined by Dubins paths (turn, straight, turn;
Dubins 1957, doi:10.2307/2372560) at a turn radius set by the bank angle;
the heading rate is then smoothed (two 3 s moving averages) so roll, which
follows the coordinated-turn bank ``atan(v * omega / g)``, changes gradually
as it does in a real aircraft.  The truth trajectory is a cubic spline
through the path sampled every 5 ms, in the local ENU frame; attitude is
relative to NED at the aircraft (roll and pitch also carry small
oscillations, heading a constant crab angle) in the aviation convention.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import binary_dilation

G = 9.80665
DT = 0.005  # truth sampling step (s); the INS and SBET are written at these epochs


@dataclass
class Line:
    start: np.ndarray  # (e, n) local metres
    heading: float  # radians, clockwise from north
    length: float
    altitude: float | None = None  # flying height of this line (None: the flight's altitude)


def plan_lines(
    centre: tuple[float, float],
    n_lines: int,
    spacing: float,
    length: float,
    heading_deg: float,
    cross: bool,
    *,
    one_way: bool = False,
    second_altitude: float | None = None,
) -> list[Line]:
    """Parallel lines (alternating direction) centred on *centre*, and a cross line through the middle.

    *one_way*: every parallel line is flown in the first line's direction (a turn back between lines).
    *second_altitude*: the middle line is flown again, there and back, at this height
    (a calibration flight: opposite directions, a cross line and two heights separate the boresight
    angles and the lever arm; docs/CALIBRATION.md).
    """
    psi = np.radians(heading_deg)
    along = np.array([np.sin(psi), np.cos(psi)])
    across = np.array([np.cos(psi), -np.sin(psi)])
    c = np.asarray(centre, dtype=float)
    lines = []
    for k in range(n_lines):
        off = (k - (n_lines - 1) / 2) * spacing
        mid = c + off * across
        if k % 2 == 0 or one_way:
            lines.append(Line(mid - along * length / 2, psi, length))
        else:
            lines.append(Line(mid + along * length / 2, psi + np.pi, length))
    if cross:
        width = (n_lines - 1) * spacing + spacing
        cross_len = max(width, length / 2)
        lines.append(Line(c - across * cross_len / 2, psi + np.pi / 2, cross_len))
    if second_altitude is not None:
        mid = lines[n_lines // 2]
        end = mid.start + mid.length * np.array([np.sin(mid.heading), np.cos(mid.heading)])
        lines.append(Line(end, mid.heading + np.pi, mid.length, second_altitude))
        lines.append(Line(mid.start, mid.heading, mid.length, second_altitude))
    return lines


def _dubins_csc(p, psi0, q, psi1, r):
    """Shortest of the LSL and RSR paths from (p, psi0) to (q, psi1): [(turn sign, angle), straight, (sign, angle)]."""
    best = None
    for sign in (+1, -1):  # +1: right turn (clockwise heading increase), -1: left
        # centre of a turn: to the right of the heading for a right turn
        def centre(point, psi, s=sign):
            return point + s * r * np.array([np.cos(psi), -np.sin(psi)])

        c0, c1 = centre(p, psi0), centre(q, psi1)
        d = c1 - c0
        dist = float(np.hypot(*d))
        phi = float(np.arctan2(d[0], d[1]))  # heading of the straight (clockwise from north)
        a = (sign * (phi - psi0)) % (2 * np.pi)
        b = (sign * (psi1 - phi)) % (2 * np.pi)
        total = r * (a + b) + dist
        if best is None or total < best[0]:
            best = (total, [(sign, a), dist, (sign, b)])
    return best[1]


@dataclass
class Flight:
    """The flown path: samples every DT seconds and their cubic splines (the truth)."""

    t: np.ndarray  # seconds from the start of the flight
    pos: np.ndarray  # (m, 3) local ENU
    roll: np.ndarray  # radians (aviation: right wing down positive)
    pitch: np.ndarray
    heading: np.ndarray  # radians, clockwise from north, unwrapped
    line: np.ndarray  # line index (1-based) per sample; 0 in turns and lead-ins
    speed: float

    def __post_init__(self) -> None:
        self._pos = CubicSpline(self.t, self.pos, axis=0)
        self._att = CubicSpline(self.t, np.column_stack((self.roll, self.pitch, self.heading)), axis=0)

    @property
    def duration(self) -> float:
        return float(self.t[-1])

    def position(self, t: np.ndarray) -> np.ndarray:
        return self._pos(t)

    def attitude(self, t: np.ndarray) -> np.ndarray:
        """(n, 3) roll, pitch, heading (radians) at times *t*."""
        return self._att(t)

    def velocity(self, t: np.ndarray) -> np.ndarray:
        """(n, 3) velocity (m/s, local ENU) at times *t*: the derivative of the position spline."""
        return self._pos(t, 1)

    def line_at(self, t: np.ndarray) -> np.ndarray:
        """The line index (0: off the lines) of the truth sample nearest to each time *t*."""
        return self.line[sample_index(t, len(self.t))]


def sample_index(t: np.ndarray, n: int) -> np.ndarray:
    """The truth sample (every DT seconds) nearest to each time *t*, clipped to the *n* samples."""
    return np.clip(np.round(np.asarray(t) / DT).astype(np.int64), 0, n - 1)


def recorded(recording: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Whether the scanner records at each time *t* (*recording*: a flag per truth sample)."""
    return recording[sample_index(t, len(recording))]


def recording_mask(flight: Flight, lead_s: float | None) -> np.ndarray:
    """The scanner records on the lines and for *lead_s* before and after each (None: all the time)."""
    on = flight.line > 0 if lead_s is not None else np.ones(len(flight.t), bool)
    k = int(round(lead_s / DT)) if lead_s is not None else 0
    if k:
        on = binary_dilation(on, np.ones(2 * k + 1, bool))
    edge = int(round(2.0 / DT))  # the navigation files start and end 2 s beyond the scanner's data
    on[:edge] = False
    on[-edge:] = False
    return on


def fly(
    lines: list[Line],
    *,
    altitude: float,
    speed: float,
    bank_deg: float = 20.0,
    lead_in: float = 100.0,
    smooth_s: float = 3.0,
    seed: int = 0,
    level: bool = False,
) -> Flight:
    """Fly *lines* in order at *altitude* (local up; a line's own ``altitude`` when set) and *speed*, with
    turns between them; a change of height is flown as a steady climb or descent between the lines.  *level*:
    roll and pitch exactly 0 out of the turns (:func:`_attitude`)."""
    radius = speed**2 / (G * np.tan(np.radians(bank_deg)))
    segs, start_p, start_psi = _segments(lines, speed, radius, lead_in)
    total = sum(s[0] for s in segs)
    t = np.arange(0.0, total + DT / 2, DT)
    omega, label = _turn_rates(segs, t)
    win = max(1, int(round(smooth_s / DT)))
    kernel = np.ones(win) / win
    omega_s = np.convolve(np.convolve(omega, kernel, "same"), kernel, "same")
    heading = start_psi + _integral(omega_s)
    e = start_p[0] + _integral(speed * np.sin(heading))
    n = start_p[1] + _integral(speed * np.cos(heading))
    up = _heights(t, label, lines, altitude, lead_in / speed)
    pos = np.column_stack((e, n, up))
    roll, pitch, crab = _attitude(t, omega_s, speed, seed, level)
    # a line keeps its label only where the smoothed turn rate has died away
    label[np.abs(omega_s) > np.radians(0.05)] = 0
    return Flight(t, pos, roll, pitch, heading + crab, label, speed)


def _segments(
    lines: list[Line], speed: float, radius: float, lead_in: float
) -> tuple[list[tuple[float, float, int]], np.ndarray, float]:
    """(duration, heading rate, line index) of every straight and turn of the flight; its start point and heading."""
    segs: list[tuple[float, float, int]] = []
    run_in = 3.0  # s of straight flight before the first lead-in and after the last (navigation only)
    p = lines[0].start - (lead_in + run_in * speed) * np.array([np.sin(lines[0].heading), np.cos(lines[0].heading)])
    psi = lines[0].heading
    start_p, start_psi = p.copy(), psi
    segs.append((run_in, 0.0, 0))
    for k, line in enumerate(lines, 1):
        d = np.array([np.sin(line.heading), np.cos(line.heading)])
        target = line.start - lead_in * d
        if k > 1:
            (s0, a), straight, (s1, b) = _dubins_csc(p, psi, target, line.heading, radius)
            omega = speed / radius
            segs += [(a / omega, s0 * omega, 0), (straight / speed, 0.0, 0), (b / omega, s1 * omega, 0)]
        segs += [(lead_in / speed, 0.0, 0), (line.length / speed, 0.0, k), (lead_in / speed, 0.0, 0)]
        p, psi = line.start + line.length * d + lead_in * d, line.heading
    segs.append((run_in, 0.0, 0))
    return segs, start_p, start_psi


def _turn_rates(segs: list[tuple[float, float, int]], t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The heading rate and the line index of the segment at each time *t*."""
    omega = np.zeros_like(t)
    label = np.zeros(len(t), np.int32)
    edges = np.cumsum([0.0] + [s[0] for s in segs])
    for (dur, w, k), t0 in zip(segs, edges[:-1], strict=True):
        sel = (t >= t0) & (t < t0 + dur)
        omega[sel] = w
        label[sel] = k
    return omega, label


def _integral(rate: np.ndarray) -> np.ndarray:
    """The running integral of a quantity sampled every DT seconds (trapezoids), 0 at the first sample."""
    return np.concatenate(([0.0], np.cumsum((rate[1:] + rate[:-1]) / 2 * DT)))


def _heights(t: np.ndarray, label: np.ndarray, lines: list[Line], altitude: float, lead_s: float) -> np.ndarray:
    """Height at each time: level from the start of each line's lead-in (*lead_s*) to the end of its lead-out,
    climbing or descending in between."""
    heights = [altitude if line.altitude is None else line.altitude for line in lines]
    if all(hh == altitude for hh in heights):
        return np.full(t.shape, altitude, dtype=np.float64)
    knots_t, knots_h = [], []
    for k, hh in enumerate(heights, 1):
        on = np.flatnonzero(label == k)
        knots_t += [t[on[0]] - lead_s, t[on[-1]] + lead_s]
        knots_h += [hh, hh]
    return np.interp(t, knots_t, knots_h)


def _attitude(
    t: np.ndarray, omega_s: np.ndarray, speed: float, seed: int, level: bool = False
) -> tuple[np.ndarray, np.ndarray, float]:
    """Roll (coordinated-turn bank plus a small oscillation), pitch (oscillating) and a constant crab angle, radians.

    *level*: no oscillation and no nose-up pitch: roll is the turns' bank alone (0 on the lines), pitch 0;
    the crab angle stays.
    """
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0, 2 * np.pi, 3)
    roll = np.arctan(speed * omega_s / G)
    if level:
        return roll, np.zeros_like(t), np.radians(2.0) * np.sin(ph[2])
    roll = roll + np.radians(0.6) * np.sin(2 * np.pi * 0.21 * t + ph[0])
    pitch = np.radians(1.5) + np.radians(0.4) * np.sin(2 * np.pi * 0.13 * t + ph[1])
    crab = np.radians(2.0) * np.sin(ph[2])
    return roll, pitch, crab
