"""Opening a LAS/LAZ file safely: a damaged header is one sentence, not gigabytes of memory.

:func:`open_las` checks the header's sizes against the file
(:func:`check_header_sizes`) before laspy allocates anything, and turns
whatever laspy raises on a damaged file (:func:`las_parse_errors`) into an
:class:`~pipeline.errors.InputDataError` naming the file.  :func:`read_chunks`
does the same for the points (the LAZ decoder's panics too), naming the
byte of the record or LAZ chunk; :func:`check_strays` finds the points
outside the header's bounds, and refuses a file with too many.  Errors of
the machine (:func:`is_machine_error`) are never the file's.
"""

from __future__ import annotations

import errno
import struct
from collections.abc import Iterator
from contextlib import nullcontext
from pathlib import Path

import laspy
import lazrs
import numpy as np

from pipeline.errors import FULL, InputDataError


def las_parse_errors() -> tuple[type[BaseException], ...]:
    """What laspy raises on damaged files (found by fuzzing): all mean "unreadable"."""
    return (
        laspy.LaspyException,
        OSError,
        ValueError,
        struct.error,
        IndexError,
        KeyError,
        UnicodeDecodeError,
        OverflowError,
        RuntimeError,
        MemoryError,  # a damaged (E)VLR length makes laspy ask for terabytes
    )


#: The way out of a damaged file, ending its message.
WAY_OUT = "re-export or re-download it, or leave it out of input.paths"
#: A damaged file's diagnosis and way out.
DAMAGED = f"the file is damaged; {WAY_OUT}"
#: Errors of the machine, not of the file read: they propagate untouched (the engine's exit 4).
MACHINE_ERRNOS = FULL | {errno.EROFS}
#: Largest scale offset accepted (CRS units): far beyond any coordinate on Earth, in any unit.
MAX_OFFSET = 1e9
#: Smallest and largest scale factors accepted (CRS units a step): no survey has steps of a
#: picometre (or 1e-12 degree) or of a kilometre.
MIN_SCALE, MAX_SCALE = 1e-12, 1e3


def is_decoder_panic(exc: BaseException) -> bool:
    """Whether *exc* is a panic of the LAZ decoder (pyo3's PanicException derives from BaseException)."""
    return type(exc).__name__ == "PanicException"


def is_machine_error(exc: BaseException) -> bool:
    """Whether *exc* is the machine failing (disk full, quota, read-only file system), not the input."""
    return isinstance(exc, OSError) and exc.errno in MACHINE_ERRNOS


#: A LAZ point takes at least this many bytes (LAZ compresses 3-10x; 1/64 byte
#: per point is far below anything real), so a header claiming more points than
#: 64 x the file size is damaged.
_MIN_LAZ_BYTES_PER_POINT = 1 / 64


def check_header_sizes(path: Path) -> None:
    """Refuse a LAS/LAZ whose header announces more data than the file holds.

    Read before laspy allocates anything: the offset to the point data, the
    point count times the record length (LAZ: a generous lower bound per
    point), the VLRs' 54-byte headers before the point data, and the extended
    VLRs' start and lengths must fit in the file; the scales and offsets must
    be usable.  A damaged header then costs one sentence, not gigabytes of memory.
    """
    size = path.stat().st_size
    with open(path, "rb") as fh:  # opened once for every check below
        _check_sizes(path, fh, size)


def _check_sizes(path: Path, fh, size: int) -> None:
    """:func:`check_header_sizes` on the open file *fh* of *size* bytes."""
    head = fh.read(375)
    if len(head) < 227 or head[:4] != b"LASF":
        return  # laspy reports the missing signature itself
    minor = head[25]
    header_size = int.from_bytes(head[94:96], "little")
    offset_points = int.from_bytes(head[96:100], "little")
    vlr_count = int.from_bytes(head[100:104], "little")
    point_format = head[104]
    record_length = int.from_bytes(head[105:107], "little")
    count = int.from_bytes(head[107:111], "little")
    evlr_start = evlr_count = 0
    if minor >= 4 and len(head) >= 255:
        evlr_start = int.from_bytes(head[235:243], "little")
        evlr_count = int.from_bytes(head[243:247], "little")
        count = max(count, int.from_bytes(head[247:255], "little"))
    scales = np.frombuffer(head[131:155], dtype="<f8")
    offsets = np.frombuffer(head[155:179], dtype="<f8")
    _check_scales(path, scales, offsets)
    if header_size + 54 * vlr_count > min(offset_points, size):
        raise InputDataError(
            f"{path}, byte 100: the header announces {vlr_count:,} VLRs, more than fit before the point data."
        )
    compressed = bool(point_format & 0x80) or bool(point_format & 0x40)
    need = count * (_MIN_LAZ_BYTES_PER_POINT if compressed else record_length)
    if offset_points > size or offset_points + need > size:
        raise InputDataError(
            f"{path}, byte 107: the header announces {count:,} points, more than the file's {size:,} bytes can hold."
        )
    if compressed and count and offset_points + 8 <= size:
        _check_chunk_table(path, fh, offset_points, size, vlr_count, count)
    if evlr_count:
        if evlr_start + 60 * evlr_count > size:
            raise InputDataError(f"{path}, byte 235: the extended VLRs start beyond the end of the file.")
        position = evlr_start
        with nullcontext(fh):
            for _ in range(evlr_count):
                fh.seek(position + 20)
                length = int.from_bytes(fh.read(8), "little")
                position += 60 + length
                if position > size:
                    raise InputDataError(
                        f"{path}, byte {position - length - 40}: an extended VLR runs past the end of the file."
                    )


