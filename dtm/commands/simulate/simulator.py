"""``pipeline simulate``: one survey with known truth, in every raw format (SPEC 10).

The world (:mod:`dtm.commands.simulate.scene`) and the flight (:mod:`dtm.commands.simulate.flight`)
live in a local ENU frame tangent to WGS 84 at the configured origin, an
exact rigid transform of ECEF.  For every pulse the simulator takes the
true pose at the pulse's time, the *true* mounting (configured + injected
error), casts the ray into the scene, and records the echo's range (with
noise) in the scanner's frame.  Navigation files get the true trajectory
plus the configured errors (smooth noise, per-line GNSS bias).  The truth
is the ray's hit point, transformed to the output CRS with PROJ point by
point.

Written (``<output>/``): ``ldmrs/acquisition.log.gz`` (3.A), ``lmsq/scan.lmsq``
+ ``lmsq/nav.nmea`` + ``lmsq/ins.csv`` (3.B), ``lmsq/trajectory.sbet`` +
``lmsq/trajectory.smrmsg`` (3.C, same stream), ``las/points.laz`` (3.D),
``truth/points.laz``, ``truth/terrain.tif``, ``truth/land_cover.tif``, ``truth/faults.json``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dtm.commands.simulate import scene as sc
from dtm.commands.simulate.flight import DT, Flight, fly, plan_lines
from dtm.commands.simulate.forward import Earth, RecordedPose, attitude, mounting_matrix
from dtm.commands.simulate.reference import TABLE_15_MOUNTINGS, gps_seconds, utm_epsg
from dtm.commands.simulate.sensors import Scanner, make_scanner, navigation_sigmas

D_FLIP = np.diag([1.0, -1.0, -1.0])  # NED <-> NWU and forward-right-down <-> forward-left-up
#: truth/points.laz extra dimension ``fault``: why the reader will drop the echo (0: it will not)
FAULT_CODES = {"none": 0, "invalid_scan": 1, "bad_gps": 2, "clutter": 3, "dirt": 4, "pps_gap": 5,
               "invalid_quality": 6, "dust": 7}  # fmt: skip
CHUNK_S = 2.0
P_LINE = "P {} {} 0x{:02x} {:.4f} {:.4f} {:.4f}"


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


@dataclass
class SimResult:
    """What was written, the fault counts (as in faults.json), and the recorded navigation at 200 Hz."""

    output: Path
    faults: dict
    files: dict[str, str] = field(default_factory=dict)
    navigation: Navigation | None = None
    gps_start: float = 0.0


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


def _line_biases(flight: Flight, size: float, rng: np.random.Generator, spare: list[int] = ()) -> np.ndarray:
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


def _poses(frame: Earth, flight: Flight, lat_s, lon_s, t: np.ndarray):
    """True position (n, 3) and rotation local ENU <- body (forward-right-down) (n, 3, 3) at times t."""
    pos = flight.position(t)
    att = flight.attitude(t)
    lat = np.interp(t, flight.t, lat_s)
    lon = np.interp(t, flight.t, lon_s)
    return pos, frame.local_from_body(lat, lon, att[:, 0], att[:, 1], att[:, 2]).as_matrix()


def simulate(cfg, log=None) -> SimResult:
    """Run the simulation described by a :class:`~dtm.commands.simulate.settings.SimulateConfig`."""
    out = Path(cfg.output)
    rng = np.random.default_rng(cfg.seed)
    # noise has its own stream: realisations with another noise_seed see the same scene, flight and echoes
    noise_rng = np.random.default_rng([cfg.seed, 1, cfg.noise_seed if cfg.noise_seed is not None else cfg.seed])
    scanner = make_scanner(cfg.scanner)
    if scanner.kind == "ldmrs" and any(f in ("lmsq_nmea", "lmsq_sbet") for f in cfg.formats):
        raise SimConfigError("formats lmsq_nmea and lmsq_sbet need a RIEGL scanner (scanner.preset q140 or q280)")
    if scanner.kind == "line" and "ldmrs_mtig" in cfg.formats:
        raise SimConfigError("format ldmrs_mtig needs scanner.preset: ldmrs")
    noise = cfg.faults.noise
    sigma_pos, sigma_att = navigation_sigmas(cfg.navigation)
    if not noise:
        sigma_pos = sigma_att = 0.0
    range_noise = scanner.range_noise_m if noise else 0.0
    frame = Earth(cfg.origin.lat, cfg.origin.lon, cfg.origin.h)  # the simulator's own geometry (forward.py)
    crs = _truth_crs(cfg.crs, cfg.origin.lon, cfg.origin.lat)

    # --- flight and scene
    f = cfg.flight
    swath = 2 * f.altitude_m * np.tan(np.radians(scanner.half_angle_deg))
    spacing = swath * (1 - f.sidelap)
    lines = plan_lines((0.0, 0.0), f.lines, spacing, f.line_length_m, f.heading_deg, f.cross_line,
                       one_way=f.one_way, second_altitude=f.second_altitude_m)  # fmt: skip
    flight = fly(lines, altitude=f.altitude_m, speed=f.speed_ms, bank_deg=f.bank_deg, lead_in=f.lead_in_m,
                 seed=cfg.seed)  # fmt: skip
    # RIEGL systems record on the lines (and lead-ins); the seed-0 LD-MRS logs the whole flight
    rec_mask = _recording_mask(flight, f.lead_in_m / f.speed_ms if scanner.kind == "line" else None)
    if not rec_mask.any():
        raise SimConfigError("the flight is too short to record anything (make the lines longer)")
    on_lines = flight.pos[rec_mask]
    margin = swath / 2 + 20.0
    extent = (on_lines[:, 0].min() - margin, on_lines[:, 0].max() + margin,
              on_lines[:, 1].min() - margin, on_lines[:, 1].max() + margin)  # fmt: skip
    world = sc.make_scene(extent, seed=cfg.seed)
    lat_s, lon_s, h_s = frame.geodetic(flight.pos)

    # --- mounting: configured (what the files' users are told) and true (what flew)
    err_rot = mounting_matrix(*np.radians(cfg.faults.boresight_error_deg))
    if scanner.kind == "ldmrs":
        # LD-MRS -> MTi-G body (forward-left-up): Ry(+90 deg), then MPOS; in forward-right-down axes:
        r_nominal = D_FLIP @ mounting_matrix(0.0, np.pi / 2, 0.0)
        a_nominal = D_FLIP @ np.asarray(TABLE_15_MOUNTINGS[cfg.mounting])
    else:
        r_nominal = mounting_matrix(*np.radians(cfg.boresight_deg))
        a_nominal = np.asarray(cfg.lever_arm_m, dtype=float)
    r_true = err_rot @ r_nominal
    a_true = a_nominal + np.asarray(cfg.faults.lever_arm_error_m)

    # --- recorded navigation
    bias = _line_biases(flight, cfg.faults.strip_bias_m, rng, cfg.faults.error_free_lines)
    tau = cfg.navigation.error_period_s
    pos_err = smooth_noise(flight.t, sigma_pos, tau, noise_rng) + bias
    lat_r, lon_r, h_r = frame.geodetic(flight.pos + pos_err)
    # roll and pitch only: over a straight line they tilt and shift the strip rigidly; a heading bias
    # shears it (along-track shift growing across track), which no rigid strip correction can undo
    att_bias = _line_biases(flight, cfg.faults.strip_rotation_deg, rng, cfg.faults.error_free_lines)
    att_bias[:, 2] = 0.0
    att_err = smooth_noise(flight.t, sigma_att, tau / 4, noise_rng) + att_bias
    nav = Navigation(flight.t, lat_r, lon_r, h_r, np.degrees(flight.roll) + att_err[:, 0],
                     np.degrees(flight.pitch) + att_err[:, 1], np.degrees(flight.heading) + att_err[:, 2],
                     sigma_pos, sigma_att)  # fmt: skip

    if any(fmt in cfg.formats for fmt in ("lmsq_nmea", "lmsq_sbet")):
        # every navigation file spans the same time: from the first to the last GNSS epoch
        step = max(1, int(round(1.0 / (cfg.navigation.gnss_rate_hz * DT))))
        end = (len(nav.t) - 1) // step * step + 1
        nav = Navigation(*(getattr(nav, k)[:end] for k in ("t", "lat", "lon", "h", "roll", "pitch", "heading")),
                         nav.sigma_pos, nav.sigma_att)  # fmt: skip
    start = _gps_seconds(cfg.start_utc, cfg.leap_seconds)
    faults = {"seed": cfg.seed, "noise": noise, "range_noise_m": range_noise, "position_noise_m": sigma_pos,
              "attitude_noise_deg": sigma_att, "strip_bias_m": cfg.faults.strip_bias_m,
              "line_biases_m": _bias_table(flight, bias),
              "line_attitude_biases_deg": _bias_table(flight, att_bias),
              "boresight_error_deg": list(cfg.faults.boresight_error_deg),
              "lever_arm_error_m": list(cfg.faults.lever_arm_error_m),
              "gps_start": start, "crs": crs.to_string()}  # fmt: skip

    # --- pulses, chunk by chunk
    plan = _fault_plan(cfg, scanner, flight, rec_mask, rng)
    to_map_exact = frame.to_crs(crs)
    out.mkdir(parents=True, exist_ok=True)
    sinks = _Sinks(cfg, out, crs, scanner, plan, start, to_map_exact, nav, flight)
    nav_traj = RecordedPose(frame, start + nav.t, nav.lat, nav.lon, nav.h, nav.roll, nav.pitch, nav.heading)
    t_end = flight.duration
    t0 = 0.0
    pulse_base = 0
    while t0 < t_end:
        t1 = min(t0 + CHUNK_S, t_end)
        pat = scanner.pattern(t0, t1)
        keep = rec_mask[np.clip(np.round(pat["t"] / DT).astype(np.int64), 0, len(rec_mask) - 1)]
        pat = {k: v[keep] for k, v in pat.items()}
        n = len(pat["t"])
        if n:
            echoes = _echoes(world, frame, flight, lat_s, lon_s, pat, r_true, a_true, scanner, range_noise,
                             rng, plan, pulse_base, noise_rng)  # fmt: skip
            sinks.add(pat, echoes, flight, nav_traj, (r_nominal, a_nominal))
        pulse_base += n
        t0 = t1
    faults.update(sinks.close())
    files = sinks.files
    files.update(_write_navigation(cfg, out, nav, flight, start))
    if "lmsq" in faults:
        faults["lmsq"]["nmea_bad_checksums"] = cfg.faults.nmea_bad_checksums
    files["truth_terrain"] = "truth/terrain.tif"
    files["truth_land_cover"] = "truth/land_cover.tif"
    _write_truth_terrain(out / "truth", world, frame, crs, extent, cfg.truth_resolution)
    if cfg.checkpoints:
        _write_checkpoints(
            out / "checkpoints.csv", world, frame, crs, flight.pos[flight.line > 0], cfg.checkpoints, rng
        )
        files["checkpoints"] = "checkpoints.csv"
    faults["files"] = files
    (out / "truth" / "faults.json").write_text(json.dumps(faults, indent=2) + "\n")
    return SimResult(out, faults, files, nav, start)


def _truth_crs(setting: str, lon: float, lat: float):
    """The projected CRS of the simulated LAS and truth files: *setting*, or the WGS 84 / UTM zone of the origin."""
    import pyproj

    crs = pyproj.CRS.from_epsg(utm_epsg(lon, lat)) if setting == "auto-utm" else pyproj.CRS.from_user_input(setting)
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    if not horizontal.is_projected:
        raise SimConfigError(f"crs {crs.name} is not projected; choose a projected CRS or auto-utm")
    return crs


def _gps_seconds(start_utc: str, leap: float) -> float:
    from datetime import datetime

    try:
        stamp = datetime.fromisoformat(start_utc.replace("Z", "+00:00"))
    except ValueError:
        raise SimConfigError(f"start_utc {start_utc!r} is not an ISO 8601 time") from None
    if stamp.tzinfo is None:
        raise SimConfigError(f"start_utc {start_utc!r} has no time zone (UTC times end in Z)")
    value = gps_seconds(stamp, leap)
    if value != round(value):
        raise SimConfigError("start_utc must be a whole second")
    return float(value)


def _recording_mask(flight: Flight, lead_s: float | None) -> np.ndarray:
    """The scanner records on the lines and for *lead_s* before and after each (None: all the time)."""
    on = flight.line > 0 if lead_s is not None else np.ones(len(flight.t), bool)
    k = int(round(lead_s / DT)) if lead_s is not None else 0
    if k:
        from scipy.ndimage import binary_dilation

        on = binary_dilation(on, np.ones(2 * k + 1, bool))
    edge = int(round(2.0 / DT))  # the navigation files start and end 2 s beyond the scanner's data
    on[:edge] = False
    on[-edge:] = False
    return on


def _bias_table(flight: Flight, bias: np.ndarray) -> dict[str, list[float]]:
    table = {}
    for k in range(1, int(flight.line.max()) + 1):
        sel = flight.line == k
        table[str(k)] = [round(float(v), 6) for v in bias[sel].mean(axis=0)]
    return table


@dataclass
class _Plan:
    """Which scans / pulses / seconds get which fault (chosen up front so counts are exact)."""

    invalid_scans: set = field(default_factory=set)
    bad_gps_scans: set = field(default_factory=set)
    lost_scans: set = field(default_factory=set)
    empty_scans: set = field(default_factory=set)
    clutter_scans: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    dirt_count: int = 0
    dust_pulses: set = field(default_factory=set)
    invalid_pulses: set = field(default_factory=set)
    pps_gaps: set = field(default_factory=set)


def _fault_plan(cfg, scanner: Scanner, flight: Flight, rec_mask: np.ndarray, rng) -> _Plan:
    fl = cfg.faults
    plan = _Plan()
    recorded = flight.t[rec_mask]
    if scanner.kind == "ldmrs":
        period = 1.0 / scanner.scan_rate_hz
        scans = np.unique(np.ceil(recorded / period - 1e-9).astype(np.int64))
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
    # line scanner: count pulses to choose fault pulses by index
    total = 0
    for t0 in np.arange(0.0, flight.duration, CHUNK_S):
        pat_t = scanner.pattern(t0, min(t0 + CHUNK_S, flight.duration))["t"]
        total += int(rec_mask[np.clip(np.round(pat_t / DT).astype(np.int64), 0, len(rec_mask) - 1)].sum())
    if fl.dust_echoes + fl.invalid_quality > total // 10:
        raise SimConfigError(f"too many faulty pulses asked for ({total} pulses in the flight)")
    pick = rng.choice(total, fl.dust_echoes + fl.invalid_quality, replace=False)
    plan.dust_pulses = set(pick[: fl.dust_echoes].tolist())
    plan.invalid_pulses = set(pick[fl.dust_echoes :].tolist())
    seconds = np.unique(np.floor(recorded).astype(np.int64))
    if fl.pps_gaps:
        interior = seconds[(seconds > seconds[0] + 1) & (seconds < seconds[-1] - 1)]
        plan.pps_gaps = set(rng.choice(interior, fl.pps_gaps, replace=False).tolist())
    return plan


def _echoes(world, frame, flight, lat_s, lon_s, pat, r_true, a_true, scanner: Scanner, range_noise, rng, plan: _Plan,
            pulse_base: int, noise_rng) -> dict[str, np.ndarray]:  # fmt: skip
    """Cast every pulse: first echo on the canopy, a second through gaps in vegetation; dust; water drop-outs."""
    t = pat["t"]
    pos, r_l_b = _poses(frame, flight, lat_s, lon_s, t)
    origin = pos + r_l_b @ a_true
    d = np.einsum("nij,nj->ni", r_l_b, pat["dir"] @ r_true.T)
    first = sc.cast(world, world.canopy, origin, d)
    hit = origin + d * first[:, None]
    ok = np.isfinite(first) & (first <= scanner.max_range_m)
    veg = ok & (
        world.sample(world.canopy, hit[:, 0], hit[:, 1]) > world.sample(world.solid, hit[:, 0], hit[:, 1]) + 0.3
    )
    cls1 = np.where(veg, sc.VEGETATION, world.class_at(hit[:, 0], hit[:, 1]))
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
    cls2 = world.class_at(hit2[:, 0], hit2[:, 1])
    pulse_id = pulse_base + np.arange(len(t))
    dust = np.isin(pulse_id, list(plan.dust_pulses)) if plan.dust_pulses else np.zeros(len(t), bool)
    if dust.any():  # the pulse is answered by a dust cloud 3-30 m away, and nothing else
        first = np.where(dust, rng.uniform(3.0, 30.0, len(t)), first)
        ok |= dust
        has2 &= ~dust
        cls1 = np.where(dust, sc.NOISE, cls1)
        hit = origin + d * first[:, None]
    n_ret = ok.astype(np.int64) + (has2 & ok)
    rows = []
    for echo, rng_true, pts, cls, sel in ((0, first, hit, cls1, ok), (1, second, hit2, cls2, has2 & ok)):
        i = np.flatnonzero(sel)
        rows.append({"pulse": i, "echo": np.full(len(i), echo), "n": n_ret[i], "range_true": rng_true[i],
                     "hit": pts[i], "cls": cls[i], "dust": dust[i]})  # fmt: skip
    e = {k: np.concatenate([r[k] for r in rows]) for k in rows[0]}
    order = np.lexsort((e["echo"], e["pulse"]))
    e = {k: v[order] for k, v in e.items()}
    e["range"] = e["range_true"] + (noise_rng.normal(0, range_noise, len(e["pulse"])) if range_noise else 0.0)
    e["pulse_id"] = pulse_base + e["pulse"]
    return e


class SimConfigError(ValueError):
    """A combination of settings that cannot be simulated (the message says which)."""


class _Sinks:
    """Streams every chunk of echoes to the formats' files and the truth."""

    def __init__(self, cfg, out: Path, crs, scanner: Scanner, plan: _Plan, start: float, to_map, nav, flight):
        self.cfg, self.out, self.crs, self.scanner, self.plan, self.start = cfg, out, crs, scanner, plan, start
        self.to_map = to_map
        self.nav, self.flight = nav, flight
        self.files: dict[str, str] = {}
        self.counts = {"pulses": 0, "echoes": 0, "echoes_by_class": {}}
        (out / "truth").mkdir(parents=True, exist_ok=True)
        self.truth = _LasSink(out / "truth" / "points.laz", crs, to_map, extra_fault=True)
        self.files["truth_points"] = "truth/points.laz"
        self.las = None
        if "las" in cfg.formats:
            (out / "las").mkdir(exist_ok=True)
            self.las = _LasSink(out / "las" / "points.laz", crs, to_map)
            self.files["las"] = "las/points.laz"
        self.ldmrs = self.lmsq = None
        if "ldmrs_mtig" in cfg.formats:
            (out / "ldmrs").mkdir(exist_ok=True)
            from dtm.commands.simulate.writers import create_text

            self.ldmrs = create_text(out / "ldmrs" / "acquisition.log.gz")
            date = cfg.start_utc[:10]
            self.ldmrs.write(
                f"# LDMRS-MTIG acquisition log v1\n# date: {date}\n# simulated by pipeline simulate, seed {cfg.seed}\n"
            )
            self.files["ldmrs_mtig"] = "ldmrs/acquisition.log.gz"
            self.scan_counts = {"scans_written": 0, "invalid_scans": 0, "bad_gps": 0, "lost_scans": 0,
                                "empty_scans": 0, "rejected_clutter": 0, "rejected_dirt": 0}  # fmt: skip
            self.dirt_left = plan.dirt_count
        if any(f in cfg.formats for f in ("lmsq_nmea", "lmsq_sbet")):
            (out / "lmsq").mkdir(exist_ok=True)
            from dtm.commands.simulate.writers import LmsqWriter

            skip = {int(start) + s for s in plan.pps_gaps}
            self.lmsq = LmsqWriter(out / "lmsq" / "scan.lmsq", scanner.model, skip)
            self.files["lmsq"] = "lmsq/scan.lmsq"
            self.lmsq_counts = {"invalid_quality": 0, "dust_echoes": 0}

    def add(self, pat, e, flight: Flight, nav_traj: RecordedPose, mounting_nominal: tuple) -> None:
        n = len(e["pulse"])
        self.counts["pulses"] += len(pat["t"])
        self.counts["echoes"] += n
        for c, k in zip(*np.unique(e["cls"], return_counts=True), strict=True):
            name = sc.CLASS_NAMES[int(c)]
            self.counts["echoes_by_class"][name] = self.counts["echoes_by_class"].get(name, 0) + int(k)
        p = e["pulse"]
        t_rel = pat["t"][p]
        gps = self.start + t_rel
        v_s = pat["dir"][p] * e["range"][:, None]
        fault = np.zeros(n, np.uint8)
        fault[e["dust"]] = FAULT_CODES["dust"]
        strip = flight.line_at(t_rel).astype(np.uint16)
        keep = np.ones(n, bool)
        if self.ldmrs is not None:
            keep, fault = self._write_ldmrs(pat, e, v_s, gps, flight, fault)
        if self.lmsq is not None:
            fault = self._write_lmsq(pat, e, gps, fault)
        cols = {"gps_time": gps, "return_number": e["echo"] + 1, "number_of_returns": e["n"],
                "scan_angle": pat["angle"][p], "scanner_channel": pat["channel"][p], "point_source_id": strip}  # fmt: skip
        sel = {k: v[keep] for k, v in cols.items()}
        self.truth.add(e["hit"][keep], classification=e["cls"][keep], fault=fault[keep], **sel)
        if self.las is not None:
            ok_for_las = keep & (fault != FAULT_CODES["invalid_quality"])  # after a missed PPS: dated by the counter
            # what the vendor's software wrote: the echoes georeferenced from the recorded navigation
            xyz = nav_traj.points(gps[ok_for_las], v_s[ok_for_las], *mounting_nominal)
            s2 = {k: v[ok_for_las] for k, v in cols.items()}
            self.las.add(xyz, classification=np.zeros(len(xyz), np.uint8), **s2)

    def _write_ldmrs(self, pat, e, v_s, gps, flight: Flight, fault):
        from dtm.commands.simulate.writers import utc_iso

        plan, fh, counts = self.plan, self.ldmrs, self.scan_counts
        leap = self.cfg.leap_seconds
        keep = np.ones(len(e["pulse"]), bool)
        scan_of_echo = pat["scan"][e["pulse"]]
        scans = np.unique(pat["scan"])
        period = 1.0 / self.scanner.scan_rate_hz
        traj = self._mtig_record
        rng = np.random.default_rng(self.cfg.seed + 7)
        bounds = np.searchsorted(scan_of_echo, scans), np.searchsorted(scan_of_echo, scans, side="right")
        for s, a, b in zip(scans, *bounds, strict=True):
            s = int(s)
            if s in plan.lost_scans:
                keep[a:b] = False  # never recorded: not in the truth either
                counts["lost_scans"] += 1
                continue
            counts["scans_written"] += 1
            t_rel = s * period
            lat, lon, h, roll, pitch, yaw, vel = traj(t_rel)
            valid, status, utc = 1, 0x07, utc_iso(self.start + t_rel, leap)
            if s in plan.invalid_scans:
                counts["invalid_scans"] += 1
                if len(plan.invalid_scans) > 1 and s % 2:
                    utc = utc[:11] + "25" + utc[13:]  # hour 25: unparseable
                else:
                    valid = 0
                fault[a:b] = FAULT_CODES["invalid_scan"]
            elif s in plan.bad_gps_scans:
                counts["bad_gps"] += 1
                status = 0x01 if s % 2 else 0x05
                fault[a:b] = FAULT_CODES["bad_gps"]
            points = []
            accepted = s not in plan.invalid_scans and s not in plan.bad_gps_scans  # as the reader will judge
            if s in plan.empty_scans:
                keep[a:b] = False
            else:
                flags = np.zeros(b - a, np.int64)
                # dirt only in scans the reader accepts (an invalid or bad-GPS scan is skipped whole)
                if self.dirt_left and b > a and accepted:
                    j = int(rng.integers(a, b))
                    flags[j - a] = 0x08
                    fault[j] = FAULT_CODES["dirt"]
                    self.dirt_left -= 1
                    counts["rejected_dirt"] += 1
                # plain Python numbers: formatting NumPy scalars one by one is several times slower
                rows = zip(pat["channel"][e["pulse"][a:b]].tolist(), e["echo"][a:b].tolist(), flags.tolist(),
                           *v_s[a:b].T.tolist(), strict=True)  # fmt: skip
                points = [P_LINE.format(*row) for row in rows]
                n_clutter = int(np.sum(plan.clutter_scans == s))
                for _ in range(n_clutter):  # dust seen by the scanner and flagged by it (not in the truth)
                    rr = rng.uniform(1.0, 8.0)
                    al = np.radians(rng.uniform(-30, 30))
                    points.append(f"P {rng.integers(0, 4)} 0 0x02 {rr * np.cos(al):.4f} {rr * np.sin(al):.4f} 0.0000")
                if n_clutter and accepted:
                    counts["rejected_clutter"] += n_clutter
            valid_points = (b - a) - int(np.sum(fault[a:b] == FAULT_CODES["dirt"]))
            if accepted and (s in plan.empty_scans or valid_points <= 0):
                counts["empty_scans"] += 1
            fh.write(f"SCAN {s % 65536}\nUTC {utc}\nSTATUS 0x{status:02X}\nVALID {valid}\n")
            fh.write(f"LLA {lat:.10f} {lon:.10f} {h:.4f}\nEULER {roll:.7f} {pitch:.7f} {yaw:.7f}\n")
            fh.write(f"VEL {vel[0]:.3f} {vel[1]:.3f} {vel[2]:.3f}\nNPOINTS {len(points)}\n")
            if points:
                fh.write("\n".join(points) + "\n")
            fh.write("END\n")
        return keep, fault

    def _mtig_record(self, t_rel: float):
        """What the MTi-G reports at a scan: LLA, Euler angles in its NWU convention, body velocity."""
        i = int(round(t_rel / DT))
        nav = self.nav
        roll, pitch, heading = nav.roll[i], nav.pitch[i], nav.heading[i]
        yaw = -((heading + 180.0) % 360.0 - 180.0)  # counter-clockwise from north
        v_enu = self.flight._pos(t_rel, 1)
        v_ned = np.array([v_enu[1], v_enu[0], -v_enu[2]])
        v_frd = attitude(*np.radians([roll, pitch, heading])).inv().apply(v_ned)[0]
        return nav.lat[i], nav.lon[i], nav.h[i], roll, -pitch, yaw, D_FLIP @ v_frd

    def _write_lmsq(self, pat, e, gps, fault):
        plan = self.plan
        n = len(e["pulse"])
        quality = np.full(n, 40, np.int64)
        bad = np.isin(e["pulse_id"], list(plan.invalid_pulses)) if plan.invalid_pulses else np.zeros(n, bool)
        quality[bad] = 0
        fault[bad] = FAULT_CODES["invalid_quality"]
        gps_us = np.round(gps * 1e6).astype(np.int64)
        second = gps_us // 1_000_000
        gap = np.isin(second - int(self.start), list(plan.pps_gaps)) if plan.pps_gaps else np.zeros(n, bool)
        fault[gap] = FAULT_CODES["pps_gap"]
        # what a reader sees: a measurement after a missed PPS is still dated by the us counter
        self.lmsq_counts["invalid_quality"] += int(bad.sum())
        self.lmsq_counts["dust_echoes"] += int((e["dust"] & ~bad).sum())
        amplitude = np.where(e["cls"] == sc.WATER, 20, np.where(e["cls"] == sc.VEGETATION, 90, 160))
        amplitude = (amplitude * (1 - 0.3 * e["echo"])).astype(np.uint8)
        self.lmsq.add(gps_us, e["range"], amplitude, pat["angle"][e["pulse"]], quality, e["echo"])
        return fault

    def close(self) -> dict:
        self.truth.close()
        if self.las is not None:
            self.las.close()
        result = {"pulses": self.counts["pulses"], "echoes": self.counts["echoes"],
                  "echoes_by_class": self.counts["echoes_by_class"]}  # fmt: skip
        if self.ldmrs is not None:
            self.ldmrs.close()
            result["ldmrs_mtig"] = self.scan_counts
        if self.lmsq is not None:
            self.lmsq.close()
            result["lmsq"] = {**self.lmsq_counts, "pps_gaps": len(self.plan.pps_gaps),
                              "missed_pps": self.lmsq.skipped_measurements,
                              "pps_recovered": self.lmsq.recoverable}  # fmt: skip
        return result


