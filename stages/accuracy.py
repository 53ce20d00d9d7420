"""DTM vertical accuracy against check points or a truth raster (ASPRS 2014/2023).

ASPRS Positional Accuracy Standards for Digital Geospatial Data (2014;
Edition 2, 2023): non-vegetated vertical accuracy at 95 % confidence
NVA = 1.96 x RMSEz; vegetated vertical accuracy VVA = the 95th percentile of
the absolute errors in vegetated land cover.  Errors are DTM - reference.

Check points: a CSV file with a header, comma-separated, ``#`` starts a
comment; columns ``x``, ``y``, ``z`` (or ``easting``, ``northing``,
``elevation``), in the DTM's CRS, height system and units (feet for a CRS in
feet: :mod:`stages.units`); optionally a land-cover column (default name
``land_cover``).  Errors are reported in metres whatever the CRS.  The DTM is interpolated
bilinearly at each check point; points outside the DTM or on nodata cells
are counted and left out.

Stage ``accuracy`` runs when ``stages.accuracy.checkpoints`` names a file;
``pipeline evaluate dtm`` does the same from the command line.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field

from pipeline.config import InputFile
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageParams

_ALIASES = {"x": ("x", "easting", "e"), "y": ("y", "northing", "n"), "z": ("z", "elevation", "h", "height")}


def read_checkpoints(path: Path, land_cover_column: str = "land_cover") -> tuple[np.ndarray, np.ndarray | None]:
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
    from stages.io import read_raster
    from stages.units import raster_units

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


def vertical_accuracy(errors: np.ndarray, land_cover: np.ndarray | None = None, vegetated=("vegetated",)) -> dict:
    """RMSEz, mean, NVA (1.96 RMSEz, non-vegetated) and VVA (95th percentile |e|, vegetated).

    >>> r = vertical_accuracy(np.array([0.1, -0.1, 0.1, -0.1]))
    >>> round(r["rmse_z"], 6), round(r["nva_95"], 6), r["vva_95"]
    (0.1, 0.196, None)
    """
    e = np.asarray(errors, dtype=np.float64)
    valid = np.isfinite(e)
    veg = np.zeros(len(e), dtype=bool)
    if land_cover is not None:
        veg = np.isin(np.char.lower(land_cover.astype(str)), [v.lower() for v in vegetated])
    nv = e[valid & ~veg]
    vv = e[valid & veg]
    out = {
        "n": int(valid.sum()),
        "outside": int((~valid).sum()),
        "rmse_z": float(np.sqrt(np.mean(e[valid] ** 2))) if valid.any() else None,
        "mean_error": float(np.mean(e[valid])) if valid.any() else None,
        "std": float(np.std(e[valid], ddof=1)) if valid.sum() > 1 else None,
        "max_abs": float(np.max(np.abs(e[valid]))) if valid.any() else None,
        "n_non_vegetated": int(len(nv)),
        "nva_95": float(1.96 * np.sqrt(np.mean(nv**2))) if len(nv) else None,
        "n_vegetated": int(len(vv)),
        "vva_95": float(np.percentile(np.abs(vv), 95)) if len(vv) else None,
    }
    if land_cover is not None:
        out["by_land_cover"] = {
            str(k): {
                "n": int((valid & (land_cover == k)).sum()),
                "rmse_z": float(np.sqrt(np.mean(e[valid & (land_cover == k)] ** 2)))
                if (valid & (land_cover == k)).any()
                else None,
            }
            for k in sorted(set(land_cover.tolist()))
        }
    return out


def compare_with_truth(dtm_path: Path, truth_path: Path) -> np.ndarray:
    """DTM - truth per DTM cell, in metres; the truth raster is resampled (bilinear) onto the DTM grid.

    Each raster's heights are taken in its own CRS's vertical unit (:mod:`stages.units`).
    """
    import rasterio
    from rasterio.warp import Resampling, reproject

    from stages.io import read_raster
    from stages.units import raster_units

    dtm, transform, crs, _ = read_raster(dtm_path)
    with rasterio.open(truth_path) as ts:
        truth_unit = raster_units(ts.crs).vertical
        truth = np.full(dtm.shape, np.nan)
        reproject(
            source=rasterio.band(ts, 1),
            destination=truth,
            dst_transform=transform,
            dst_crs=crs,
            dst_nodata=np.nan,
            resampling=Resampling.bilinear,
        )
    return dtm * raster_units(crs).vertical - truth * truth_unit


class AccuracyParams(StageParams):
    checkpoints: InputFile | None = Field(
        None, description="CSV of check points (x, y, z[, land_cover]); none = no check"
    )
    land_cover_column: str = Field("land_cover", description="name of the land-cover column in the check points")
    vegetated: list[str] = Field(["vegetated"], description="land-cover values counted as vegetated (for VVA)")


class Accuracy(Stage):
    name = "accuracy"
    version = "1"
    Params = AccuracyParams
    description = "DTM vertical accuracy at check points (runs when checkpoints is set)"
    inputs = ("dtm",)
    outputs: ClassVar = {"accuracy": "accuracy.json"}
    products: ClassVar = {"accuracy": "accuracy.json"}

    def is_enabled(self, params, config) -> bool:
        return params.enabled and params.checkpoints is not None

    def external_files(self, params, config) -> list[Path]:
        return [params.checkpoints] if params.checkpoints else []

    def run(self, ctx) -> None:
        import json

        p = ctx.params
        points, cover = read_checkpoints(p.checkpoints, p.land_cover_column)
        errors = checkpoint_errors(ctx.inputs["dtm"], points)  # metres, whatever the CRS's units
        result = vertical_accuracy(errors, cover, p.vegetated)
        ctx.metrics.update(result)
        ctx.outputs["accuracy"].write_text(json.dumps(result, indent=2))
        ctx.log.info(
            "RMSEz %.3f m at %d check points (%d outside the DTM)",
            result["rmse_z"] or float("nan"),
            result["n"],
            result["outside"],
        )
