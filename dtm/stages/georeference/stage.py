"""Stage ``georeference``: trajectory + pulses -> points in the output CRS (SPEC 4).

The algorithm (direct georeferencing, exact geodesy, SLERP) is in
:mod:`dtm.common.georeferencing`; this driver reads the parse stage's columns,
segments the flight into strips, streams the pulses through the algorithm
in batches and writes the point cloud (LAS 1.4, point format 6):
``gps_time`` (adjusted standard GPS time, GPS seconds - 1e9, as LAS 1.4
requires), return number and count, intensity (amplitude x 257),
scan angle, scanner channel (LD-MRS layer), strip id in
``point_source_id``.

Frames (``frame``):

- ``exact`` (default): ECEF, then PROJ to ``crs`` (``auto-utm``: the WGS 84
  / UTM zone of the first fix); heights ellipsoidal, or orthometric with a
  ``geoid`` grid.
- ``ltp``: the seed-0 local tangent plane, one NWU plane at the first fix:
  E = R (lon - lon0) cos lat0, N = R (lat - lat0), U = h, with the offsets
  of every pulse added in that one plane (flat earth).  Written with the
  equivalent PROJ definition (``+proj=eqc`` on a sphere of radius R), so
  GIS software places it.

In both modes the largest difference between ``ltp`` and the exact local
tangent plane over the survey is measured and reported
(``ltp_vs_exact_*`` metrics); the seed claims it is negligible under 1 km.
"""

from __future__ import annotations

from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from dtm.common.georeferencing import LAS_GPS_OFFSET, ltp_crs, prepare_exact, prepare_ltp
from pipeline.config import InputFile, StrictModel
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext, StageParams


class StripParams(StrictModel):
    turn_rate_deg_s: float = Field(1.0, gt=0, description="a turn rate above this (deg/s, smoothed over 2 s) is a turn")
    min_line_s: float = Field(10.0, ge=0, description="a steady-heading run shorter than this (s) is not a strip")
    keep_turns: bool = Field(False, description="keep the points flown in turns (strip id 0); default: drop and count")


class UncertaintyParams(StrictModel):
    """One-sigma errors for the per-point propagated uncertainty (none is guessed)."""

    range_m: float = Field(gt=0, description="scanner range error, metres (e.g. 0.025 for the LMS-Q140i)")
    scan_angle_deg: float = Field(ge=0, description="scanner angle error, degrees (e.g. 0.005 for the LMS-Q140i)")
    position_m: float | None = Field(
        None, gt=0, description="position error per axis, metres; default: the trajectory's own sigmas (GST, smrmsg)"
    )
    attitude_deg: float | None = Field(
        None, gt=0, description="roll, pitch and heading error, degrees; default: the trajectory's sigmas (smrmsg)"
    )
    boresight_deg: float = Field(0.0, ge=0, description="boresight calibration error, degrees (0: treated as exact)")
    lever_arm_m: float = Field(0.0, ge=0, description="lever-arm measurement error per axis, metres (0: exact)")


class GeoreferenceParams(StageParams):
    frame: Literal["exact", "ltp"] = Field(
        "exact", description="exact (PROJ to crs) or ltp (seed-0 local tangent plane)"
    )
    max_gap_s: float = Field(
        0.5, gt=0, description="pulses inside a gap of the trajectory longer than this get no position, seconds"
    )
    geoid: InputFile | None = Field(
        None, description="geoid grid (GeoTIFF/GTX, PROJ vgridshift) for orthometric heights"
    )
    ltp_radius_m: float = Field(6_371_000.0, gt=0, description="ltp: the Earth radius R of the seed-0 formula, metres")
    strips: StripParams = Field(default_factory=StripParams)
    batch_size: int = Field(2_000_000, ge=10_000, description="pulses georeferenced per batch (memory ~ 200 B each)")
    uncertainty: UncertaintyParams | None = Field(
        None,
        description="per-point propagated uncertainty (LAS extra bytes sigma_horizontal, sigma_vertical); off when absent",
    )