class _LasSink:
    """A LAZ written chunk by chunk (laspy + lazrs), LAS 1.4 point format 6, 0.1 mm scale."""

    def __init__(self, path: Path, crs, to_map, *, extra_fault: bool = False):
        self.path, self.crs, self.to_map, self.extra_fault = path, crs, to_map, extra_fault
        self.writer = None

    def add(self, xyz: np.ndarray, *, classification, fault=None, **cols) -> None:
        import laspy

        if len(xyz) == 0:
            return
        pts = self.to_map(xyz)  # local ENU -> output CRS
        if self.writer is None:
            from dtm.common.clouds import point_header

            # later chunks lie elsewhere in the survey: a kilometre of margin below, and the scale
            # chosen for 200 km around the first chunk
            lo = pts.min(axis=0) - np.array([0.0, 0.0, 1000.0])
            header = point_header(self.crs, lo, pts.max(axis=0))
            if self.extra_fault:
                header.add_extra_dim(laspy.ExtraBytesParams(name="fault", type=np.uint8,
                                                            description="simulator: why a reader drops it"))  # fmt: skip
            header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
            self.writer = laspy.open(self.path, mode="w", header=header, do_compress=True,
                                     laz_backend=laspy.LazBackend.Lazrs)  # fmt: skip
            self.header = header
        rec = laspy.ScaleAwarePointRecord.zeros(len(pts), header=self.header)
        rec.x, rec.y, rec.z = pts[:, 0], pts[:, 1], pts[:, 2]
        rec.gps_time = cols["gps_time"] - 1e9  # adjusted standard GPS time (LAS 1.4)
        rec.return_number = cols["return_number"]
        rec.number_of_returns = cols["number_of_returns"]
        rec.scan_angle = np.round(np.asarray(cols["scan_angle"]) / 0.006).astype(np.int16)
        rec.scanner_channel = cols["scanner_channel"]
        rec.point_source_id = cols["point_source_id"]
        rec.classification = classification
        if self.extra_fault:
            rec.fault = fault
        self.writer.write_points(rec)

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()


