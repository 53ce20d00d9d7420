"""Opening a LAS/LAZ file safely: a damaged header is one sentence, not gigabytes of memory.

:func:`open_las` checks the header's sizes against the file
(:func:`check_header_sizes`) before laspy allocates anything, and turns
whatever laspy raises on a damaged file (:func:`las_parse_errors`) into an
:class:`~pipeline.errors.InputDataError` naming the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pipeline.errors import InputDataError

if TYPE_CHECKING:
    import laspy


def las_parse_errors() -> tuple[type[BaseException], ...]:
    """What laspy raises on damaged files (found by fuzzing): all mean "unreadable"."""
    import struct

    import laspy

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
    with open(path, "rb") as fh:
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
    for axis, (scale, offset) in enumerate(zip(scales, offsets, strict=True)):
        if not (np.isfinite(scale) and scale != 0 and np.isfinite(offset)):
            name = "xyz"[axis]
            raise InputDataError(
                f"{path}, byte {131 + 8 * axis}: the {name} scale factor {scale!r} or offset {offset!r} is not usable "
                "(a scale must be a finite non-zero number, an offset finite)."
            )
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
        _check_chunk_table(path, offset_points, size)
    if evlr_count:
        if evlr_start + 60 * evlr_count > size:
            raise InputDataError(f"{path}, byte 235: the extended VLRs start beyond the end of the file.")
        position = evlr_start
        with open(path, "rb") as fh:
            for _ in range(evlr_count):
                fh.seek(position + 20)
                length = int.from_bytes(fh.read(8), "little")
                position += 60 + length
                if position > size:
                    raise InputDataError(
                        f"{path}, byte {position - length - 40}: an extended VLR runs past the end of the file."
                    )


def _check_chunk_table(path: Path, offset_points: int, size: int) -> None:
    """Refuse a LAZ chunk table whose offset or chunk count cannot be right.

    LASzip stores the chunk table's offset in the first 8 bytes of the point
    data (-1: in the last 8 bytes of the file), and the number of chunks in
    the table's second 4 bytes.  A damaged count made lazrs ask for 64 GB
    (found by fuzzing); every chunk holds at least one byte, so the count is
    at most the file size.
    """
    with open(path, "rb") as fh:
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


def open_las(path: Path) -> laspy.LasReader:
    """``laspy.open`` of a checked file (:func:`check_header_sizes`); InputDataError when it is unreadable."""
    import laspy

    check_header_sizes(path)
    try:
        return laspy.open(str(path))
    except las_parse_errors() as exc:
        reason = "a header field announces more data than can exist" if isinstance(exc, MemoryError) else exc
        raise InputDataError(f"{path}: not a readable LAS/LAZ file ({reason}).") from None
