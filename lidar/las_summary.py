"""One LAS/LAZ file summarised as plain values: ``pipeline info``'s figures and the report's per-file table.

The header's figures (version, point format, counts, scales, CRS, VLRs) are
read alone; with the points, one pass over them in chunks adds the bounds,
the classes, the returns and the GPS time range.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from lidar import glossary
from lidar.crs import crs_problem, header_crs
from lidar.las_guard import check_strays, header_box, open_las, read_chunks
from lidar.units import Units

#: Points read at a time.
CHUNK = 1_000_000


def gps_time_type(header) -> str | None:
    """The GPS time type global encoding bit 0 states, or None when the point format has no GPS time."""
    if "gps_time" not in header.point_format.dimension_names:
        return None
    return "adjusted standard GPS time" if int(header.global_encoding.gps_time_type) else "GPS week seconds"


def _crs(header) -> tuple[dict, object]:
    """The CRS of a header as a dict (name, EPSG code, units; or why there is none) and as a pyproj CRS."""
    try:
        crs, _ = header_crs(header)  # as the run reads it
    except Exception as exc:  # laspy raises various errors for malformed GeoTIFF keys or WKT
        return {"name": None, "error": f"unreadable ({exc})"}, None
    if crs is None:
        return {"name": None, "error": "none in the header"}, None

    try:
        units = Units.of(crs).describe()
    except ValueError:
        units = "degrees (geographic)"
    return {"name": crs.name, "epsg": crs.to_epsg(), "units": units, "compound": bool(crs.is_compound)}, crs


def crs_fit(crs, mins, maxs) -> tuple[bool | None, str | None]:
    """Whether the points' horizontal bounds *mins*..*maxs* are plausible coordinates in *crs*, and why not.

    The check is the run's (:func:`lidar.crs.crs_problem`).
    """
    problem = crs_problem(crs, mins, maxs)
    return problem is None, problem


def summary(path: Path, points: bool = True) -> dict:
    """Everything ``pipeline info`` says about one LAS/LAZ file, as plain values (JSON-ready).

    With *points* false, only what the header says (no pass over the points).

    Raises
    ------
    InputDataError
        When the file is not a readable LAS/LAZ file, or one a run refuses: the
        same checks (header, LAZ chunk table, the records decoded and checked
        against the header's bounds, :func:`~lidar.las_guard.check_strays`).
    """

    path = Path(path)
    with open_las(path) as reader:
        out, crs = header_summary(path, reader)
        if not points:
            return out
        tally = PointTally(gps="gps_time" in out["dimensions"])
        box, strays = header_box(reader.header), 0
        for chunk in read_chunks(path, reader, CHUNK):
            if len(chunk):
                xyz = (np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z))
                _, strays = check_strays(path, reader.header, box, xyz, tally.n, strays)
                tally.add(chunk)
    out.update(tally.figures())
    out["outside_header_bounds"] = strays
    if crs is not None and tally.n:
        out["crs_fits"], out["crs_problem"] = crs_fit(crs, tally.lo[:2], tally.hi[:2])
    return out


def header_summary(path: Path, reader) -> tuple[dict, object]:
    """What the header of an open file says, as plain values, and its CRS (pyproj; None when it has none)."""
    h = reader.header
    crs_info, crs = _crs(h)
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
        "dimensions": list(h.point_format.dimension_names),
        "extra_bytes": [
            {"name": d.name, "type": d.type_str(), "description": d.description}
            for d in h.point_format.extra_dimensions
        ],
        "vlrs": [_vlr(v) for v in h.vlrs],
        "evlrs": [_vlr(v) for v in (h.evlrs or [])],
    }
    return out, crs


@dataclass
class PointTally:
    """The figures of one pass over the points, added up chunk by chunk."""

    gps: bool  # the point format has GPS time
    n: int = 0
    lo: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))
    hi: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    classes: np.ndarray = field(default_factory=lambda: np.zeros(256, dtype=np.int64))
    returns: np.ndarray = field(default_factory=lambda: np.zeros((16, 16), dtype=np.int64))  # return x of returns
    t_lo: float = np.inf
    t_hi: float = -np.inf
    t_bad: int = 0

    def add(self, chunk) -> None:
        """Count one chunk of points."""
        self.n += len(chunk)
        for axis, values in enumerate((chunk.x, chunk.y, chunk.z)):
            v = np.asarray(values)
            self.lo[axis], self.hi[axis] = min(self.lo[axis], float(v.min())), max(self.hi[axis], float(v.max()))
        self.classes += np.bincount(np.asarray(chunk.classification, dtype=np.int64), minlength=256)[:256]
        r = np.clip(np.asarray(chunk.return_number, dtype=np.int64), 0, 15)
        k = np.clip(np.asarray(chunk.number_of_returns, dtype=np.int64), 0, 15)
        self.returns += np.bincount(r * 16 + k, minlength=256).reshape(16, 16)
        if self.gps:
            t = np.asarray(chunk.gps_time, dtype=np.float64)
            ok = np.isfinite(t)
            self.t_bad += int((~ok).sum())
            if ok.any():
                self.t_lo, self.t_hi = min(self.t_lo, float(t[ok].min())), max(self.t_hi, float(t[ok].max()))

    def figures(self) -> dict:
        """``points_read``, ``bounds``, ``returns``, ``classes`` and ``gps_time`` as plain values."""
        n, classes, returns = self.n, self.classes, self.returns
        out: dict = {"points_read": n, "bounds": {"min": self.lo.tolist(), "max": self.hi.tolist()} if n else None}
        out["returns"] = {
            "return_number": {str(i): int(c) for i, c in enumerate(returns.sum(axis=1)) if c},
            "number_of_returns": {str(i): int(c) for i, c in enumerate(returns.sum(axis=0)) if c},
        }
        out["classes"] = {
            str(c): {"name": glossary.class_name(int(c)), "points": int(classes[c])} for c in np.flatnonzero(classes)
        }
        if self.gps:
            some = n > self.t_bad
            out["gps_time"] = {
                "min": self.t_lo if some else None,
                "max": self.t_hi if some else None,
                "not_finite": self.t_bad,
            }
        else:
            out["gps_time"] = None
        return out


def _vlr(v) -> dict:
    data = getattr(v, "record_data", None)
    size = len(data) if isinstance(data, bytes | bytearray) else None
    return {"user_id": v.user_id, "record_id": int(v.record_id), "description": v.description, "bytes": size}
