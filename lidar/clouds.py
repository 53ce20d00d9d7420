"""Point clouds between stages: their LAS header, writer and reading helpers.

Clouds between stages are uncompressed LAS 1.4, point format 6 (7 with the
input's RGB, 8 with RGB and NIR, plus the input's extra bytes and GPS time
type), with the CRS as a WKT VLR: an open format any LiDAR viewer opens, so
every cached intermediate can be inspected; uncompressed because it is read
and written several times per run and LAZ costs about ten times more CPU.
Rasters: :mod:`lidar.rasters`; vectors: :mod:`lidar.vectors`.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

import laspy
import numpy as np

from lidar.units import Units
from pipeline import __version__

#: Point format of every point cloud the pipeline writes (LAS 1.4).
POINT_FORMAT = 6
#: ``system_identifier`` of every point cloud the pipeline writes (LAS 1.4 allows
#: "a string up to 32 characters identifying the operation"; PDAL and LAStools
#: name themselves there too).
SYSTEM_IDENTIFIER = "dtm-pipeline"


def generating_software() -> str:
    """``generating_software`` of every point cloud the pipeline writes: this tool and its version."""
    return f"dtm-pipeline {__version__}"[:32]


@dataclass(frozen=True)
class PointLayout:
    """What the point records of a written cloud hold, taken from the input files.

    ``point_format`` 6, 7 (RGB) or 8 (RGB and NIR); ``extra``: the input's
    extra-byte dimensions, in its order; ``gps_adjusted``: global encoding
    bit 0 (adjusted standard GPS time, not seconds of the week);
    ``synthetic_returns``: bit 3; ``vlrs``, ``evlrs``: the input's own
    (extended) VLRs carried through (not the CRS, extra-byte, LASzip or
    waveform records, which the writer makes or which no longer apply).
    """

    point_format: int = POINT_FORMAT
    extra: tuple = ()
    gps_adjusted: bool = False
    synthetic_returns: bool = False
    vlrs: tuple = ()
    evlrs: tuple = ()


def point_header(crs, lo=None, hi=None, *, layout: PointLayout | None = None):
    """The header of every point cloud the pipeline writes: LAS 1.4, point format 6-8, the CRS as WKT.

    Offsets are *lo* rounded down to whole kilometres; the scale is 0.1 mm —
    finer than any airborne LiDAR's precision, and int32 holds +-214 km
    around the offset — and 1 mm, 1 cm, ... for a survey reaching farther
    (*hi*).  Without bounds (an empty cloud) offsets are 0.  The point
    format, extra bytes and the GPS time type follow *layout* (default:
    format 6, GPS week time); ``system_identifier`` and
    ``generating_software`` name this tool and its version.
    """
    layout = layout or PointLayout()
    header = laspy.LasHeader(point_format=layout.point_format, version="1.4")
    if layout.extra:
        header.add_extra_dims(list(layout.extra))
    header.global_encoding.gps_time_type = (
        laspy.header.GpsTimeType.STANDARD if layout.gps_adjusted else laspy.header.GpsTimeType.WEEK_TIME
    )
    header.global_encoding.synthetic_return_numbers = layout.synthetic_returns
    header.system_identifier = SYSTEM_IDENTIFIER
    header.generating_software = generating_software()
    header.vlrs.extend(layout.vlrs)
    if layout.evlrs:
        header.evlrs = [*(header.evlrs or []), *layout.evlrs]
    scale = 1e-4
    if lo is not None:
        header.offsets = np.floor(np.asarray(lo, dtype=np.float64) / 1000.0) * 1000.0
        reach = float(np.max(np.asarray(hi, dtype=np.float64) - header.offsets))
        while reach / scale > 2.0e9:
            scale *= 10.0
    header.scales = np.array([scale, scale, scale])
    header.add_crs(crs)
    return header


def open_las_writer(path, header, **options):
    """``laspy.open(path, mode="w", header=header, **options)`` whose header grows without sorting each chunk.

    laspy's writer updates its header with every chunk it writes
    (:meth:`laspy.LasHeader.grow`): bounds, GPS time range and points per
    return, the last with ``np.unique`` (a sort of the chunk's return
    numbers: 27 ms of the 51 ms a 1 M-point chunk costs, 0.5 s in the
    three writers of a 10 M-point run).  This writer's header counts the
    returns with ``np.bincount`` instead (:func:`grow_header`): the same
    header, byte for byte (``tests/lidar/test_las_writer.py``).
    """
    writer = laspy.open(str(path), mode="w", header=header, **options)
    writer.header.grow = partial(grow_header, writer.header)  # this header only: laspy itself is untouched
    return writer


def grow_header(header, points) -> None:
    """:meth:`laspy.LasHeader.grow` (laspy 2.5-2.7), the points per return counted by ``np.bincount``.

    Bounds as laspy computes them (``X.max() * scale + offset``, ...), the
    GPS time range, the returns numbered 1 to the header's 15 slots (0 and
    higher numbers are not counted, as laspy does not), the point count.
    """
    for axis, name in enumerate("XYZ"):
        raw = points[name]
        scale, offset = header.scales[axis], header.offsets[axis]
        header.maxs[axis] = max(header.maxs[axis], raw.max() * scale + offset)
        header.mins[axis] = min(header.mins[axis], raw.min() * scale + offset)
    if "gps_time" in points.point_format.dimension_names:
        gps_time = points["gps_time"]
        header.max_gps_time = max(header.max_gps_time, gps_time.max())
        header.min_gps_time = min(header.min_gps_time, gps_time.min())
    slots = header.number_of_points_by_return
    counts = np.bincount(np.asarray(points.return_number, dtype=np.intp), minlength=1)[1 : len(slots) + 1]
    slots[: len(counts)] += counts.astype(slots.dtype)
    header.point_count += len(points)


#: A pass over a file's points reads it in at least this many chunks, so that its progress moves at least every
#: tenth of the pass (:func:`progress_chunk`).
PROGRESS_CHUNKS = 20
#: ... but never in chunks of fewer points than this (laspy's overhead per read).
MIN_PROGRESS_CHUNK = 10_000


def progress_chunk(points: int, chunk_size: int = 1_000_000) -> int:
    """Points to read at a time in a pass over *points* points: *chunk_size*, or fewer in a small file.

    A file of fewer than :data:`PROGRESS_CHUNKS` chunks is read in about
    that many (at least :data:`MIN_PROGRESS_CHUNK` points each), so the
    pass's progress figure moves.  Only for passes whose result does not
    depend on where the chunks end (else :func:`read_chunks_counted`).

    >>> progress_chunk(185_821), progress_chunk(3_000_000), progress_chunk(50_000_000), progress_chunk(5_000)
    (10000, 150000, 1000000, 10000)
    """
    chunk = max(-(-int(points) // PROGRESS_CHUNKS), MIN_PROGRESS_CHUNK)
    return max(min(int(chunk_size), chunk), 1)


def read_chunks_counted(reader, chunk_size: int, advance: Callable[[int], object] | None = None) -> Iterator:
    """The records of an open laspy *reader*, *chunk_size* at a time (``reader.chunk_iterator``'s chunks).

    For a pass whose result depends on where the chunks end (sums in
    floating point, figures updated chunk by chunk): each chunk is read in
    pieces of :func:`progress_chunk` and joined, and *advance* is told the
    points of each piece as it is read, so a small file's progress moves
    too; the chunks are the same as without it.
    """
    piece = progress_chunk(reader.header.point_count, chunk_size)
    if advance is None or piece >= chunk_size:
        for chunk in reader.chunk_iterator(chunk_size):
            if advance is not None:
                advance(len(chunk))
            yield chunk
        return
    while True:
        parts, held = [], 0
        while held < chunk_size:
            part = reader.read_points(min(piece, chunk_size - held))
            if not len(part):
                break
            parts.append(part)
            held += len(part)
            advance(len(part))
        if not parts:
            return
        first = parts[0]
        if len(parts) == 1:
            yield first
        else:
            array = np.concatenate([part.array for part in parts])
            yield laspy.ScaleAwarePointRecord(array, first.point_format, first.scales, first.offsets)
        if held < chunk_size:
            return


def chunk_xyz_metres(chunk, units) -> np.ndarray:
    """A chunk's (laspy record's) coordinates in metres, (n, 3) with contiguous columns.

    laspy's scaled values (``X * scale + offset``, computed as laspy does),
    then :meth:`lidar.units.Units.to_metres`'s factors, column by column:
    no stacked copy of three separate columns.
    """
    xyz = np.empty((len(chunk), 3), order="F")
    for axis, name in enumerate("XYZ"):
        np.multiply(chunk.array[name], chunk.scales[axis], out=xyz[:, axis])
        xyz[:, axis] += chunk.offsets[axis]
        if not units.is_metre:
            xyz[:, axis] *= units.vertical if axis == 2 else units.horizontal
    return xyz


def cloud_crs(las):
    """The pyproj CRS of a LasData (or an open laspy reader), or None when its header has none."""
    try:
        return las.header.parse_crs()
    except Exception:  # laspy raises various errors for malformed GeoTIFF keys
        return None


@dataclass(frozen=True)
class CloudInfo:
    """What a LAS file's header says, for cutting it into tiles."""

    extent: tuple[float, float, float, float]  # xmin, ymin, xmax, ymax in metres
    units: Any  # lidar.units.Units of its CRS
    crs: Any  # pyproj CRS, or None
    count: int
    dimensions: frozenset[str]


def cloud_info(path: Path) -> CloudInfo:
    """The extent (metres), units, CRS, point count and dimensions a LAS file's header gives."""
    with laspy.open(str(path)) as reader:
        header = reader.header
        crs = cloud_crs(reader)
        units = Units.of(crs)
        lo = units.to_metres(np.array([[header.mins[0], header.mins[1], header.mins[2]]]))[0]
        hi = units.to_metres(np.array([[header.maxs[0], header.maxs[1], header.maxs[2]]]))[0]
        return CloudInfo(
            (float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])),
            units,
            crs,
            int(header.point_count),
            frozenset(header.point_format.dimension_names),
        )
