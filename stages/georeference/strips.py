"""Flight strips (SPEC 4): steady-heading lines of the trajectory separated by turns.

:func:`segment_strips` labels the epochs, :func:`pulse_strips` gives every
pulse its strip and :func:`write_flight_lines` writes the lines to
``qc/trajectory.gpkg``.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from lidar.vectors import line_wkb, write_gpkg
from stages.georeference.params import StripParams

#: The segmentation's parameters at their defaults: the function's defaults are the configuration's.
_STRIPS = StripParams()

if TYPE_CHECKING:
    import pyproj


GAP_S = 2.0
"""A step between epochs longer than this (s) is a gap in the trajectory: it ends a line."""


def segment_strips(
    time: np.ndarray,
    heading_deg: np.ndarray,
    *,
    turn_rate_deg_s: float = _STRIPS.turn_rate_deg_s,
    min_line_s: float = _STRIPS.min_line_s,
    smooth_s: float = 2.0,
) -> np.ndarray:
    """Strip number per epoch: 1, 2, ... for the lines in time order, 0 in turns.

    The trajectory is first cut at its gaps: a step between epochs longer
    than :data:`GAP_S` (2 s) ends a piece (the recording paused, in a turn or
    on a line).  In each piece on its own, the heading (unwrapped) is smoothed
    with a moving average of *smooth_s* seconds (the piece padded with its own
    first and last heading; a piece no longer than the window is not smoothed)
    and differentiated, the window counted in the piece's median time step.  An
    epoch is on a line when the smoothed turn rate is below *turn_rate_deg_s*;
    a run of such epochs, within one piece, lasting at least *min_line_s*
    seconds is a line.  A piece of one epoch has no turn rate: it is taken as
    steady, a run of 0 s (a line only if *min_line_s* is 0).  Fewer than three
    epochs in all make one line if they span *min_line_s*, gaps or not.
    Units: seconds and degrees (the direction of the heading does not matter,
    so NED and NWU yaw both work).

    Smoothing piece by piece departs from the earlier whole-array average:
    across a gap that one mixed the heading of the line before the gap with
    the line after it, so the first epochs after a gap looked like a turn.

    >>> t = np.arange(0, 60, 0.1)
    >>> hdg = np.where(t < 20, 0.0, np.where(t < 30, (t - 20) * 18.0, 180.0))
    >>> s = segment_strips(t, hdg, min_line_s=5)
    >>> int(s[0]), int(s[-1]), int(s[250])
    (1, 2, 0)
    """
    t = np.asarray(time, dtype=np.float64)
    n = len(t)
    if n < 3:  # too few epochs for a turn rate: one line if they last long enough
        return np.full(n, 1 if n and t[-1] - t[0] >= min_line_s else 0, np.int32)
    h = np.unwrap(np.radians(np.asarray(heading_deg, dtype=np.float64)))
    gaps = np.concatenate(([False], np.diff(t) > GAP_S))
    # the turn rate piece by piece between the gaps (a loop over the pieces, a few hundred at most;
    # each piece vectorised: a trajectory has an epoch every 5 ms, hours of them)
    bounds = np.concatenate(([0], np.flatnonzero(gaps), [n]))
    rate = np.empty(n)
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        rate[a:b] = _turn_rate(t[a:b], h[a:b], smooth_s)
    steady = rate < turn_rate_deg_s
    # runs of steady epochs, a gap in the trajectory also starting a new run
    before = np.concatenate(([False], steady[:-1]))
    after = np.concatenate((steady[1:], [False]))
    first = np.flatnonzero(steady & (~before | gaps))
    last = np.flatnonzero(steady & (~after | np.concatenate((gaps[1:], [False]))))
    run = np.cumsum(steady & (~before | gaps)) * steady
    long_enough = t[last] - t[first] >= min_line_s
    label = np.concatenate(([0], np.where(long_enough, np.cumsum(long_enough), 0))).astype(np.int32)
    return label[run]


def _turn_rate(t: np.ndarray, h: np.ndarray, smooth_s: float) -> np.ndarray:
    """Smoothed turn rate (deg/s) of one piece of trajectory without a gap; 0 for a lone epoch."""
    n = len(t)
    if n < 2:
        return np.zeros(n)
    dt = float(np.median(np.diff(t)))
    win = max(1, int(round(smooth_s / max(dt, 1e-9))))
    if win > 1 and n > win:
        kernel = np.ones(win) / win
        padded = np.concatenate((np.full(win, h[0]), h, np.full(win, h[-1])))
        h = np.convolve(padded, kernel, "same")[win:-win]
    return np.degrees(np.abs(np.gradient(h, t)))


def nearest(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the epoch nearest to each time.

    >>> nearest(np.array([0.0, 1.0, 2.0]), np.array([0.4, 0.6, 5.0])).tolist()
    [0, 1, 2]
    """
    idx = np.clip(np.searchsorted(times, t, side="left"), 0, len(times) - 1)
    prev = np.clip(idx - 1, 0, None)
    return np.where(np.abs(times[prev] - t) < np.abs(times[idx] - t), prev, idx)


def pulse_strips(
    epoch_time: np.ndarray, epoch_strip: np.ndarray, pulse_time: np.ndarray, batch_size: int
) -> tuple[np.ndarray, np.ndarray]:
    """The strip of every pulse (its nearest epoch's), and of every epoch, numbered again.

    The strips that have pulses are numbered 1, 2, ... in time order (0 stays
    a turn); the pulses are looked up *batch_size* at a time.
    """
    pulse_strip = np.empty(len(pulse_time), np.int32)
    for s in range(0, len(pulse_time), batch_size):
        sl = slice(s, s + batch_size)
        pulse_strip[sl] = epoch_strip[nearest(epoch_time, np.asarray(pulse_time[sl]))]
    used = np.unique(pulse_strip)
    renumber = np.zeros(int(epoch_strip.max()) + 1, np.int32)
    renumber[used[used > 0]] = np.arange(1, int(np.sum(used > 0)) + 1)
    return renumber[pulse_strip], renumber[epoch_strip]


def write_flight_lines(path: Path, time: np.ndarray, xyz: np.ndarray, strip: np.ndarray, crs: pyproj.CRS) -> None:
    """``qc/trajectory.gpkg``: one LineString a flight line, in the output CRS.

    Per line: the strip id, the first and last GPS time, and the height of the
    platform in the output CRS (mean, lowest, highest); epochs in turns
    (strip 0) are left out, as is a line of one epoch (no line to draw).
    """
    ids = [int(s) for s in np.unique(strip) if s > 0 and np.count_nonzero(strip == s) > 1]
    lines, rows = [], []
    for s in ids:
        m = strip == s
        pts = xyz[m]
        lines.append(line_wkb(pts))
        rows.append((s, time[m].min(), time[m].max(), pts[:, 2].mean(), pts[:, 2].min(), pts[:, 2].max()))
    names = ("strip", "time_start", "time_end", "altitude_mean", "altitude_min", "altitude_max")
    table = np.array(rows, dtype=np.float64).reshape(-1, len(names))
    fields = {n: table[:, i] for i, n in enumerate(names)}
    fields["strip"] = fields["strip"].astype(np.int32)
    write_gpkg(path, lines, fields, crs=crs, layer="flight_lines")
