"""The trajectory of the ``.lmsq`` formats: GNSS positions with INS attitudes (3.B), or an SBET (3.C).

Both return the trajectory's columns (time, lat, lon, h, roll, pitch, yaw
and the sigmas the files give) and the figures counted on the way, for
``qc/debug.txt`` and the metrics.  Times are GPS seconds since 1980-01-06.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from pipeline.errors import ConfigError, InputDataError
from stages.parse.params import LmsqNmeaInput, LmsqSbetInput
from stages.parse.read_ins import (
    TrajectoryCounters,
    canonical_attitude,
    increasing,
    read_ins_csv,
    read_sbet,
    read_smrmsg,
)
from stages.parse.read_nmea import NmeaCounters, read_nmea

#: smrmsg column -> trajectory column (the smrmsg's down sigma is the up sigma)
SMRMSG_SIGMAS = (
    ("sigma_north_m", "sigma_north_m"),
    ("sigma_east_m", "sigma_east_m"),
    ("sigma_down_m", "sigma_up_m"),
    ("sigma_roll_deg", "sigma_roll_deg"),
    ("sigma_pitch_deg", "sigma_pitch_deg"),
    ("sigma_heading_deg", "sigma_heading_deg"),
)


def nmea_ins_trajectory(
    p: LmsqNmeaInput, week: int, counters: TrajectoryCounters, log: logging.LoggerAdapter, geoid: Path | None = None
) -> tuple[dict[str, np.ndarray], dict]:
    """3.B: INS attitude epochs with positions from the GNSS log (cubic spline in time between GNSS epochs).

    The attitude is the INS CSV's, or without one the NMEA log's ``$PASHR``.
    INS epochs outside the GNSS span, or inside a gap between GNSS epochs
    longer than ``max_gap_s``, are dropped and counted.  *geoid* gives the
    geoid separation of fixes without one (:func:`read_nmea`).

    Returns
    -------
    trajectory : dict
        Columns time, lat, lon, h, roll, pitch, yaw, and the GST sigmas when the log has them.
    figures : dict
        The NMEA counters, GNSS epochs and INS epochs without a position.
    """
    nmea_counters = NmeaCounters()
    nav = read_nmea(
        p.nmea,
        nmea_counters,
        day=p.nmea_date,
        leap_seconds=p.leap_seconds,
        separation_m=p.geoid_separation_m,
        geoid=geoid,
    )
    counters.locations.extend(nmea_counters.locations[:10])
    pos = _in_time_order(nav.position, counters, "GGA", p.nmea)
    ins = read_ins_csv(p.ins, week, counters) if p.ins is not None else _pashr_attitude(nav.attitude, counters, p.nmea)
    extra = _nmea_figures(nmea_counters)
    extra["gnss_epochs"] = len(pos["time"])
    if nmea_counters.fixes_2d:
        log.warning(
            "%d 2-D fixes (GGA/GNS without altitude) in %s: not used as positions", nmea_counters.fixes_2d, p.nmea.name
        )
    if len(pos["time"]) < 2:
        raise InputDataError(
            f"{p.nmea}: fewer than two usable GGA positions ({nmea_counters.sentences} sentences read)."
        )
    inside = _covered(pos["time"], ins["time"], p.max_gap_s)
    extra["ins_epochs_without_position"] = int((~inside).sum())
    if extra["ins_epochs_without_position"]:
        log.warning(
            "%d INS epochs outside the GNSS positions or in gaps over %g s: dropped",
            extra["ins_epochs_without_position"],
            p.max_gap_s,
        )
    out = _positions_at(pos, ins, inside)
    out.update(_sigmas_at(nav.sigma, out["time"]))
    return out, extra


def _in_time_order(table: dict[str, np.ndarray], counters: TrajectoryCounters, what: str, path: Path) -> dict:
    """The epochs of *table* each later than the last one kept (the others counted)."""
    keep = increasing(table["time"], counters, what, lambda i: f"{path}, {what} epoch {i + 1}")
    return {k: v[keep] for k, v in table.items()}


def _pashr_attitude(attitude: dict[str, np.ndarray], counters: TrajectoryCounters, path: Path) -> dict:
    """The INS attitude from the log's ``$PASHR`` sentences, when no INS CSV is given."""
    if not len(attitude["time"]):
        raise ConfigError(f"{path}: the log has no $PASHR attitude; set input.ins (the INS attitude CSV).")
    att = _in_time_order(attitude, counters, "PASHR", path)
    roll, pitch, heading = canonical_attitude(att["roll_deg"], att["pitch_deg"], att["heading_deg"])
    return {"time": att["time"], "roll": roll, "pitch": pitch, "heading": heading}