def _check_scales(path: Path, scales: np.ndarray, offsets: np.ndarray) -> None:
    """Refuse scale factors and offsets that make coordinates non-finite or beyond any on Earth (naming the field)."""
    for axis, (scale, offset) in enumerate(zip(scales.tolist(), offsets.tolist(), strict=True)):
        name = "xyz"[axis]
        if not (np.isfinite(scale) and scale != 0 and np.isfinite(offset)):
            raise InputDataError(
                f"{path}, byte {131 + 8 * axis}: the {name} scale factor {scale:g} or offset {offset:g} is not usable "
                f"(a scale must be a finite non-zero number, an offset finite); {DAMAGED}."
            )
        if not MIN_SCALE <= abs(scale) <= MAX_SCALE:
            raise InputDataError(
                f"{path}, byte {131 + 8 * axis}: the {name} scale factor {scale:g} makes a step outside "
                f"{MIN_SCALE:g} to {MAX_SCALE:g} units, which no survey has; {DAMAGED}."
            )
        if abs(offset) > MAX_OFFSET:
            raise InputDataError(
                f"{path}, byte {155 + 8 * axis}: the {name} offset {offset:g} lies beyond any coordinate on Earth "
                f"(more than {MAX_OFFSET:g} units from 0); {DAMAGED}."
            )


def _check_chunk_table(path: Path, fh, offset_points: int, size: int, vlr_count: int, count: int) -> None:
    """Refuse a LAZ chunk table whose offset, chunk count or chunk sizes cannot be right.

    LASzip stores the chunk table's offset in the first 8 bytes of the point
    data (-1: in the last 8 bytes of the file), and the number of chunks in
    the table's second 4 bytes.  A damaged count made lazrs ask for 64 GB
    (found by fuzzing); every chunk holds at least one byte, so the count is
    at most the file size.
    """
    with nullcontext(fh):
        fh.seek(offset_points)
        table = int.from_bytes(fh.read(8), "little", signed=True)
        where = offset_points
        if table == -1:
            fh.seek(size - 8)
            table = int.from_bytes(fh.read(8), "little", signed=True)
            where = size - 8
        if not offset_points + 8 <= table <= size - 8:
            raise InputDataError(f"{path}, byte {where}: the LAZ chunk table offset {table} is outside the file.")
        fh.seek(table + 4)
        chunks = int.from_bytes(fh.read(4), "little")
    if chunks > size:
        raise InputDataError(
            f"{path}, byte {table + 4}: the LAZ chunk table announces {chunks:,} chunks, "
            f"more than the file's {size:,} bytes can hold."
        )
    _check_chunk_sizes(path, fh, offset_points, table, vlr_count, count)


#: Points a LAZ chunk may hold beyond the file's: LASzip's default is 50,000 a chunk.
MAX_CHUNK_POINTS = 1_000_000


