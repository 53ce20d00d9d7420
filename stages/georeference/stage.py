"""Stage ``georeference``: trajectory + pulses -> points in the output CRS (SPEC 4).

The driver: it prepares the trajectory (in the exact frame and in the seed-0
ltp plane), labels the strips, builds the output frame, and writes the
flight lines and the points, batch by batch.  The algorithm is
:mod:`lidar.georeferencing`; the frames, strips and checks are described
in ``docs/stages/georeference.md``.
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import BaseModel

from lidar import glossary
from lidar.clouds import open_las_writer
from lidar.columns import read_columns
from lidar.crs import HEIGHTS_KEYS, heights_of_run, output_crs, state_heights
from lidar.georeferencing import exact_output, ltp_output, prepare_exact, prepare_ltp, pulse_reach
from lidar.units import Units
from pipeline.errors import ConfigError, InputDataError
from pipeline.stage import Stage, StageContext
from stages.georeference.batches import PASSES, las_header, write_batches
from stages.georeference.ltp_check import ltp_metrics
from stages.georeference.params import GeoreferenceParams
from stages.georeference.strips import pulse_strips, segment_strips, write_flight_lines
from stages.georeference.uncertainty import point_uncertainty


class Georeference(Stage, name="georeference", version="9", params=GeoreferenceParams):
    """pulses + trajectory -> points in the output CRS (raw formats only)."""

    inputs: ClassVar = ("trajectory", "pulses")
    outputs: ClassVar = {"points_georef": "points.las", "trajectory_lines": "trajectory.gpkg"}
    products: ClassVar = {"trajectory_lines": "qc/trajectory.gpkg"}
    config_keys = ("crs", *HEIGHTS_KEYS)

    def is_enabled(self, params: GeoreferenceParams, config: BaseModel) -> bool:
        if config.input.format == "las":
            return False  # already georeferenced: "not applicable"
        if not params.enabled:
            raise ConfigError(
                f"stages.georeference.enabled: false, but input.format {config.input.format} is a raw format: "
                "its pulses must be georeferenced before anything else can run."
            )
        return True

    def external_files(self, params: GeoreferenceParams, config: BaseModel) -> list[Path]:
        return [params.geoid] if params.geoid is not None else []

    def run(self, ctx: StageContext[GeoreferenceParams]) -> None:
        p = ctx.params
        traj, tmeta = read_columns(ctx.inputs["trajectory"])
        pulses, pmeta = read_columns(ctx.inputs["pulses"])
        n_pulses = len(pulses["time"])
        if len(traj["time"]) == 0 or n_pulses == 0:
            raise InputDataError("nothing to georeference: the trajectory or the pulses are empty.")
        # the trajectory in the exact frame and in the seed-0 ltp plane; the strips of epochs and pulses
        convention = tmeta["convention"]
        lat0, lon0 = float(traj["lat"][0]), float(traj["lon"][0])
        exact, mounting = prepare_exact(traj, convention, pmeta)
        ltp = prepare_ltp(traj, convention, lat0, lon0, p.ltp_radius_m)
        epoch_strip = segment_strips(
            traj["time"], traj["yaw"], turn_rate_deg_s=p.strips.turn_rate_deg_s, min_line_s=p.strips.min_line_s
        )
        _check_lines(ctx, traj["time"], epoch_strip)
        pulse_strip, epoch_strip = pulse_strips(traj["time"], epoch_strip, pulses["time"], p.batch_size)
        # the output frame over the survey: the platform's box +- the longest pulse
        reach = pulse_reach(pulses["x"], pulses["y"], pulses["z"], p.batch_size)
        reach += float(np.linalg.norm(mounting.lever_arm)) + 1.0
        if p.frame == "exact":
            out = exact_output(exact, output_crs(ctx.setting("crs"), None, (lon0, lat0)), reach, geoid=p.geoid)
            ctx.metrics.update(map_transform=out.to_map.method, map_transform_max_error_m=out.to_map.max_error_m)
        else:
            out = ltp_output(ltp, p.ltp_radius_m, reach)
        epochs = out.trajectory.position[: len(traj["time"])]  # a lone epoch is doubled for interpolating
        write_flight_lines(ctx.outputs["trajectory_lines"], traj["time"], out.points(epochs), epoch_strip, out.crs)
        ctx.metrics.update(
            frame=p.frame,
            crs=out.crs.name,
            crs_epsg=out.crs.to_epsg(),
            attitude_convention=convention,
            units=Units.of(out.crs).describe(),
        )
        ctx.log.info("output CRS %s: %s", out.crs.name, ctx.metrics["units"])
        state_heights(ctx, heights_of_run(ctx.config, out.crs))
        # the points, batch by batch
        tpu = point_uncertainty(p.uncertainty, traj, pmeta.get("format")) if p.uncertainty is not None else None
        header = las_header(out.crs, out.bounds(), uncertainty=tpu is not None)
        with (
            open_las_writer(ctx.outputs["points_georef"], header) as writer,
            ctx.progress(PASSES * n_pulses, f"georeferencing, {PASSES} passes over the pulses", unit="pulses") as bar,
        ):
            workers = max(1, int(ctx.workers or 1))
            tally = write_batches(
                writer, header, pulses, pulse_strip, out, mounting, p, tpu, workers=workers, advance=bar.update
            )
        ctx.metrics.update(ltp_metrics(exact, ltp, pulses, mounting, p.max_gap_s, p.ltp_radius_m))
        ctx.metrics.update(tally.metrics(n_pulses, len(traj["time"]), tpu))
        tally.report(ctx.log, n_pulses, out.crs.name, p.max_gap_s)


def _check_lines(ctx: StageContext[GeoreferenceParams], time: np.ndarray, epoch_strip: np.ndarray) -> None:
    """Refuse, before any pulse is georeferenced, a flight without one line when the turns are dropped."""
    strips = ctx.params.strips
    if strips.keep_turns or (epoch_strip > 0).any():
        return
    span = float(time[-1] - time[0]) if len(time) else 0.0
    raise InputDataError(
        f"{glossary.input_names(ctx.config)}: not enough trajectory for a flight line: its {len(time):,} "
        f"epoch{'s' if len(time) != 1 else ''} "
        f"span {span:.3f} s and no steady stretch lasts stages.georeference.strips.min_line_s ({strips.min_line_s:g} s), "
        "so every point would be dropped as flown in a turn (a log cut short? set strips.keep_turns: true to keep them)."
    )