def _nmea_figures(counters: NmeaCounters) -> dict:
    """The NMEA reader's counters as figures (``nmea_...``; sentences not read, by type)."""
    extra = {f"nmea_{k}": v for k, v in vars(counters).items() if k not in ("locations", "unread")}
    extra.update({f"nmea_unread_{kind}": n for kind, n in sorted(counters.unread.items())})
    return extra


def _covered(tg: np.ndarray, ti: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Mask of the INS times *ti* inside the GNSS times *tg*, in no gap longer than *max_gap_s*."""
    i = np.clip(np.searchsorted(tg, ti, side="right") - 1, 0, len(tg) - 2)
    return (ti >= tg[0]) & (ti <= tg[-1]) & ((tg[i + 1] - tg[i]) <= max_gap_s)


def _positions_at(pos: dict[str, np.ndarray], ins: dict[str, np.ndarray], inside: np.ndarray) -> dict:
    """The INS epochs *inside*, with positions splined (cubic, in time) from the GNSS epochs."""
    t = ins["time"][inside]
    # lazy: scipy.interpolate takes about 0.1 s to import, in every run; only raw flights' trajectories need it
    from scipy.interpolate import CubicSpline

    spline = CubicSpline(pos["time"], np.column_stack((pos["lat"], pos["lon"], pos["h"])), axis=0)
    lla = spline(t)
    return {
        "time": t,
        "lat": lla[:, 0],
        "lon": lla[:, 1],
        "h": lla[:, 2],
        "roll": ins["roll"][inside],
        "pitch": ins["pitch"][inside],
        "yaw": ins["heading"][inside],
    }


def _sigmas_at(sig: dict[str, np.ndarray], t: np.ndarray) -> dict[str, np.ndarray]:
    """The GST position sigmas at times *t* (linear in time; none when the log has no GST)."""
    if len(sig["time"]) < 1:
        return {}
    order = np.argsort(sig["time"], kind="stable")
    st = sig["time"][order]
    return {
        "sigma_north_m": np.interp(t, st, sig["sigma_lat_m"][order]),
        "sigma_east_m": np.interp(t, st, sig["sigma_lon_m"][order]),
        "sigma_up_m": np.interp(t, st, sig["sigma_h_m"][order]),
    }


def sbet_trajectory(p: LmsqSbetInput, week: int, counters: TrajectoryCounters) -> tuple[dict[str, np.ndarray], dict]:
    """3.C: the SBET as it is (true heading = platform heading - wander), sigmas from the smrmsg.

    Returns the trajectory's columns and the figures (``smrmsg_epochs`` when an smrmsg is given).
    """
    sb = read_sbet(p.sbet, week, counters)
    out = {
        "time": sb["time"],
        "lat": sb["lat"],
        "lon": sb["lon"],
        "h": sb["h"],
        "roll": sb["roll"],
        "pitch": sb["pitch"],
        "yaw": sb["heading"],
    }
    extra = {}
    if p.smrmsg is not None:
        sm = read_smrmsg(p.smrmsg, week, counters)
        extra["smrmsg_epochs"] = len(sm["time"])
        if not len(sm["time"]):
            where = counters.locations[0] if counters.locations else f"{p.smrmsg.stat().st_size} bytes"
            raise InputDataError(f"{p.smrmsg}: no usable smrmsg record ({where}); fix the file or remove input.smrmsg.")
        for src, dst in SMRMSG_SIGMAS:
            out[dst] = np.interp(out["time"], sm["time"], sm[src])
    return out, extra
