"""TODO docstring: carried out of dtm.commands.info."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from dtm.common import glossary
from dtm.common.las_guard import las_parse_errors, open_las
from pipeline.errors import InputDataError

#: Points read at a time.
CHUNK = 1_000_000


def gps_time_type(header) -> str | None:
    """The GPS time type global encoding bit 0 states, or None when the point format has no GPS time."""
    if "gps_time" not in header.point_format.dimension_names:
        return None
    return "adjusted standard GPS time" if int(header.global_encoding.gps_time_type) else "GPS week seconds"


def _crs(header) -> tuple[dict, object]:
    """The CRS of a header as a dict (name, EPSG code, units; or why there is none) and as a pyproj CRS."""
    from dtm.common.crs import header_crs

    try:
        crs, _ = header_crs(header)  # as the run reads it
    except Exception as exc:  # laspy raises various errors for malformed GeoTIFF keys or WKT
        return {"name": None, "error": f"unreadable ({exc})"}, None
    if crs is None:
        return {"name": None, "error": "none in the header"}, None
    from dtm.common.units import Units

    try:
        units = Units.of(crs).describe()
    except ValueError:
        units = "degrees (geographic)"
    return {"name": crs.name, "epsg": crs.to_epsg(), "units": units, "compound": bool(crs.is_compound)}, crs


def crs_fit(crs, mins, maxs) -> tuple[bool | None, str | None]:
    """Whether the points' horizontal bounds *mins*..*maxs* are plausible coordinates in *crs*, and why not.

    The check is the run's (:func:`dtm.common.crs.crs_problem`).
    """
    from dtm.common.crs import crs_problem

    problem = crs_problem(crs, mins, maxs)
    return problem is None, problem


def summary(path: Path, points: bool = True) -> dict:
    """Everything ``pipeline info`` says about one LAS/LAZ file, as plain values (JSON-ready).

    With *points* false, only what the header says (no pass over the points).

    Raises
    ------
    InputDataError
        When the file is not a readable LAS/LAZ file.
    """

    path = Path(path)
    with open_las(path) as reader:
        h = reader.header
        crs_info, crs = _crs(h)
        dims = list(h.point_format.dimension_names)
        out: dict = {
            "file": str(path),
            "bytes": path.stat().st_size,
            "version": str(h.version),
            "point_format": h.point_format.id,
            "compressed": bool(path.suffix.lower() == ".laz" or getattr(reader, "laszip_vlr", None)),
            "points": int(h.point_count),
            "points_by_return_header": [int(v) for v in h.number_of_points_by_return],
            "system_identifier": h.system_identifier,
            "generating_software": h.generating_software,
            "creation_date": h.creation_date.isoformat() if h.creation_date else None,
            "global_encoding": int(h.global_encoding.value),
            "gps_time_type": gps_time_type(h),
            "scale": [float(v) for v in h.scales],
            "offset": [float(v) for v in h.offsets],
            "bounds_header": {"min": [float(v) for v in h.mins], "max": [float(v) for v in h.maxs]},
            "crs": crs_info,
            "crs_fits": None,  # True / False from the run's CRS check (crs_fit); None: not checked
            "crs_problem": None,
            "dimensions": dims,
            "extra_bytes": [
                {"name": d.name, "type": d.type_str(), "description": d.description}
                for d in h.point_format.extra_dimensions
            ],
            "vlrs": [_vlr(v) for v in h.vlrs],
            "evlrs": [_vlr(v) for v in (h.evlrs or [])],
        }
        if not points:
            return out
        n = 0
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        classes = np.zeros(256, dtype=np.int64)
        returns = np.zeros((16, 16), dtype=np.int64)  # return number x number of returns
        t_lo, t_hi, t_bad = np.inf, -np.inf, 0
        try:
            for chunk in reader.chunk_iterator(CHUNK):
                if not len(chunk):
                    continue
                n += len(chunk)
                for axis, values in enumerate((chunk.x, chunk.y, chunk.z)):
                    v = np.asarray(values)
                    lo[axis], hi[axis] = min(lo[axis], float(v.min())), max(hi[axis], float(v.max()))
                classes += np.bincount(np.asarray(chunk.classification, dtype=np.int64), minlength=256)[:256]
                r = np.clip(np.asarray(chunk.return_number, dtype=np.int64), 0, 15)
                k = np.clip(np.asarray(chunk.number_of_returns, dtype=np.int64), 0, 15)
                returns += np.bincount(r * 16 + k, minlength=256).reshape(16, 16)
                if "gps_time" in dims:
                    t = np.asarray(chunk.gps_time, dtype=np.float64)
                    ok = np.isfinite(t)
                    t_bad += int((~ok).sum())
                    if ok.any():
                        t_lo, t_hi = min(t_lo, float(t[ok].min())), max(t_hi, float(t[ok].max()))
        except las_parse_errors() as exc:
            raise InputDataError(f"{path}: unreadable after point {n:,} ({exc}).") from None
    out["points_read"] = n
    out["bounds"] = {"min": lo.tolist(), "max": hi.tolist()} if n else None
    out["returns"] = {
        "return_number": {str(i): int(c) for i, c in enumerate(returns.sum(axis=1)) if c},
        "number_of_returns": {str(i): int(c) for i, c in enumerate(returns.sum(axis=0)) if c},
    }
    out["classes"] = {
        str(c): {"name": glossary.class_name(int(c)), "points": int(classes[c])} for c in np.flatnonzero(classes)
    }
    if "gps_time" in dims:
        out["gps_time"] = {"min": t_lo if n > t_bad else None, "max": t_hi if n > t_bad else None, "not_finite": t_bad}
    else:
        out["gps_time"] = None
    if crs is not None and n:
        out["crs_fits"], out["crs_problem"] = crs_fit(crs, lo[:2], hi[:2])
    return out


def _vlr(v) -> dict:
    data = getattr(v, "record_data", None)
    size = len(data) if isinstance(data, bytes | bytearray) else None
    return {"user_id": v.user_id, "record_id": int(v.record_id), "description": v.description, "bytes": size}