def _write_navigation(cfg, out: Path, nav: Navigation, flight: Flight, start: float) -> dict[str, str]:
    """NMEA, INS CSV, SBET and smrmsg from the recorded navigation; ``nmea_bad_checksums`` corrupts
    GGA/HDT/VTG/GST sentences (never ZDA: without a date the log cannot be read at all)."""
    from dtm.commands.simulate.writers import SECONDS_PER_WEEK, wrap_pi, write_ins_csv, write_nmea, write_sbet

    files = {}
    if any(f in cfg.formats for f in ("lmsq_nmea", "lmsq_sbet")):
        step = max(1, int(round(1.0 / (cfg.navigation.gnss_rate_hz * DT))))
        gps = start + nav.t
        sow = np.mod(gps, SECONDS_PER_WEEK)
        sel = slice(0, None, step)
        vel = flight._pos(nav.t, 1)
        course = np.degrees(np.arctan2(vel[:, 0], vel[:, 1]))
        speed = np.hypot(vel[:, 0], vel[:, 1])
        sigma = np.full(len(gps), max(nav.sigma_pos, 0.01))
        rng = np.random.default_rng(cfg.seed + 11)
        k = cfg.faults.nmea_bad_checksums
        corrupt = set(rng.choice(4 * len(gps[sel]), k, replace=False).tolist()) if k else set()
        write_nmea(out / "lmsq" / "nav.nmea", gps[sel], nav.lat[sel], nav.lon[sel], nav.h[sel], nav.heading[sel],
                   course[sel], speed[sel], sigma[sel], leap_seconds=cfg.leap_seconds, corrupt=corrupt)  # fmt: skip
        ins = slice(0, None, max(1, int(round(1.0 / (cfg.navigation.ins_rate_hz * DT)))))
        unwrapped = cfg.navigation.unwrapped_heading
        write_ins_csv(out / "lmsq" / "ins.csv", sow[ins], nav.roll[ins], nav.pitch[ins], nav.heading[ins],
                      unwrapped=unwrapped)  # fmt: skip
        files.update(nmea="lmsq/nav.nmea", ins="lmsq/ins.csv")
        gps, sow, vel = gps[ins], sow[ins], vel[ins]
        nav = Navigation(nav.t[ins], nav.lat[ins], nav.lon[ins], nav.h[ins], nav.roll[ins], nav.pitch[ins],
                         nav.heading[ins], nav.sigma_pos, nav.sigma_att)  # fmt: skip
        wander = np.radians(10.0) + 1e-4 * nav.t  # a wander azimuth that drifts, as a wander-azimuth INS does
        sbet = np.zeros((len(gps), 17))
        sbet[:, 0] = sow
        sbet[:, 1], sbet[:, 2], sbet[:, 3] = np.radians(nav.lat), np.radians(nav.lon), nav.h
        sbet[:, 4], sbet[:, 5], sbet[:, 6] = vel[:, 1], vel[:, 0], -vel[:, 2]
        sbet[:, 7], sbet[:, 8] = np.radians(nav.roll), np.radians(nav.pitch)
        sbet[:, 9] = np.radians(nav.heading) + wander  # platform heading = true heading + wander
        sbet[:, 10] = wander
        if not unwrapped:  # as an SBET holds them: (-pi, pi]
            sbet[:, 9:11] = wrap_pi(sbet[:, 9:11])
        write_sbet(out / "lmsq" / "trajectory.sbet", sbet)
        smr = np.zeros((len(gps), 10))
        smr[:, 0] = sow
        smr[:, 1:4] = max(nav.sigma_pos, 0.01)
        smr[:, 4:7] = 0.01
        smr[:, 7:10] = max(nav.sigma_att, 1e-4) * 60.0  # arc-minutes
        write_sbet(out / "lmsq" / "trajectory.smrmsg", smr)
        files.update(sbet="lmsq/trajectory.sbet", smrmsg="lmsq/trajectory.smrmsg")
    return files


