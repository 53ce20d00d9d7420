"""Flight-strip segmentation from a trajectory: steady-heading lines separated by turns (SPEC 4)."""

from __future__ import annotations

import numpy as np


def segment_strips(
    time: np.ndarray, heading_deg: np.ndarray, *, turn_rate_deg_s: float = 1.0, min_line_s: float = 10.0,
    smooth_s: float = 2.0,
) -> np.ndarray:  # fmt: skip
    """Strip number per epoch: 1, 2, ... for the lines in time order, 0 in turns.

    The heading (unwrapped) is smoothed with a moving average of *smooth_s*
    seconds; an epoch is on a line when the smoothed turn rate is below
    *turn_rate_deg_s*; a run of such epochs lasting at least *min_line_s*
    seconds is a line.  A gap in the trajectory longer than 2 s also ends a
    line.  Units: seconds and degrees (the direction of the heading does not
    matter, so NED and NWU yaw both work).

    >>> t = np.arange(0, 60, 0.1)
    >>> hdg = np.where(t < 20, 0.0, np.where(t < 30, (t - 20) * 18.0, 180.0))
    >>> s = segment_strips(t, hdg, min_line_s=5)
    >>> int(s[0]), int(s[-1]), int(s[250])
    (1, 2, 0)
    """
    t = np.asarray(time, dtype=np.float64)
    n = len(t)
    if n < 3:
        return np.ones(n, np.int32)
    h = np.unwrap(np.radians(np.asarray(heading_deg, dtype=np.float64)))
    dt = float(np.median(np.diff(t)))
    win = max(1, int(round(smooth_s / max(dt, 1e-9))))
    if win > 1 and n > win:
        kernel = np.ones(win) / win
        padded = np.concatenate((np.full(win, h[0]), h, np.full(win, h[-1])))
        h = np.convolve(padded, kernel, "same")[win:-win]
    rate = np.degrees(np.abs(np.gradient(h, t)))
    steady = rate < turn_rate_deg_s
    gaps = np.concatenate(([False], np.diff(t) > 2.0))
    # runs of steady epochs, a gap in the trajectory also starting a new run (vectorised: a
    # trajectory has an epoch every 5 ms, hours of them)
    before = np.concatenate(([False], steady[:-1]))
    after = np.concatenate((steady[1:], [False]))
    first = np.flatnonzero(steady & (~before | gaps))
    last = np.flatnonzero(steady & (~after | np.concatenate((gaps[1:], [False]))))
    run = np.cumsum(steady & (~before | gaps)) * steady
    long_enough = t[last] - t[first] >= min_line_s
    label = np.concatenate(([0], np.where(long_enough, np.cumsum(long_enough), 0))).astype(np.int32)
    return label[run]
