"""What the report draws besides the metrics: :class:`ReportInputs`, and the readers of the files it takes."""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pyogrio

from lidar.checkpoints import checkpoint_errors, read_checkpoints
from lidar.rasters import read_raster
from lidar.units import raster_units
from stages.report.acceptance import DEFAULT_SPECIFICATION
from stages.report.cloud import CloudSummary
from stages.report.maps import MapFrame


@dataclass
class ReportInputs:
    """Everything :func:`build_report` draws, besides the metrics."""

    dtm: np.ndarray
    density: np.ndarray  # points per cell
    frame: MapFrame  # of the DTM
    cloud: CloudSummary
    input_files: list[tuple[str, str]] = field(default_factory=list)  # (role, path)
    input_info: list[dict] = field(default_factory=list)  # las_info of LAS inputs
    corrections: dict | None = None  # strip_corrections.json
    differences: tuple | None = None  # (before, after, MapFrame) in CRS units
    uncertainty: np.ndarray | None = None  # DTM 1-sigma, CRS units
    checkpoints: dict | None = None  # id, x, y, z, land_cover, dtm, error (m)
    trajectory: list[tuple[np.ndarray, np.ndarray, str]] | None = None  # flight lines in map coordinates
    specification: str = DEFAULT_SPECIFICATION
    dem_float_bits: int = 32  # of dtm.tif's cell type (0: not floating point)
    dem_nodata: float | None = None  # dtm.tif's nodata value
    water_bodies: list | None = None  # the flattened bodies of water.gpkg: (rings, level) in metres; None: no file


def checkpoint_rows(path: str | Path, land_cover_column: str, dtm_path: str | Path) -> dict:
    """The check points with the DTM's height and the error (DTM − check point, metres).

    Returns
    -------
    dict
        ``id`` (the file's ``id`` column, or 1, 2, ...), ``land_cover``, ``x``,
        ``y``, ``z`` and ``dtm`` (CRS units), ``error`` (metres; NaN off the DTM).
    """
    xyz, cover = read_checkpoints(path, land_cover_column)
    errors = checkpoint_errors(dtm_path, xyz)
    ids = checkpoint_ids(path, len(xyz))
    crs = read_raster(dtm_path)[2]
    metres = raster_units(crs).vertical
    return {
        "id": ids,
        "land_cover": list(cover) if cover is not None else [""] * len(xyz),
        "x": xyz[:, 0],
        "y": xyz[:, 1],
        "z": xyz[:, 2],
        "dtm": xyz[:, 2] + errors / metres,
        "error": errors,
    }


def checkpoint_ids(path: str | Path, count: int) -> list[str]:
    """The ``id`` column of a check-point CSV, or 1 to *count* when it has none."""
    lines = [
        ln
        for ln in Path(path).read_text(encoding="utf-8").splitlines()
        if ln.strip() and not ln.lstrip().startswith("#")
    ]
    names = [h.strip().lower() for h in next(csv.reader([lines[0]]))]
    if "id" not in names:
        return [str(i + 1) for i in range(count)]
    col = names.index("id")
    return [row[col] if col < len(row) else "" for row in csv.reader(lines[1:])]


def read_flight_lines(path: str | Path) -> list[tuple[np.ndarray, np.ndarray, str]]:
    """The flight lines of ``trajectory.gpkg`` (:func:`stages.georeference.strips.write_flight_lines`): (x, y, 'strip N')."""
    meta, _, geometry, fields = pyogrio.raw.read(str(path))
    strips = fields[list(meta["fields"]).index("strip")]
    out = []
    for strip, wkb in zip(strips, geometry, strict=True):
        xy = np.frombuffer(bytes(wkb), dtype="<f8", offset=9).reshape(-1, 3 if _has_z(wkb) else 2)
        out.append((xy[:, 0], xy[:, 1], f"strip {int(strip)}"))
    return out


def _has_z(wkb: bytes) -> bool:
    kind = int.from_bytes(bytes(wkb)[1:5], "little")
    return kind in (1002, 0x80000002)
