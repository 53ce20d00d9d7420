"""The pulses georeferenced batch by batch into LAS 1.4 point records (point format 6).

Each point keeps ``gps_time`` (adjusted standard GPS time, GPS seconds - 1e9,
as LAS 1.4 requires), its return number and count, intensity (amplitude x
257), scan angle, scanner channel (LD-MRS layer) and its strip id in
``point_source_id``; with the uncertainty on, the extra bytes
``sigma_horizontal`` and ``sigma_vertical``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import laspy
import numpy as np

from lidar.clouds import point_header
from lidar.georeferencing import LAS_GPS_OFFSET, Mounting, OutputFrame, georeference
from pipeline.errors import InputDataError
from stages.georeference.params import GeoreferenceParams
from stages.georeference.uncertainty import PointUncertainty

if TYPE_CHECKING:
    import pyproj


def pulse_batches(time: np.ndarray, batch_size: int) -> Iterator[slice]:
    """Slices of about *batch_size* pulses; the echoes of one pulse (or of one 3.A scan) stay in one batch."""
    n = len(time)
    start = 0
    while start < n:
        stop = min(start + batch_size, n)
        while stop < n and time[stop] == time[stop - 1]:
            stop += 1
        yield slice(start, stop)
        start = stop


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


def las_header(crs: pyproj.CRS, bounds: np.ndarray, uncertainty: bool) -> laspy.LasHeader:
    """The header of ``points.las``: the box of *bounds*, standard GPS time, the sigma extra bytes if asked."""
    header = point_header(crs, bounds.min(axis=0), bounds.max(axis=0))
    header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    if uncertainty:
        for name, what in (("sigma_horizontal", "horizontal"), ("sigma_vertical", "vertical")):
            header.add_extra_dim(
                laspy.ExtraBytesParams(name=name, type=np.float32, description=f"propagated 1-sigma {what}, m")
            )
    return header


@dataclass
class Batch:
    """One batch of pulses, georeferenced: map coordinates (NaN where ``ok`` is False) and what a record needs."""

    sl: slice
    t: np.ndarray
    v_s: tuple[np.ndarray, np.ndarray, np.ndarray]  # scanner-frame x, y, z
    xyz: np.ndarray
    ok: np.ndarray  # the pulse had a trajectory
    strip: np.ndarray
    channel: np.ndarray
    angle: np.ndarray


def georeference_batch(
    pulses: dict,
    sl: slice,
    pulse_strip: np.ndarray,
    out: OutputFrame,
    mounting: Mounting,
    max_gap_s: float,
    workers: int,
    advance: Callable[[int], object] | None = None,
) -> Batch:
    """The pulses *sl* in the output frame, with their strips (from :func:`~.strips.pulse_strips`); *advance* is told
    the pulses georeferenced, a tenth of them at a time."""
    t = np.asarray(pulses["time"][sl])
    cols = tuple(np.ascontiguousarray(pulses[k][sl], dtype=np.float64) for k in ("x", "y", "z"))
    xyz, ok = georeference(
        out.trajectory, t, cols, mounting, out.columns, max_gap_s=max_gap_s, workers=workers, advance=advance
    )
    channel = np.asarray(pulses["channel"][sl])
    angle = np.asarray(pulses["angle"][sl])
    return Batch(sl, t, cols, xyz, ok, pulse_strip[sl], channel, angle)


def point_record(header: laspy.LasHeader, pulses: dict, b: Batch, keep: np.ndarray) -> laspy.ScaleAwarePointRecord:
    """The LAS record of the pulses *keep* of batch *b* (the sigma extra bytes left for the caller)."""
    n_ret = group_returns(b.t, b.channel, b.angle)
    rec = laspy.ScaleAwarePointRecord.zeros(int(keep.sum()), header=header)
    rec.x, rec.y, rec.z = b.xyz[keep, 0], b.xyz[keep, 1], b.xyz[keep, 2]
    rec.gps_time = b.t[keep] - LAS_GPS_OFFSET
    echo = np.asarray(pulses["echo"][b.sl])[keep].astype(np.int64)
    rec.return_number = np.clip(echo + 1, 1, 15)
    rec.number_of_returns = np.clip(np.maximum(n_ret[keep], echo + 1), 1, 15)
    rec.intensity = np.asarray(pulses["amplitude"][b.sl])[keep].astype(np.uint16) * 257
    rec.scan_angle = np.clip(np.round(b.angle[keep] / 0.006), -30000, 30000).astype(np.int16)
    rec.scanner_channel = b.channel[keep] & 3
    rec.point_source_id = b.strip[keep]
    return rec


@dataclass
class Tally:
    """What the batches wrote and dropped."""

    points: int = 0
    no_trajectory: int = 0
    in_turns: int = 0
    sigma_vertical_sum: float = 0.0
    per_strip: dict[int, int] = field(default_factory=dict)

    def add_strips(self, strip: np.ndarray) -> None:
        for sid, cnt in zip(*np.unique(strip, return_counts=True), strict=True):
            self.per_strip[int(sid)] = self.per_strip.get(int(sid), 0) + int(cnt)

    def metrics(self, pulses: int, epochs: int, tpu: PointUncertainty | None) -> dict:
        """The stage's counts (and the mean vertical sigma when the uncertainty is on)."""
        out = {}
        if tpu is not None and self.points:
            out.update(
                sigma_vertical_mean_m=self.sigma_vertical_sum / self.points, uncertainty_sources=tpu.epochs.sources
            )
        out.update(
            pulses=pulses,
            points=self.points,
            rejected_no_trajectory=self.no_trajectory,
            dropped_in_turns=self.in_turns,
            strips={str(k): v for k, v in sorted(self.per_strip.items())},
            trajectory_epochs=epochs,
        )
        return out

    def report(self, log: logging.Logger, pulses: int, crs_name: str, max_gap_s: float) -> None:
        """Log what was written and dropped; no point written at all is an :class:`InputDataError`."""
        log.info(
            "%d of %d pulses georeferenced into %d strips (%s)",
            self.points,
            pulses,
            len([s for s in self.per_strip if s > 0]),
            crs_name,
        )
        if self.no_trajectory:
            log.warning("%d pulses outside the trajectory or in gaps over %g s: dropped", self.no_trajectory, max_gap_s)
        if self.in_turns:
            log.info("%d points flown in turns dropped (strips.keep_turns: false)", self.in_turns)
        if self.points == 0:
            raise InputDataError(
                f"no pulse could be georeferenced ({self.no_trajectory} without trajectory, {self.in_turns} in turns): "
                "check that the scanner and navigation files are of the same flight."
            )