def _epoch_sigmas(u: UncertaintyParams, traj: dict) -> dict:
    """Per-epoch position (m, east north up) and attitude (rad, roll pitch heading) sigmas: from the
    configuration, else from the trajectory's columns; neither is an error naming the key to set."""
    from pipeline.errors import ConfigError

    n = len(traj["time"])
    out = {"sources": {}}
    wanted = (
        ("position", u.position_m, 1.0, ("sigma_east_m", "sigma_north_m", "sigma_up_m"), "position_m",
         "no position sigmas (no $GST, no smrmsg)"),
        ("attitude", u.attitude_deg, np.pi / 180, ("sigma_roll_deg", "sigma_pitch_deg", "sigma_heading_deg"),
         "attitude_deg", "no attitude sigmas (only smrmsg files carry them)"),
    )  # fmt: skip
    for name, stated, scale, columns, key, missing in wanted:
        if stated is not None:
            out[name] = tuple(np.full(n, stated * scale) for _ in range(3))
            out["sources"][name] = "configuration"
        elif all(c in traj for c in columns):
            out[name] = tuple(np.asarray(traj[c], dtype=np.float64) * scale for c in columns)
            out["sources"][name] = "trajectory"
        else:
            raise ConfigError(
                f"stages.georeference.uncertainty.{key}: the trajectory has {missing}, so state the {name} error."
            )
    return out


def _propagate(traj, t, cols, mounting, p, sigmas, scan_axis):
    from dtm.common.georeferencing import locate
    from dtm.stages.georeference.uncertainty import Sigmas, propagate

    i, f, _ = locate(traj, t, float("inf"))
    u = p.uncertainty
    sig = Sigmas(
        range_m=u.range_m, scan_angle_rad=np.radians(u.scan_angle_deg),
        position_enu_m=tuple(c[i] for c in sigmas["position"]), attitude_rad=tuple(c[i] for c in sigmas["attitude"]),
        boresight_rad=np.radians(u.boresight_deg), lever_arm_m=u.lever_arm_m,
    )  # fmt: skip
    return propagate(traj, i, f, tuple(cols), mounting, sig, scan_axis)


