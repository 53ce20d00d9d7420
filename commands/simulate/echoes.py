"""Every pulse cast into the scene from the true pose and mounting: its echoes, their ranges and classes."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from commands.simulate import scene as sc
from commands.simulate.faults import FaultPlan
from commands.simulate.flight import Flight
from commands.simulate.forward import Earth
from commands.simulate.sensors import Scanner


@dataclass(frozen=True)
class Survey:
    """What a pulse meets: the scene, the flight over it and the scanner as it truly flew."""

    world: sc.Scene
    frame: Earth  # the local ENU frame
    flight: Flight
    lat: np.ndarray  # geodetic latitude and longitude of the flight's truth samples, degrees
    lon: np.ndarray
    scanner: Scanner
    rotation: np.ndarray  # true mounting R_body<-scanner (3, 3)
    lever_arm: np.ndarray  # true lever arm, body axes (3,)
    range_noise: float  # 1-sigma, metres (0: none)


def poses(survey: Survey, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """True position (n, 3) and rotation local ENU <- body (forward-right-down) (n, 3, 3) at times t."""
    flight = survey.flight
    pos = flight.position(t)
    att = flight.attitude(t)
    lat = np.interp(t, flight.t, survey.lat)
    lon = np.interp(t, flight.t, survey.lon)
    return pos, survey.frame.local_from_body(lat, lon, att[:, 0], att[:, 1], att[:, 2]).as_matrix()


def echoes(
    survey: Survey,
    pat: dict[str, np.ndarray],
    pulse_base: int,
    plan: FaultPlan,
    rng: np.random.Generator,
    noise_rng: np.random.Generator,
) -> dict[str, np.ndarray]:
    """Cast every pulse of *pat*: first echo on the canopy, a second through gaps in vegetation; dust; water drop-outs.

    *pulse_base* numbers the pulses across chunks (the plan's dust pulses).
    Returns per echo, in pulse then echo order: pulse (index in *pat*),
    echo (0, 1), n (echoes of the pulse), range_true, range (with noise),
    hit (local ENU), cls, dust, pulse_id.
    """
    world, scanner = survey.world, survey.scanner
    t = pat["t"]
    pos, r_l_b = poses(survey, t)
    origin = pos + r_l_b @ survey.lever_arm
    d = np.einsum("nij,nj->ni", r_l_b, pat["dir"] @ survey.rotation.T)
    first = sc.cast(world, world.canopy, origin, d)
    hit = origin + d * first[:, None]
    ok = np.isfinite(first) & (first <= scanner.max_range_m)
    veg = ok & (
        world.sample(world.canopy, hit[:, 0], hit[:, 1]) > world.sample(world.solid, hit[:, 0], hit[:, 1]) + 0.3
    )
    cls1 = np.where(veg, sc.VEGETATION, world.class_of_hit(hit[:, 0], hit[:, 1], hit[:, 2]))
    # water: most pulses are not returned (specular)
    ok &= ~((cls1 == sc.WATER) & (rng.random(len(t)) < 0.5))
    # vegetation: half the pulses also reach the surface below
    through = veg & ok & (rng.random(len(t)) < 0.5)
    second = np.full(len(t), np.nan)
    idx = np.flatnonzero(through)
    if len(idx):
        second[idx] = sc.cast(world, world.solid, origin[idx], d[idx], t_min=first[idx] + 1.5)
    has2 = np.isfinite(second) & (second <= scanner.max_range_m)
    hit2 = origin + d * np.nan_to_num(second)[:, None]
    cls2 = world.class_of_hit(hit2[:, 0], hit2[:, 1], hit2[:, 2])
    pulse_id = pulse_base + np.arange(len(t))
    dust = np.isin(pulse_id, list(plan.dust_pulses)) if plan.dust_pulses else np.zeros(len(t), bool)
    if dust.any():  # the pulse is answered by a dust cloud 3-30 m away, and nothing else
        first = np.where(dust, rng.uniform(3.0, 30.0, len(t)), first)
        ok |= dust
        has2 &= ~dust
        cls1 = np.where(dust, sc.NOISE, cls1)
        hit = origin + d * first[:, None]
    n_ret = ok.astype(np.int64) + (has2 & ok)
    first_echoes = (0, first, hit, cls1, ok)
    second_echoes = (1, second, hit2, cls2, has2 & ok)
    e = _in_pulse_order([_rows(*echo, n_ret, dust) for echo in (first_echoes, second_echoes)])
    e["range"] = e["range_true"] + (
        noise_rng.normal(0, survey.range_noise, len(e["pulse"])) if survey.range_noise else 0.0
    )
    e["pulse_id"] = pulse_base + e["pulse"]
    return e


def _rows(echo: int, ranges, hits, classes, selected, n_ret, dust) -> dict[str, np.ndarray]:
    """The echoes of number *echo* (0 first, 1 second) of the *selected* pulses."""
    i = np.flatnonzero(selected)
    return {
        "pulse": i,
        "echo": np.full(len(i), echo),
        "n": n_ret[i],
        "range_true": ranges[i],
        "hit": hits[i],
        "cls": classes[i],
        "dust": dust[i],
    }


def _in_pulse_order(rows: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The echoes of *rows* together, sorted by pulse, then echo."""
    e = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    order = np.lexsort((e["echo"], e["pulse"]))
    return {k: v[order] for k, v in e.items()}
