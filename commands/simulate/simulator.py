"""``pipeline simulate``: one survey with known truth, in every raw format (SPEC 10).

The scene and the flight live in a local ENU frame tangent to WGS 84 at the
configured origin.  Each pulse is cast from the true pose and the *true*
mounting (configured + injected error); its range, with noise, is recorded
in the scanner's frame; the navigation files get the true trajectory plus
the configured errors; the truth is the ray's hit point, taken to the output
CRS with PROJ point by point.

Written (``<output>/``): ``ldmrs/acquisition.log.gz`` (3.A), ``lmsq/scan.lmsq``
+ ``lmsq/nav.nmea`` + ``lmsq/ins.csv`` (3.B), ``lmsq/trajectory.sbet`` +
``lmsq/trajectory.smrmsg`` (3.C, same stream), ``las/points.laz`` (3.D),
``truth/points.laz``, ``truth/terrain.tif``, ``truth/land_cover.tif``, ``truth/breaklines.gpkg``,
``truth/faults.json``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import numpy as np
import pyproj

from commands.simulate import scene as sc
from commands.simulate.echoes import Survey, echoes
from commands.simulate.faults import CHUNK_S, FaultPlan, fault_plan
from commands.simulate.flight import Flight, fly, plan_lines, recorded, recording_mask
from commands.simulate.forward import D_FLIP, Earth, RecordedPose, mounting_matrix
from commands.simulate.navigation import Navigation, bias_table, recorded_navigation, write_navigation
from commands.simulate.reference import TABLE_15_MOUNTINGS, gps_seconds, utm_epsg
from commands.simulate.sensors import Scanner, make_scanner, navigation_sigmas
from commands.simulate.settings import SimConfigError, SimulateConfig
from commands.simulate.sinks import Sinks
from commands.simulate.truth import write_checkpoints, write_truth_breaklines, write_truth_terrain


@dataclass
class SimResult:
    """What was written, the fault counts (as in faults.json), and the recorded navigation at 200 Hz."""

    output: Path
    faults: dict
    files: dict[str, str] = field(default_factory=dict)
    navigation: Navigation | None = None
    gps_start: float = 0.0


@dataclass(frozen=True)
class Mounting:
    """The scanner's mounting: as configured (what the files' users are told) and as it truly flew."""

    nominal: tuple[np.ndarray, np.ndarray]  # R_body<-scanner (3, 3) and lever arm (3,), body axes, configured
    true: tuple[np.ndarray, np.ndarray]  # the same, with the injected boresight and lever-arm errors


def simulate(cfg: SimulateConfig) -> SimResult:
    """Run the simulation described by a :class:`~commands.simulate.settings.SimulateConfig`.

    The steps: the scanner, the flight plan flown and the scene under it, the
    mounting, the recorded navigation, the faults, every pulse cast and
    written chunk by chunk, then the navigation files and the truth.  The
    random draws follow that order, so a seed gives the same files.
    """
    out = Path(cfg.output)
    rng = np.random.default_rng(cfg.seed)
    # noise has its own stream: realisations with another noise_seed see the same scene, flight and echoes
    noise_rng = np.random.default_rng([cfg.seed, 1, cfg.noise_seed if cfg.noise_seed is not None else cfg.seed])
    scanner = _scanner(cfg)
    noise = cfg.faults.noise
    sigmas = navigation_sigmas(cfg.navigation) if noise else (0.0, 0.0)
    range_noise = scanner.range_noise_m if noise else 0.0
    frame = Earth(cfg.origin.lat, cfg.origin.lon, cfg.origin.h)  # the simulator's own geometry (forward.py)
    crs = truth_crs(cfg.crs, cfg.origin.lon, cfg.origin.lat)
    flight, recording, extent = _flight(cfg, scanner)
    if cfg.scene.water == "lbs" and min(extent[1] - extent[0], extent[3] - extent[2]) < sc.LBS_EXTENT:
        raise SimConfigError(
            f"scene.water: lbs needs a scene of {sc.LBS_EXTENT:g} m each way, and the flight covers "
            f"{extent[1] - extent[0]:.0f} x {extent[3] - extent[2]:.0f} m: lengthen flight.line_length_m or add "
            "flight.lines"
        )
    world = sc.make_scene(extent, seed=cfg.seed, terrain=cfg.scene.terrain, water=cfg.scene.water)
    lat_s, lon_s, _ = frame.geodetic(flight.pos)
    mounting = _mounting(cfg, scanner)
    nav, bias, att_bias = recorded_navigation(cfg, frame, flight, sigmas, rng, noise_rng)
    start = start_seconds(cfg.start_utc, cfg.leap_seconds)
    faults = {
        "seed": cfg.seed,
        "noise": noise,
        "range_noise_m": range_noise,
        "position_noise_m": sigmas[0],
        "attitude_noise_deg": sigmas[1],
        "strip_bias_m": cfg.faults.strip_bias_m,
        "line_biases_m": bias_table(flight, bias),
        "line_attitude_biases_deg": bias_table(flight, att_bias),
        "boresight_error_deg": list(cfg.faults.boresight_error_deg),
        "lever_arm_error_m": list(cfg.faults.lever_arm_error_m),
        "gps_start": start,
        "crs": crs.to_string(),
    }
    plan = fault_plan(cfg, scanner, flight, recording, rng)
    out.mkdir(parents=True, exist_ok=True)
    sinks = Sinks(cfg, out, frame.to_crs(crs), scanner, plan, start, nav, flight)
    survey = Survey(world, frame, flight, lat_s, lon_s, scanner, *mounting.true, range_noise=range_noise)
    nav_traj = RecordedPose(frame, start + nav.t, nav.lat, nav.lon, nav.h, nav.roll, nav.pitch, nav.heading)
    _fly_pulses(survey, recording, plan, sinks, nav_traj, mounting, rng, noise_rng)
    faults.update(sinks.close())
    files = sinks.files
    files.update(write_navigation(cfg, out, nav, flight, start))
    if "lmsq" in faults:
        faults["lmsq"]["nmea_bad_checksums"] = cfg.faults.nmea_bad_checksums
    ground_xy = np.concatenate(sinks.ground_on_lines) if sinks.ground_on_lines else np.zeros((0, 2))
    files.update(_write_truth(cfg, out, world, frame, crs, extent, rng, ground_xy))
    faults["files"] = files
    (out / "truth" / "faults.json").write_text(json.dumps(faults, indent=2) + "\n")
    return SimResult(out, faults, files, nav, start)


def _scanner(cfg: SimulateConfig) -> Scanner:
    """The configured scanner, checked against the formats it must write."""
    scanner = make_scanner(cfg.scanner)
    if scanner.kind == "ldmrs" and cfg.writes_lmsq:
        raise SimConfigError("formats lmsq_nmea and lmsq_sbet need a RIEGL scanner (scanner.preset q140 or q280)")
    if scanner.kind == "line" and "ldmrs_mtig" in cfg.formats:
        raise SimConfigError("format ldmrs_mtig needs scanner.preset: ldmrs")
    return scanner


def truth_crs(setting: str, lon: float, lat: float) -> pyproj.CRS:
    """The projected CRS of the simulated LAS and truth files: *setting*, or the WGS 84 / UTM zone of the origin."""
    crs = pyproj.CRS.from_epsg(utm_epsg(lon, lat)) if setting == "auto-utm" else pyproj.CRS.from_user_input(setting)
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    if not horizontal.is_projected:
        raise SimConfigError(f"crs {crs.name} is not projected; choose a projected CRS or auto-utm")
    return crs


def start_seconds(start_utc: str, leap: float) -> float:
    """GPS seconds of the flight's start, a whole second given in ISO 8601 UTC."""
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