def _nearest(times: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Index of the epoch nearest to each time."""
    idx = np.clip(np.searchsorted(times, t, side="left"), 0, len(times) - 1)
    prev = np.clip(idx - 1, 0, None)
    return np.where(np.abs(times[prev] - t) < np.abs(times[idx] - t), prev, idx)


def group_returns(time: np.ndarray, channel: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Number of returns of each echo: the size of its run of consecutive echoes of one pulse.

    >>> group_returns(np.array([1.0, 1.0, 2.0]), np.zeros(3), np.zeros(3)).tolist()
    [2, 2, 1]
    """
    n = len(time)
    if n == 0:
        return np.zeros(0, np.int64)
    # angles to 0.01 degree: 3.A angles come from printed coordinates, so the echoes of one
    # pulse differ in the last digits
    angle = np.round(np.asarray(angle, dtype=np.float64), 2)
    new = np.ones(n, bool)
    new[1:] = (time[1:] != time[:-1]) | (channel[1:] != channel[:-1]) | (angle[1:] != angle[:-1])
    starts = np.flatnonzero(new)
    sizes = np.diff(np.append(starts, n))
    return np.repeat(sizes, sizes)


class Georeference(Stage):
    """Raw pulses + trajectory -> georeferenced, strip-labelled points."""

    name = "georeference"
    version = "6"
    Params = GeoreferenceParams
    inputs: ClassVar = ("trajectory", "pulses")
    outputs: ClassVar = {"points_georef": "points.las", "trajectory_lines": "trajectory.gpkg"}
    products: ClassVar = {"trajectory_lines": "qc/trajectory.gpkg"}
    config_keys = ("crs",)
    description = "pulses + trajectory -> points in the output CRS (raw formats only)"

    def is_enabled(self, params, config) -> bool:
        if config.input.format == "las":
            return False  # already georeferenced: "not applicable"
        if not params.enabled:
            from pipeline.errors import ConfigError

            raise ConfigError(
                f"stages.georeference.enabled: false, but input.format {config.input.format} is a raw format: "
                "its pulses must be georeferenced before anything else can run."
            )
        return True

    def external_files(self, params, config):
        return [params.geoid] if params.geoid is not None else []

    def run(self, ctx: StageContext[GeoreferenceParams]) -> None:
        import laspy

        from dtm.common.clouds import open_las_writer, point_header
        from dtm.common.columns import read_columns
        from dtm.common.crs import output_crs
        from dtm.common.geodesy import MapTransform
        from dtm.common.georeferencing import georeference, georeference_local, locate
        from dtm.stages.georeference.strips import segment_strips

        p = ctx.params
        traj, tmeta = read_columns(ctx.inputs["trajectory"])
        pulses, pmeta = read_columns(ctx.inputs["pulses"])
        convention = tmeta["convention"]
        n_pulses = len(pulses["time"])
        if len(traj["time"]) == 0 or n_pulses == 0:
            raise InputDataError("nothing to georeference: the trajectory or the pulses are empty.")
        lat0, lon0, h0 = float(traj["lat"][0]), float(traj["lon"][0]), float(traj["h"][0])
        frame, exact, mounting = prepare_exact(traj, convention, pmeta)
        ltp = prepare_ltp(traj, convention, lat0, lon0, p.ltp_radius_m)

        # strips from the trajectory's heading
        strips_epoch = segment_strips(traj["time"], traj["yaw"], turn_rate_deg_s=p.strips.turn_rate_deg_s,
                                      min_line_s=p.strips.min_line_s)  # fmt: skip

        # extent of the survey in the local frame (platform +- the longest pulse), and the strips that
        # have pulses, numbered 1, 2, ... in time order
        reach = 0.0
        pulse_strip = np.empty(n_pulses, np.int32)  # the strip of each pulse, looked up once
        for s in range(0, n_pulses, p.batch_size):
            sl = slice(s, s + p.batch_size)
            r = np.sqrt(pulses["x"][sl] ** 2 + pulses["y"][sl] ** 2 + pulses["z"][sl] ** 2)
            reach = max(reach, float(r.max()))
            pulse_strip[sl] = strips_epoch[_nearest(traj["time"], np.asarray(pulses["time"][sl]))]
        used = np.unique(pulse_strip)
        renumber = np.zeros(int(strips_epoch.max()) + 1, np.int32)
        renumber[used[used > 0]] = np.arange(1, int(np.sum(used > 0)) + 1)
        pulse_strip = renumber[pulse_strip]
        reach += float(np.linalg.norm(mounting.lever_arm)) + 1.0
        lo = exact.position.min(axis=0) - reach
        hi = exact.position.max(axis=0) + reach
        if p.frame == "exact":
            crs = output_crs(ctx.setting("crs"), None, (lon0, lat0))
            to_map = MapTransform(frame, crs, lo, hi, geoid=p.geoid)
            traj_used, map_columns = exact, to_map.columns
            ctx.metrics.update(map_transform=to_map.method, map_transform_max_error_m=to_map.max_error_m)
            corners = np.array(
                [[lo[0], lo[1], lo[2]], [hi[0], hi[1], hi[2]], [lo[0], hi[1], lo[2]], [hi[0], lo[1], hi[2]]]
            )
            bounds = to_map(corners)
        else:
            crs = ltp_crs(lat0, lon0, p.ltp_radius_m)
            traj_used, map_columns = ltp, (lambda e, n, u: (e, n, u))
            bounds = np.array([ltp.position.min(axis=0) - reach, ltp.position.max(axis=0) + reach])
        platform_map = to_map(exact.position) if p.frame == "exact" else ltp.position
        write_flight_lines(ctx.outputs["trajectory_lines"], traj["time"], platform_map, renumber[strips_epoch], crs)
        from dtm.common.units import Units

        ctx.metrics.update(frame=p.frame, crs=crs.name, crs_epsg=crs.to_epsg(), attitude_convention=convention,
                           units=Units.of(crs).describe())  # fmt: skip
        ctx.log.info("output CRS %s: %s", crs.name, ctx.metrics["units"])

        header = point_header(crs, bounds.min(axis=0), bounds.max(axis=0))
        header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
        sigmas = _epoch_sigmas(p.uncertainty, traj) if p.uncertainty is not None else None
        if sigmas is not None:
            for name, what in (("sigma_horizontal", "horizontal"), ("sigma_vertical", "vertical")):
                header.add_extra_dim(laspy.ExtraBytesParams(name=name, type=np.float32,
                                                            description=f"propagated 1-sigma {what}, m"))  # fmt: skip
            scan_axis = (0.0, 0.0, 1.0) if pmeta.get("format") == "ldmrs_mtig" else (1.0, 0.0, 0.0)
        workers = max(1, int(ctx.workers or 1))
        written = no_traj = in_turns = 0
        sig_sum = 0.0
        per_strip: dict[int, int] = {}
        tmp = ctx.outputs["points_georef"]
        with (
            open_las_writer(tmp, header) as writer,
            ctx.progress(n_pulses, "georeferencing", unit="pulse") as bar,
        ):
            start = 0
            while start < n_pulses:
                stop = min(start + p.batch_size, n_pulses)
                while stop < n_pulses and pulses["time"][stop] == pulses["time"][stop - 1]:
                    stop += 1  # keep the echoes of a pulse (or a 3.A scan) in one batch
                sl = slice(start, stop)
                t = np.asarray(pulses["time"][sl])
                cols = tuple(np.ascontiguousarray(pulses[k][sl], dtype=np.float64) for k in ("x", "y", "z"))
                xyz, ok = georeference(traj_used, t, cols, mounting, map_columns, max_gap_s=p.max_gap_s,
                                       workers=workers)  # fmt: skip
                strip = pulse_strip[sl]
                channel = np.asarray(pulses["channel"][sl])
                angle = np.asarray(pulses["angle"][sl])
                n_ret = group_returns(t, channel, angle)
                keep = ok & ((strip > 0) | p.strips.keep_turns)
                no_traj += int((~ok).sum())
                in_turns += int((ok & (strip == 0) & ~p.strips.keep_turns).sum())
                k = int(keep.sum())
                if k:
                    rec = laspy.ScaleAwarePointRecord.zeros(k, header=header)
                    rec.x, rec.y, rec.z = xyz[keep, 0], xyz[keep, 1], xyz[keep, 2]
                    rec.gps_time = t[keep] - LAS_GPS_OFFSET
                    echo = np.asarray(pulses["echo"][sl])[keep].astype(np.int64)
                    rec.return_number = np.clip(echo + 1, 1, 15)
                    rec.number_of_returns = np.clip(np.maximum(n_ret[keep], echo + 1), 1, 15)
                    rec.intensity = np.asarray(pulses["amplitude"][sl])[keep].astype(np.uint16) * 257
                    rec.scan_angle = np.clip(np.round(angle[keep] / 0.006), -30000, 30000).astype(np.int16)
                    rec.scanner_channel = channel[keep] & 3
                    rec.point_source_id = strip[keep]
                    if sigmas is not None:
                        sh, sv = _propagate(traj_used, t[keep], [c[keep] for c in cols], mounting, p, sigmas,
                                            scan_axis)  # fmt: skip
                        rec.sigma_horizontal = sh.astype(np.float32)
                        rec.sigma_vertical = sv.astype(np.float32)
                        sig_sum += float(np.sum(sv))
                    writer.write_points(rec)
                    for sid, cnt in zip(*np.unique(strip[keep], return_counts=True), strict=True):
                        per_strip[int(sid)] = per_strip.get(int(sid), 0) + int(cnt)
                written += k
                bar.update(stop - start)
                start = stop

        # ltp vs the exact local tangent plane, on a subsample of the survey
        step = max(1, n_pulses // 200_000)
        t = np.asarray(pulses["time"][::step])
        cols = tuple(np.ascontiguousarray(pulses[k][::step], dtype=np.float64) for k in ("x", "y", "z"))
        i, f, ok = locate(exact, t, p.max_gap_s)
        cols = tuple(c[ok] for c in cols)
        ex = np.column_stack(georeference_local(exact, *cols, mounting, i[ok], f[ok]))
        ie, fe = i[ok], f[ok]
        platform = exact.position[ie] + (exact.position[ie + 1] - exact.position[ie]) * fe[:, None]
        i, f, _ = locate(ltp, t, p.max_gap_s)
        lt = np.column_stack(georeference_local(ltp, *cols, mounting, i[ok], f[ok]))
        lt[:, 2] -= h0
        diff = lt - ex
        if len(diff):
            # what geometry predicts: the platform is placed with R instead of the radii of curvature
            # at its height, M + h (meridian) and N + h (prime vertical), and the tangent plane rises
            # over the ellipsoid by d^2 / 2R; the pulse offsets themselves are not scaled (they are
            # added in the plane, which tilts by d/R against the true local level: a term left out)
            e2 = 6.69437999014e-3
            w = 1.0 - e2 * np.sin(np.radians(lat0)) ** 2
            radius_m, radius_n = 6_378_137.0 * (1 - e2) / w**1.5, 6_378_137.0 / np.sqrt(w)
            h_p = h0 + platform[:, 2]
            pred_h = np.hypot((p.ltp_radius_m / (radius_n + h_p) - 1) * platform[:, 0],
                              (p.ltp_radius_m / (radius_m + h_p) - 1) * platform[:, 1])  # fmt: skip
            pred_v = (platform[:, 0] ** 2 + platform[:, 1] ** 2) / (2 * np.sqrt(radius_m * radius_n))
            ctx.metrics.update(
                ltp_vs_exact_max_horizontal_m=float(np.max(np.hypot(diff[:, 0], diff[:, 1]))),
                ltp_vs_exact_max_vertical_m=float(np.max(np.abs(diff[:, 2]))),
                ltp_vs_exact_extent_m=float(np.max(np.hypot(ex[:, 0], ex[:, 1]))),
                ltp_predicted_max_horizontal_m=float(np.max(pred_h)),
                ltp_predicted_max_vertical_m=float(np.max(pred_v)),
            )
        if sigmas is not None and written:
            ctx.metrics.update(sigma_vertical_mean_m=sig_sum / written, uncertainty_sources=sigmas["sources"])
        ctx.metrics.update(
            pulses=n_pulses, points=written, rejected_no_trajectory=no_traj, dropped_in_turns=in_turns,
            strips={str(k): v for k, v in sorted(per_strip.items())}, trajectory_epochs=len(traj["time"]),
        )  # fmt: skip
        ctx.log.info("%d of %d pulses georeferenced into %d strips (%s)", written, n_pulses,
                     len([s for s in per_strip if s > 0]), crs.name)  # fmt: skip
        if no_traj:
            ctx.log.warning("%d pulses outside the trajectory or in gaps over %g s: dropped", no_traj, p.max_gap_s)
        if in_turns:
            ctx.log.info("%d points flown in turns dropped (strips.keep_turns: false)", in_turns)
        if written == 0:
            raise InputDataError(
                f"no pulse could be georeferenced ({no_traj} without trajectory, {in_turns} in turns): "
                "check that the scanner and navigation files are of the same flight."
            )


def write_flight_lines(path, time: np.ndarray, xyz: np.ndarray, strip: np.ndarray, crs) -> None:
    """``qc/trajectory.gpkg``: one LineString a flight line (strip id, first and last GPS time, height of the
    platform in the output CRS: mean, lowest, highest), in the output CRS; epochs in turns (strip 0) left out."""
    from dtm.common.vectors import line_wkb, write_gpkg

    ids = [int(s) for s in np.unique(strip) if s > 0]
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
