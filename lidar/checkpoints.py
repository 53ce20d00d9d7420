"""Surveyed points in a CSV (check points, ground control), and the DTM's bilinear height at them.

Shared by ``accuracy`` (and ``pipeline evaluate dtm``), ``report`` and
``strip_adjust``'s ground control.  The file's format:
``docs/stages/accuracy.md``.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from lidar.rasters import read_raster
from lidar.units import raster_units
from pipeline.errors import InputDataError

#: The check points' land-cover column unless said otherwise.
LAND_COVER_COLUMN = "land_cover"

_ALIASES = {"x": ("x", "easting", "e"), "y": ("y", "northing", "n"), "z": ("z", "elevation", "h", "height")}


def read_checkpoints(path: Path, land_cover_column: str = LAND_COVER_COLUMN) -> tuple[np.ndarray, np.ndarray | None]:
    """Read check points: (n, 3) coordinates and the land cover (or None)."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputDataError(f"{path}: cannot read the check points ({exc}).") from None
    lines = [
        (i, line) for i, line in enumerate(text.splitlines(), 1) if line.strip() and not line.lstrip().startswith("#")
    ]
    if not lines:
        raise InputDataError(f"{path}: no check points (the file is empty).")
    header_line, header = lines[0]
    names = [h.strip().lower() for h in next(csv.reader([header]))]
    cols = {}
    for key, aliases in _ALIASES.items():
        found = [names.index(a) for a in aliases if a in names]
        if not found:
            raise InputDataError(
                f"{path}, line {header_line}: no column {key!r} (accepted names: {', '.join(aliases)})."
            )
        cols[key] = found[0]
    lc = names.index(land_cover_column.lower()) if land_cover_column.lower() in names else None
    coords, cover = [], []
    for lineno, line in lines[1:]:
        row = next(csv.reader([line]))
        try:
            coords.append([float(row[cols["x"]]), float(row[cols["y"]]), float(row[cols["z"]])])
        except (ValueError, IndexError):
            raise InputDataError(f"{path}, line {lineno}: x, y and z must be numbers ({line.strip()!r}).") from None
        if not np.all(np.isfinite(coords[-1])):
            raise InputDataError(f"{path}, line {lineno}: x, y and z must be finite numbers.")
        if lc is not None:
            cover.append(row[lc].strip() if lc < len(row) else "")
    if not coords:
        raise InputDataError(f"{path}: the header is there but no check point follows it.")
    return np.array(coords), (np.array(cover, dtype=object) if lc is not None else None)


def checkpoint_errors(dtm_path: Path, points: np.ndarray) -> np.ndarray:
    """DTM - check point height at each (x, y, z) in the DTM's CRS units, in metres (NaN: not covered)."""
    band, transform, crs, _ = read_raster(dtm_path)
    return (sample_dtm(band, transform, points[:, :2]) - points[:, 2]) * raster_units(crs).vertical


def sample_dtm(band: np.ndarray, transform, xy: np.ndarray) -> np.ndarray:
    """Bilinear value of *band* (NaN = nodata) at each (x, y) from cell centres; NaN outside or near nodata."""
    inv = ~transform
    col = inv.a * xy[:, 0] + inv.b * xy[:, 1] + inv.c
    row = inv.d * xy[:, 0] + inv.e * xy[:, 1] + inv.f
    fc, fr = col - 0.5, row - 0.5
    c0, r0 = np.floor(fc).astype(int), np.floor(fr).astype(int)
    rows, cols = band.shape
    out = np.full(len(xy), np.nan)
    ok = (c0 >= 0) & (r0 >= 0) & (c0 + 1 < cols) & (r0 + 1 < rows)
    tc, tr = fc[ok] - c0[ok], fr[ok] - r0[ok]
    a, b = band[r0[ok], c0[ok]], band[r0[ok], c0[ok] + 1]
    c, d = band[r0[ok] + 1, c0[ok]], band[r0[ok] + 1, c0[ok] + 1]
    out[ok] = (a * (1 - tc) + b * tc) * (1 - tr) + (c * (1 - tc) + d * tc) * tr
    return out


def read_control(path: Path) -> np.ndarray:
    """Ground control points: the (n, 3) coordinates of a check-point CSV, float64."""
    xyz, _ = read_checkpoints(path)
    return np.asarray(xyz, dtype=np.float64).reshape(-1, 3)