def _check_chunk_sizes(path: Path, fh, offset_points: int, table: int, vlr_count: int, count: int) -> None:
    """Refuse LAZ chunks the decoder would allocate without bound (lazrs aborts the process: 48 GB seen).

    The LASzip VLR's chunk size (bytes 12-15 of its data; 0xFFFFFFFF:
    variable) is at most the file's points or ``MAX_CHUNK_POINTS``; the
    table (lazrs ``read_chunk_table``) gives each chunk's bytes, which
    together fill the space between the point data's first 8 bytes and the table.
    """
    with nullcontext(fh):
        vlr, at = _laszip_vlr(fh, vlr_count), fh.tell()
        if vlr is None or len(vlr) < 34:
            return  # laspy reports a LAZ file without its VLR itself
        chunk = int.from_bytes(vlr[12:16], "little")
        if chunk != 0xFFFFFFFF and chunk > max(count, MAX_CHUNK_POINTS):
            raise InputDataError(
                f"{path}, byte {at - len(vlr) + 12}: the LASzip VLR announces chunks of {chunk:,} points, "
                f"more than the file's {count:,}; {DAMAGED}."
            )
        fh.seek(offset_points)
        try:
            entries = lazrs.read_chunk_table(fh, lazrs.LazVlr(vlr))
        except BaseException as exc:
            if not (isinstance(exc, Exception) or is_decoder_panic(exc)):
                raise
            raise InputDataError(
                f"{path}, byte {table}: the LAZ chunk table cannot be read ({exc}); {DAMAGED}."
            ) from None
    room = table - offset_points - 8
    if sum(int(size) for _, size in entries) > room or any(int(size) < 0 for _, size in entries):
        raise InputDataError(
            f"{path}, byte {table}: the LAZ chunk table gives its chunks more than the {room:,} bytes "
            f"between the point data and the table; {DAMAGED}."
        )


def open_las(path: Path, check: bool = True) -> laspy.LasReader:
    """``laspy.open`` of a checked file (:func:`check_header_sizes`); InputDataError when it is unreadable.

    A file the user may not read is one sentence too; an error of the machine
    (:func:`is_machine_error`) propagates untouched.  *check* false skips
    :func:`check_header_sizes`, for a file whose header was checked in this
    run already (a header index).
    """
    try:
        if check:
            check_header_sizes(path)
        return laspy.open(str(path))
    except PermissionError:
        raise InputDataError(
            f"{path}: permission denied; give the user running the pipeline read access to it."
        ) from None
    except InputDataError:
        raise
    except BaseException as exc:
        if is_machine_error(exc) or not (isinstance(exc, las_parse_errors()) or is_decoder_panic(exc)):
            raise
        reason = "a header field announces more data than can exist" if isinstance(exc, MemoryError) else exc
        raise InputDataError(f"{path}: not a readable LAS/LAZ file ({reason}).") from None


def laz_chunk_of(path: Path, header, point: int) -> tuple[int, int, int, int] | None:
    """The LAZ chunk holding point number *point*: (chunk, its byte offset, its first point, its points).

    From the file's chunk table (lazrs); None when the file is not LAZ or its table cannot be read.
    """
    try:
        with open(path, "rb") as fh:
            vlr = _laszip_vlr(fh, len(header.vlrs) + 1)  # laspy took the LASzip VLR out
            if vlr is None:
                return None
            fh.seek(int(header.offset_to_point_data))
            table = lazrs.read_chunk_table(fh, lazrs.LazVlr(vlr))
    except BaseException as exc:
        if isinstance(exc, Exception) or is_decoder_panic(exc):
            return None
        raise
    byte, first = int(header.offset_to_point_data) + 8, 0
    for k, (points, size) in enumerate(table):
        if point < first + points:
            return k, byte, first, int(points)
        byte, first = byte + int(size), first + int(points)
    return None


def _laszip_vlr(fh, vlr_count: int) -> bytes | None:
    """The data of the file's LASzip VLR (laspy takes it out of the header it reads), or None."""
    fh.seek(94)
    fh.seek(int.from_bytes(fh.read(2), "little"))  # the header's size
    for _ in range(vlr_count):
        head = fh.read(54)
        if len(head) < 54:
            return None
        length = int.from_bytes(head[20:22], "little")
        if head[2:18].rstrip(b"\0 ") == b"laszip encoded":
            return fh.read(length)
        fh.seek(length, 1)
    return None


def record_location(path: Path, header, point: int, last: int | None = None) -> str:
    """Where point number *point* (to *last*, when given) is stored: the record's byte (LAS) or the LAZ chunks'."""
    last = point if last is None else max(point, min(last, int(header.point_count) - 1))
    if not header.are_points_compressed:
        return f"byte {int(header.offset_to_point_data) + point * int(header.point_format.size):,} (record {point:,})"
    chunk, end = laz_chunk_of(path, header, point), laz_chunk_of(path, header, last)
    if chunk is None or end is None:
        return f"byte {int(header.offset_to_point_data):,} (compressed points, point {point:,})"
    k, byte, first, n = chunk
    if end[0] == k:
        return f"byte {byte:,} (LAZ chunk {k}, points {first:,} to {first + n - 1:,})"
    return f"bytes {byte:,} to {end[1]:,} (LAZ chunks {k} to {end[0]}, points {first:,} to {end[2] + end[3] - 1:,})"