def _ground_height(world, frame: Earth, crs, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Height in the output CRS where the vertical through (x, y) meets the bare earth, and the local (e, n)."""
    import pyproj

    from_crs = pyproj.Transformer.from_crs(crs, "EPSG:4978", always_xy=True)
    h = np.full(len(x), frame.h0)
    for _ in range(5):
        ex, ey, ez = from_crs.transform(x, y, h)
        local = frame.from_ecef(np.column_stack((ex, ey, ez)))
        g = world.sample(world.ground, local[:, 0], local[:, 1])
        h = h - (local[:, 2] - np.nan_to_num(g))
    return np.where(np.isfinite(g), h, np.nan), local


def _write_checkpoints(path: Path, world, frame: Earth, crs, on_lines: np.ndarray, n: int, rng) -> None:
    """GNSS-style check points on the true terrain: two thirds in the open, one third under trees.

    Drawn under the flown lines (so the DTM covers them), at least 5 m from
    buildings, water, the bridge, breaklines and slopes over 20 %, as a
    surveyor would place them.
    """
    from scipy.ndimage import binary_dilation

    gy, gx = np.gradient(world.ground, world.cell)
    steep = np.hypot(gx, gy) > 0.2  # breaklines and steep slopes: no check point within 5 m (ASPRS practice)
    structures = binary_dilation((world.cls != sc.GROUND) | steep, iterations=int(5 / world.cell))
    trees = world.canopy > world.solid + 0.5
    rows = []
    tries = 0
    while len(rows) < n and tries < 200 * n:
        tries += 1
        k = int(rng.integers(len(on_lines)))
        e, nn = on_lines[k, 0] + rng.uniform(-20, 20), on_lines[k, 1] + rng.uniform(-20, 20)
        ix, iy = int((e - world.e0) / world.cell), int((nn - world.n0) / world.cell)
        if not (0 <= iy < world.cls.shape[0] and 0 <= ix < world.cls.shape[1]) or structures[iy, ix]:
            continue
        want_tree = len(rows) % 3 == 2
        if bool(trees[iy, ix]) != want_tree:
            continue
        rows.append((e, nn, "vegetated" if want_tree else "open"))
    local = np.array([[r[0], r[1], 0.0] for r in rows])
    ecef = frame.to_ecef(local)
    import pyproj

    x, y, _ = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True).transform(
        ecef[:, 0], ecef[:, 1], ecef[:, 2]
    )
    z, _ = _ground_height(world, frame, crs, np.asarray(x), np.asarray(y))
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(f"# true terrain of the simulated survey; {crs.to_string()}, ellipsoidal heights, metres\n")
        fh.write("id,x,y,z,land_cover\n")
        for i, (xi, yi, zi, r) in enumerate(zip(x, y, z, rows, strict=True), 1):
            fh.write(f"CP{i:03d},{xi:.3f},{yi:.3f},{zi:.3f},{r[2]}\n")


def _write_truth_terrain(folder: Path, world, frame: Earth, crs, extent, resolution: float) -> None:
    """The bare earth on a grid of the output CRS, and what covers it, on the same cells.

    ``terrain.tif``: for each cell centre, the height where the vertical meets
    the ground.  ``land_cover.tif`` (uint8, ASPRS class codes, 0 = outside the
    scene): the class of the solid surface there (2 ground, 6 building,
    9 water, 17 bridge deck), 5 where tree crowns stand more than 0.5 m above
    it (the rule the check points' "vegetated" follows).
    """
    import pyproj

    from dtm.common.rasters import NODATA, write_cog

    corners = np.array([[extent[0], extent[2], 0.0], [extent[1], extent[2], 0.0],
                        [extent[0], extent[3], 0.0], [extent[1], extent[3], 0.0]])  # fmt: skip
    to_crs = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True)
    ec = frame.to_ecef(corners)
    cx, cy, _ = to_crs.transform(ec[:, 0], ec[:, 1], ec[:, 2])
    x0 = np.ceil(min(cx) / resolution) * resolution
    y1 = np.floor(max(cy) / resolution) * resolution
    nx = int((np.floor(max(cx) / resolution) * resolution - x0) / resolution)
    ny = int((y1 - np.ceil(min(cy) / resolution) * resolution) / resolution)
    xs = x0 + (np.arange(nx) + 0.5) * resolution
    ys = y1 - (np.arange(ny) + 0.5) * resolution
    X, Y = np.meshgrid(xs, ys)
    h, local = _ground_height(world, frame, crs, X.ravel(), Y.ravel())
    z = np.where(np.isfinite(h), h, NODATA).reshape(ny, nx)
    from rasterio.transform import from_origin

    transform = from_origin(x0, y1, resolution, resolution)
    write_cog(folder / "terrain.tif", z.astype(np.float32), transform=transform, crs=crs)
    e, n = local[:, 0], local[:, 1]
    cover = world.class_at(e, n).astype(np.uint8)
    trees = world.sample(world.canopy, e, n) > world.sample(world.solid, e, n) + 0.5
    cover = np.where(trees, sc.VEGETATION, cover)
    cover = np.where(np.isfinite(h), cover, 0).reshape(ny, nx).astype(np.uint8)
    write_cog(folder / "land_cover.tif", cover, transform=transform, crs=crs, nodata=0, dtype="uint8", unit=None)
