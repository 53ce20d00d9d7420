"""The seed-0 ltp plane measured against the exact local tangent plane over the survey.

The seed claims the difference is negligible under 1 km; every run measures
it (the ``ltp_vs_exact_*`` metrics) beside what geometry predicts
(``ltp_predicted_*``), whichever frame the points are written in.
"""

from __future__ import annotations

import numpy as np

from lidar.geodesy import ltp_predicted_departure
from lidar.georeferencing import Mounting, Trajectory, ltp_departure


def ltp_metrics(
    exact: Trajectory, ltp: Trajectory, pulses: dict, mounting: Mounting, max_gap_s: float, radius: float
) -> dict[str, float]:
    """The largest ltp - exact differences on a subsample of about 200,000 pulses, and the predicted ones.

    Empty when no pulse of the subsample has a trajectory.
    """
    step = max(1, len(pulses["time"]) // 200_000)
    t = np.asarray(pulses["time"][::step])
    cols = tuple(np.ascontiguousarray(pulses[k][::step], dtype=np.float64) for k in ("x", "y", "z"))
    diff, ex, platform = ltp_departure(exact, ltp, t, cols, mounting, max_gap_s)
    if not len(diff):
        return {}
    pred_h, pred_v = ltp_predicted_departure(platform, exact.frame.lat0, exact.frame.h0, radius)
    return {
        "ltp_vs_exact_max_horizontal_m": float(np.max(np.hypot(diff[:, 0], diff[:, 1]))),
        "ltp_vs_exact_max_vertical_m": float(np.max(np.abs(diff[:, 2]))),
        "ltp_vs_exact_extent_m": float(np.max(np.hypot(ex[:, 0], ex[:, 1]))),
        "ltp_predicted_max_horizontal_m": float(np.max(pred_h)),
        "ltp_predicted_max_vertical_m": float(np.max(pred_v)),
    }