def _flight(cfg: SimulateConfig, scanner: Scanner) -> tuple[Flight, np.ndarray, tuple[float, float, float, float]]:
    """The flight plan flown; when the scanner records; the extent of the scene (the swaths and 20 m around)."""
    f = cfg.flight
    swath = 2 * f.altitude_m * np.tan(np.radians(scanner.half_angle_deg))
    spacing = swath * (1 - f.sidelap)
    lines = plan_lines(
        (0.0, 0.0),
        f.lines,
        spacing,
        f.line_length_m,
        f.heading_deg,
        f.cross_line,
        one_way=f.one_way,
        second_altitude=f.second_altitude_m,
    )
    flight = fly(
        lines,
        altitude=f.altitude_m,
        speed=f.speed_ms,
        bank_deg=f.bank_deg,
        lead_in=f.lead_in_m,
        seed=cfg.seed,
        level=f.level_attitude,
    )
    # RIEGL systems record on the lines (and lead-ins); the seed-0 LD-MRS logs the whole flight
    recording = recording_mask(flight, f.lead_in_m / f.speed_ms if scanner.kind == "line" else None)
    if not recording.any():
        raise SimConfigError("the flight is too short to record anything (make the lines longer)")
    on_lines = flight.pos[recording]
    margin = swath / 2 + 20.0
    e_min, e_max = on_lines[:, 0].min() - margin, on_lines[:, 0].max() + margin
    n_min, n_max = on_lines[:, 1].min() - margin, on_lines[:, 1].max() + margin
    return flight, recording, (e_min, e_max, n_min, n_max)