def read_chunks(path: Path, reader: laspy.LasReader, chunk_size: int, first: int = 0) -> Iterator:
    """The chunks of ``reader.chunk_iterator``; what the decoder raises (panics too) is an InputDataError.

    The error names the file and the byte of the record (LAS) or LAZ chunk
    where reading stopped (:func:`record_location`; *first*: the number of
    the first point).  Only the reading is guarded: an error of the machine
    (:func:`is_machine_error`) propagates untouched, and so does whatever
    the caller does with a chunk.
    """
    chunks = reader.chunk_iterator(chunk_size)
    n_read = first
    while True:
        try:
            chunk = next(chunks)
        except StopIteration:
            return
        except BaseException as exc:
            if is_machine_error(exc) or not (isinstance(exc, las_parse_errors()) or is_decoder_panic(exc)):
                raise
            where = record_location(path, reader.header, n_read, n_read + chunk_size - 1)
            raise InputDataError(f"{path}, {where}: the points cannot be decoded ({exc}); {DAMAGED}.") from None
        n_read += len(chunk)
        yield chunk


#: Points farther outside their header's bounds than this share of its span (or
#: 100 scale steps), in any axis, are stray: left out, so that they size no grid.
HEADER_BOUNDS_TOLERANCE = 0.01
#: More stray points than this in one file: its records or its header are damaged (the file is refused).
STRAY_LIMIT = 100


def header_mins_maxs(header) -> tuple[np.ndarray, np.ndarray]:
    """The header's bounds (float64), swapped on an axis of negative scale.

    LAS 1.4 (R15) does not forbid a negative scale factor and the
    coordinates read correctly with one, but writers (laspy) then store the
    bounds of the stored integers, inverted on that axis; bounds in order
    are left as they are.
    """
    mins, maxs = np.asarray(header.mins, dtype=np.float64), np.asarray(header.maxs, dtype=np.float64)
    flip = (np.asarray(header.scales, dtype=np.float64) < 0) & (mins > maxs)
    return np.where(flip, maxs, mins), np.where(flip, mins, maxs)


def header_box(header) -> np.ndarray | None:
    """The box (xmin, ymin, zmin, xmax, ymax, zmax) a header announces, widened by the tolerance; None if unusable.

    Bounds that are not finite or all zero (never filled in) are not a box
    to check points against; an axis whose bounds are inverted is not checked.
    """
    mins, maxs = header_mins_maxs(header)
    if int(header.point_count) == 0 or not (np.isfinite(mins).all() and np.isfinite(maxs).all()):
        return None
    if not (mins[:2].any() or maxs[:2].any()):
        return None
    tol = np.maximum(HEADER_BOUNDS_TOLERANCE * (maxs - mins), 100.0 * np.abs(np.asarray(header.scales)))
    inverted = np.tile(mins > maxs, 2)
    box = np.concatenate((mins - tol, maxs + tol))
    box[inverted] = np.array([-np.inf, -np.inf, -np.inf, np.inf, np.inf, np.inf])[inverted]
    return box


def outside_box(box: np.ndarray | None, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Points outside *box* (see :func:`header_box`), in the file's own CRS; a non-finite value is outside."""
    if box is None:
        return np.zeros(len(x), dtype=bool)
    inside = (x >= box[0]) & (y >= box[1]) & (z >= box[2]) & (x <= box[3]) & (y <= box[4]) & (z <= box[5])
    return ~inside


def check_strays(path: Path, header, box, xyz: tuple, first: int, before: int) -> tuple[np.ndarray, int]:
    """A chunk's points outside the header's bounds (:func:`outside_box`), and the file's count of them so far.

    *before* is the count before this chunk, *first* the chunk's first point.
    More than ``STRAY_LIMIT`` in a file are not strays but damaged records
    (a LAZ chunk decoded into garbage) or a damaged header: InputDataError
    at the first one's record or LAZ chunk (:func:`record_location`).
    """
    stray = outside_box(box, *xyz)
    count = before + int(stray.sum())
    if count > STRAY_LIMIT:
        where = record_location(path, header, first + int(np.argmax(stray)))
        raise InputDataError(
            f"{path}, {where}: more than {STRAY_LIMIT} points decode outside the bounds the header announces, so its "
            f"records or its header (scale, offset or bounds: bytes 131-226) are damaged; {WAY_OUT}."
        )
    return stray, count
