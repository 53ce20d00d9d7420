"""The ``pipeline simulate`` configuration (``configs/simulate.yaml``): typed, with every default named.

Sensor and navigation presets come from the seeds: the LD-MRS and MTi-G of
seed 0, the RIEGL scanners and INS units of seed 2 (read from the budget's
equipment catalogue, ``commands/budget/catalogue.yaml``, so there is one
source for each figure).
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from pipeline.config import RelPath, StrictModel

FORMATS = ("ldmrs_mtig", "lmsq_nmea", "lmsq_sbet", "las")


class SimConfigError(ValueError):
    """A combination of settings that cannot be simulated (the message says which)."""


class Origin(StrictModel):
    lat: float = Field(40.4168, ge=-85, le=85, description="latitude of the scene centre, degrees (WGS 84)")
    lon: float = Field(-3.7038, ge=-180, le=180, description="longitude of the scene centre, degrees (WGS 84)")
    h: float = Field(650.0, description="ellipsoidal height of the local frame's origin, metres")


class ScannerConfig(StrictModel):
    preset: Literal["ldmrs", "q140", "q280"] = Field(
        "q140", description="ldmrs (seed 0 SICK LD-MRS), q140 / q280 (seed 2 RIEGL LMS-Q140i / LMS-Q280)"
    )
    pulse_rate_hz: float | None = Field(None, gt=0, description="line scanners: pulses per second (preset)")
    scan_rate_hz: float | None = Field(None, gt=0, description="lines (RIEGL) or scans (LD-MRS) per second (preset)")
    half_angle_deg: float | None = Field(None, gt=0, lt=80, description="half the field of view (preset)")
    angle_step_deg: float = Field(0.5, gt=0, description="LD-MRS: horizontal angular step, degrees")
    range_noise_m: float | None = Field(None, ge=0, description="1-sigma range noise, metres (preset)")
    max_range_m: float | None = Field(None, gt=0, description="farthest echo recorded, metres (preset)")


class NavigationConfig(StrictModel):
    preset: Literal["mtig", "igg", "novatel-bds", "pos-av-310", "pos-av-410", "pos-av-510"] = Field(
        "pos-av-410", description="GNSS/INS preset (position and attitude sigma of the seeds)"
    )
    position_noise_m: float | None = Field(
        None, ge=0, description="1-sigma position error per axis, smooth (see error_period_s), metres (preset)"
    )
    attitude_noise_deg: float | None = Field(
        None, ge=0, description="1-sigma attitude error per angle, smooth, degrees (preset)"
    )
    gnss_rate_hz: float = Field(20.0, gt=0, le=200, description="NMEA position rate, Hz (a divisor of 200)")
    ins_rate_hz: float = Field(200.0, gt=0, le=200, description="INS CSV and SBET rate, Hz (a divisor of 200)")
    error_period_s: float = Field(
        20.0, gt=0, description="shortest period of the position error, seconds (attitude: a quarter of it)"
    )
    unwrapped_heading: bool = Field(
        False,
        description="INS CSV and SBET headings written unwrapped (continuous through north, beyond +-180 deg) "
        "instead of as receivers write them (INS CSV [0, 360) deg; SBET heading and wander (-pi, pi])",
    )


class FlightConfig(StrictModel):
    altitude_m: float = Field(300.0, gt=0, description="flying height above the scene's mean ground, metres")
    speed_ms: float = Field(60.0, gt=0, description="ground speed, m/s")
    lines: int = Field(5, ge=1, description="parallel flight lines")
    sidelap: float = Field(0.4, ge=0, lt=1, description="overlap of neighbouring swaths, fraction of the swath")
    line_length_m: float = Field(600.0, gt=0, description="length of each parallel line, metres")
    heading_deg: float = Field(0.0, description="direction of the first line, degrees clockwise from north")
    cross_line: bool = Field(True, description="add a line across the others")
    one_way: bool = Field(
        False, description="fly every parallel line in the first line's direction (default: alternating)"
    )
    second_altitude_m: float | None = Field(
        None,
        gt=0,
        description="fly the middle line again, there and back, at this height: with the alternating lines and the "
        "cross line, a calibration flight (docs/CALIBRATION.md); default: no such line",
    )
    level_attitude: bool = Field(
        False,
        description="roll and pitch exactly 0 on the lines (no oscillation, no nose-up pitch; the bank in turns and "
        "the crab angle stay); with scene.terrain: flat, the geometry where pitch and yaw boresight errors only move "
        "points horizontally",
    )
    bank_deg: float = Field(30.0, gt=0, lt=60, description="bank angle in turns (sets the turn radius)")
    lead_in_m: float = Field(50.0, ge=0, description="straight flight before and after each line, metres")


class SceneConfig(StrictModel):
    terrain: Literal["default", "flat"] = Field(
        "default",
        description="default: hills, slopes, a terrace, a river falling 0.3 % eastwards with a bridge (a 6 m deck straight from the ground at one end of "
        "the banks to the ground at the other, its approaches level with it), buildings and trees; flat: level bare "
        "ground at the origin's height (local 0), nothing on it",
    )
    water: Literal["default", "lbs"] = Field(
        "default",
        description="default: the river max(12 m, 6 % of the scene's height) wide; lbs: water the USGS Lidar Base "
        "Specification hydro-flattens: the river 31 m wide (its 100 ft) and a round lake of 8,495 m² (its 2 acres: "
        "8,094 m²) north of it, in a scene of at least 350 m each way",
    )


class Faults(StrictModel):
    """Everything injected; each is counted in truth/faults.json."""

    noise: bool = Field(True, description="range, position and attitude noise on (false: a zero-noise flight)")
    invalid_utc_scans: int = Field(0, ge=0, description="3.A: scans with VALID 0 or an unparseable UTC")
    bad_gps_scans: int = Field(0, ge=0, description="3.A: scans whose STATUS lacks the XKF-valid or GPS-fix bit")
    lost_scans: int = Field(0, ge=0, description="3.A: scans dropped from the log (counter jumps)")
    empty_scans: int = Field(0, ge=0, description="3.A: scans with no point")
    clutter_points: int = Field(0, ge=0, description="3.A: dust/rain echoes flagged clutter by the scanner")
    dirt_points: int = Field(0, ge=0, description="3.A: points flagged dirt")
    dust_echoes: int = Field(0, ge=0, description="lmsq/LAS: pulses answered by dust close to the aircraft")
    pps_gaps: int = Field(
        0, ge=0, description="lmsq: PPS records missing (their second of pulses is dated by the us counter alone)"
    )
    invalid_quality: int = Field(0, ge=0, description="lmsq: measurements with quality 0")
    nmea_bad_checksums: int = Field(0, ge=0, description="NMEA sentences with a corrupted checksum")
    strip_bias_m: float = Field(0.0, ge=0, description="per-line GNSS bias, largest component, metres")
    strip_rotation_deg: float = Field(
        0.0, ge=0, description="per-line roll and pitch bias, largest component, degrees (rigid for a straight strip)"
    )
    error_free_lines: list[int] = Field(
        [], description="lines (1-based) flown without per-line bias or rotation, e.g. a reference for the datum"
    )
    boresight_error_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="true minus configured boresight roll, pitch, yaw, degrees"
    )
    lever_arm_error_m: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="true minus configured lever arm, metres"
    )


class SimulateConfig(StrictModel):
    name: str = Field("simulated", description="survey name (file names)")
    output: RelPath = Field(..., description="folder to write, relative to this file")
    seed: int = Field(1, description="random seed: the same seed gives the same files")
    noise_seed: int | None = Field(
        None,
        description="seed of the noise alone (default: from seed): other values give other noise on the same echoes",
    )
    formats: list[Literal["ldmrs_mtig", "lmsq_nmea", "lmsq_sbet", "las"]] = Field(
        list(FORMATS), description="formats to write (ldmrs_mtig needs the ldmrs scanner; the others a RIEGL)"
    )
    origin: Origin = Field(default_factory=Origin)
    start_utc: str = Field("2026-06-21T10:00:00Z", description="UTC start of the flight (ISO 8601)")
    leap_seconds: float = Field(18.0, description="GPS - UTC, seconds")
    crs: str = Field("auto-utm", description="CRS of the LAS and truth files (auto-utm: WGS 84 / UTM of the origin)")
    scanner: ScannerConfig = Field(default_factory=ScannerConfig)
    navigation: NavigationConfig = Field(default_factory=NavigationConfig)
    mounting: Literal["laboratorio", "pilatus", "cb5000"] = Field(
        "cb5000", description="3.A: seed-0 Table 15 lever arm (LD-MRS -> MTi-G is also Ry(+90 deg))"
    )
    boresight_deg: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="lmsq: configured boresight roll, pitch, yaw (scanner -> body), degrees"
    )
    lever_arm_m: tuple[float, float, float] = Field(
        (0.1, 0.0, 0.25), description="lmsq: configured lever arm (body x fwd, y right, z down), metres"
    )
    scene: SceneConfig = Field(default_factory=SceneConfig)
    flight: FlightConfig = Field(default_factory=FlightConfig)
    faults: Faults = Field(default_factory=Faults)
    truth_resolution: float = Field(1.0, gt=0, description="cell of truth/terrain.tif, metres")
    checkpoints: int = Field(40, ge=0, description="check points on the true terrain written to checkpoints.csv")

    @property
    def writes_lmsq(self) -> bool:
        """The RIEGL stream and its navigation files are written (format 3.B or 3.C)."""
        return any(f in self.formats for f in ("lmsq_nmea", "lmsq_sbet"))


class SimulateFile(StrictModel):
    """A simulation file with several named surveys, each with its own ``output``."""

    surveys: dict[str, SimulateConfig] = Field(description="name -> survey; each is written to its own output")