def write_batches(
    writer: laspy.LasWriter,
    header: laspy.LasHeader,
    pulses: dict,
    pulse_strip: np.ndarray,
    out: OutputFrame,
    mounting: Mounting,
    p: GeoreferenceParams,
    tpu: PointUncertainty | None,
    *,
    workers: int,
    advance: Callable[[int], object],
) -> Tally:
    """Georeference every pulse, batch by batch, and write the points kept (a trajectory, a strip) to *writer*.

    Points flown in turns (strip 0) are kept only with ``strips.keep_turns``;
    *advance* is told the pulses done in two passes over each batch: its
    georeferencing, then its records (with their sigmas) written, each a
    tenth at a time (:data:`PASSES` per pulse in all).
    """
    tally = Tally()
    keep_turns = p.strips.keep_turns
    for sl in pulse_batches(pulses["time"], p.batch_size):
        n = sl.stop - sl.start
        b = georeference_batch(pulses, sl, pulse_strip, out, mounting, p.max_gap_s, workers, advance)
        keep = b.ok & ((b.strip > 0) | keep_turns)
        tally.no_trajectory += int((~b.ok).sum())
        if not keep_turns:
            tally.in_turns += int((b.ok & (b.strip == 0)).sum())
        k = int(keep.sum())
        written = 0
        if k:
            rec = point_record(header, pulses, b, keep)
            if tpu is not None:
                sh, sv = _sigmas(tpu, out.trajectory, b.t[keep], [c[keep] for c in b.v_s], mounting, n, advance)
                written = n
                rec.sigma_horizontal = sh.astype(np.float32)
                rec.sigma_vertical = sv.astype(np.float32)
                tally.sigma_vertical_sum += float(np.sum(sv))
            writer.write_points(rec)
            tally.add_strips(b.strip[keep])
        tally.points += k
        advance(n - written)
    return tally


#: Passes :func:`write_batches` makes over each pulse (its progress total is this times the pulses).
PASSES = 2


def _sigmas(
    tpu: PointUncertainty, traj, t: np.ndarray, v_s: list[np.ndarray], mounting: Mounting, pulses: int, advance
) -> tuple[np.ndarray, np.ndarray]:
    """:meth:`PointUncertainty.sigmas` of a batch's kept points, a tenth at a time (each point's its own: the same
    values), *advance* told the batch's *pulses* in step with them."""
    n = len(t)
    step = -(-max(-(-n // 10), 1) // SIGMA_PIECE) * SIGMA_PIECE
    parts, told = [], 0
    for a in range(0, n, step):
        sl = slice(a, min(a + step, n))
        parts.append(tpu.sigmas(traj, t[sl], [c[sl] for c in v_s], mounting))
        now = pulses * sl.stop // n
        advance(now - told)
        told = now
    if len(parts) == 1:
        return parts[0]
    return np.concatenate([h for h, _ in parts]), np.concatenate([v for _, v in parts])


#: The points whose sigmas are propagated at a time are a whole multiple of this (and of any SIMD width).
SIGMA_PIECE = 32_768