def _mounting(cfg: SimulateConfig, scanner: Scanner) -> Mounting:
    """The configured mounting, and the true one (configured + the faults' boresight and lever-arm errors)."""
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
    return Mounting((r_nominal, a_nominal), (r_true, a_true))


def _fly_pulses(
    survey: Survey,
    recording: np.ndarray,
    plan: FaultPlan,
    sinks: Sinks,
    nav_traj: RecordedPose,
    mounting: Mounting,
    rng: np.random.Generator,
    noise_rng: np.random.Generator,
) -> None:
    """Every recorded pulse of the flight, CHUNK_S seconds at a time: cast, then written by *sinks*."""
    t_end = survey.flight.duration
    t0 = 0.0
    pulse_base = 0
    while t0 < t_end:
        t1 = min(t0 + CHUNK_S, t_end)
        pat = survey.scanner.pattern(t0, t1)
        keep = recorded(recording, pat["t"])
        pat = {k: v[keep] for k, v in pat.items()}
        n = len(pat["t"])
        if n:
            e = echoes(survey, pat, pulse_base, plan, rng, noise_rng)
            sinks.add(pat, e, nav_traj, mounting.nominal)
        pulse_base += n
        t0 = t1


def _write_truth(
    cfg: SimulateConfig,
    out: Path,
    world: sc.Scene,
    frame: Earth,
    crs: pyproj.CRS,
    extent: tuple[float, float, float, float],
    rng: np.random.Generator,
    ground_xy: np.ndarray,
) -> dict[str, str]:
    """The true terrain and land cover, and the check points (where *ground_xy*, the lines' ground echoes, are);
    the files written."""
    files = {"truth_terrain": "truth/terrain.tif", "truth_land_cover": "truth/land_cover.tif"}
    write_truth_terrain(out / "truth", world, frame, crs, extent, cfg.truth_resolution)
    if world.river is not None or world.lakes:
        write_truth_breaklines(out / "truth", world, frame, crs, extent)
        files["truth_breaklines"] = "truth/breaklines.gpkg"
    if cfg.checkpoints:
        write_checkpoints(out / "checkpoints.csv", world, frame, crs, ground_xy, cfg.checkpoints, rng)
        files["checkpoints"] = "checkpoints.csv"
    return files
