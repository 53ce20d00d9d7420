"""Small projects of many files for the tests: a real survey cut into tiles.

``autzen_trim.las`` (PDAL's test data, ``../shared/data/real``; Oregon
State Plane in international feet, LAS 1.2 format 3) cut into twelve 60 ft
squares, about 900 points each, every third one written as LAZ.
"""

from __future__ import annotations

import struct
from pathlib import Path

import laspy
import numpy as np

from tests.shared_data import REAL as SHARED_REAL

ROOT = Path(__file__).resolve().parents[3]
AUTZEN = SHARED_REAL / "pdal" / "autzen_trim.las"
#: The south-west corner of the tiles and their side (feet).
X0, Y0, SIDE = 636400.0, 849000.0, 60.0


def tile_name(k: int) -> str:
    """``tile_00.laz``, ``tile_01.las``, ...: every third tile LAZ."""
    return f"tile_{k:02d}." + ("laz" if k % 3 == 0 else "las")


def cut_tiles(folder: Path, count: int = 12, stray_in: int | None = None) -> list[Path]:
    """Write *count* tiles of AUTZEN (4 a row) into *folder*; their paths in sorted order.

    With *stray_in*, that tile gets one more point 40 ft east of its square,
    outside the bounds its header announces (written after the points: the
    reader leaves it out as a stray).
    """
    src = laspy.read(AUTZEN)
    x, y = np.asarray(src.x), np.asarray(src.y)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k in range(count):
        i, j = k % 4, k // 4
        inside = (x >= X0 + i * SIDE) & (x < X0 + (i + 1) * SIDE) & (y >= Y0 + j * SIDE) & (y < Y0 + (j + 1) * SIDE)
        las = laspy.LasData(src.header)
        las.points = src.points[inside]
        path = folder / tile_name(k)
        if k == stray_in:
            true_max_x = float(np.asarray(las.x).max())
            stray = src.points[np.flatnonzero(inside)[:1]]
            las.points = laspy.ScaleAwarePointRecord(
                np.concatenate([las.points.array, stray.array]),
                las.header.point_format,
                las.header.scales,
                las.header.offsets,
            )
            las.x[-1] = true_max_x + 40.0
            las.write(path)
            with open(path, "r+b") as fh:  # LAS 1.2 header: max X at byte 179
                fh.seek(179)
                fh.write(struct.pack("<d", true_max_x))
        else:
            las.write(path)
        paths.append(path)
    return sorted(paths, key=str)
