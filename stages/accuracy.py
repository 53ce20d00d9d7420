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

Truth raster (``stages.accuracy.truth_dtm``, e.g. a simulated survey's
``truth/terrain.tif``): resampled bilinearly onto the DTM's cells (GDAL's
warper, from cell centres), then every DTM cell with a value is compared
(:func:`truth_accuracy`): RMS, mean, the share of cells more than 1 m and
5 m off, the largest errors; with ``truth_land_cover`` (a raster of ASPRS
class codes, nearest cell), the same by land cover; and the same apart
where the truth itself is steep (``by_relief``: it varies by 2 m or more
over the 3 x 3 DTM cells around a cell, so that a shift of one cell, such
as the truth raster's own resampling across a wall, is already more than
the 1 m threshold) and elsewhere.  Check points say how well the DTM fits open
ground; the truth raster shows what they miss (a building or a bridge deck
left as ground, channel banks).

Stage ``accuracy`` runs when ``stages.accuracy.checkpoints`` or
``stages.accuracy.truth_dtm`` names a file; ``pipeline evaluate dtm`` does
the same from the command line.
"""

from __future__ import annotations

import csv
from pathlib import Path
from typing import ClassVar

import numpy as np
from pydantic import Field, model_validator

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


def truth_on_dtm_cells(dtm_path: Path, truth_path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The DTM and the truth resampled onto its cells (bilinear, from cell centres), both in metres; NaN = nodata.

    The truth's nodata cells take no part in the bilinear weights (GDAL's
    warper renormalises over the valid ones); DTM cells outside the truth
    raster are NaN.
    """
    from rasterio.warp import Resampling

    from stages.io import read_raster
    from stages.units import raster_units

    dtm, transform, crs, _ = read_raster(dtm_path)
    truth, truth_crs = _onto(truth_path, dtm.shape, transform, crs, Resampling.bilinear)
    return dtm * raster_units(crs).vertical, truth * raster_units(truth_crs).vertical


def land_cover_on_dtm_cells(dtm_path: Path, land_cover_path: Path) -> np.ndarray:
    """The codes of a land-cover raster at the DTM's cells (the nearest cell's; -1 outside it or on its nodata)."""
    from rasterio.warp import Resampling

    from stages.io import read_raster

    dtm, transform, crs, _ = read_raster(dtm_path)
    codes, _ = _onto(land_cover_path, dtm.shape, transform, crs, Resampling.nearest)
    return np.where(np.isfinite(codes), np.nan_to_num(codes), -1).astype(np.int64)


def _onto(path: Path, shape: tuple[int, int], transform, crs, resampling):
    """Band 1 of a raster resampled onto a grid (float64, NaN = nodata or outside), and the raster's CRS."""
    import rasterio
    from rasterio.warp import reproject

    with rasterio.open(path) as src:
        out = np.full(shape, np.nan)
        reproject(
            source=rasterio.band(src, 1),
            destination=out,
            dst_transform=transform,
            dst_crs=crs,
            dst_nodata=np.nan,
            resampling=resampling,
        )
        return out, src.crs


#: |DTM - truth| thresholds (metres) of :func:`truth_accuracy`: 1 m is far beyond a
#: lidar DTM's error on open ground (ASPRS 2023's 10-cm class allows NVA = 19.6 cm),
#: so a misclassification, not noise; 5 m, a building or a bridge deck left in the DTM.
TRUTH_OFF_M = (1.0, 5.0)

#: Relief of the truth (max - min over the 3 x 3 DTM cells around a cell, metres) from which
#: :func:`truth_accuracy` counts a cell as steep: twice :data:`TRUTH_OFF_M`'s 1 m, so that the truth
#: changes by 1 m or more within one cell of it and a cell's shift is already a 1 m error (a wall, a
#: bank, a terrace's step; a 1 m truth raster resampled onto 0.5 m cells blurs each wall over a metre).
TRUTH_STEEP_M = 2.0


def truth_accuracy(dtm: np.ndarray, truth: np.ndarray, land_cover: np.ndarray | None = None) -> dict:
    """The DTM against a truth raster over every DTM cell with a value (metres; errors are DTM - truth).

    Keys: ``cells`` (DTM cells with a value), ``no_truth`` (of those, where
    the truth has none), ``n`` (cells compared), ``rmse``, ``mean``,
    ``off_1m`` and ``off_5m`` (fractions of the cells more than 1 m / 5 m
    off, either way), ``max_abs``, ``max_above``, ``max_below``.  With
    *land_cover* (integer codes per cell, -1 = none), ``by_land_cover``: per
    code, its ASPRS class name and the same figures over its cells.
    ``by_relief``: the same figures where the truth's relief over the 3 x 3
    cells around a cell is under :data:`TRUTH_STEEP_M` (``under_2m``) and
    where it is not (``2m_or_more``).

    >>> dtm = np.array([[10.0, 10.0], [10.0, np.nan]])
    >>> r = truth_accuracy(dtm, np.array([[10.0, 8.0], [np.nan, 10.0]]))
    >>> r["cells"], r["no_truth"], r["n"], r["rmse"], r["off_1m"], r["max_above"]
    (3, 1, 2, 1.4142135623730951, 0.5, 2.0)
    """
    has = np.isfinite(dtm)
    both = has & np.isfinite(truth)
    out = {"cells": int(has.sum()), "no_truth": int((has & ~both).sum()), **_error_figures((dtm - truth)[both])}
    steep = truth_relief(truth) >= TRUTH_STEEP_M
    out["by_relief"] = {
        "under_2m": _error_figures((dtm - truth)[both & ~steep]),
        "2m_or_more": _error_figures((dtm - truth)[both & steep]),
    }
    if land_cover is not None:
        from stages.glossary import class_name

        out["by_land_cover"] = {
            str(code): {"name": class_name(int(code)), **_error_figures((dtm - truth)[both & (land_cover == code)])}
            for code in np.unique(land_cover[both])
            if code >= 0
        }
    return out


def truth_relief(truth: np.ndarray) -> np.ndarray:
    """Max - min of *truth* over the 3 x 3 cells around each cell (cells without a value left out; NaN where
    none has one)."""
    from scipy import ndimage

    has = np.isfinite(truth)
    high = ndimage.maximum_filter(np.where(has, truth, -np.inf), size=3, mode="nearest")
    low = ndimage.minimum_filter(np.where(has, truth, np.inf), size=3, mode="nearest")
    with np.errstate(invalid="ignore"):
        return np.where(np.isfinite(high), high - low, np.nan)


def _error_figures(e: np.ndarray) -> dict:
    some = e.size > 0
    return {
        "n": int(e.size),
        "rmse": float(np.sqrt(np.mean(e**2))) if some else None,
        "mean": float(np.mean(e)) if some else None,
        "off_1m": float(np.mean(np.abs(e) > TRUTH_OFF_M[0])) if some else None,
        "off_5m": float(np.mean(np.abs(e) > TRUTH_OFF_M[1])) if some else None,
        "max_abs": float(np.max(np.abs(e))) if some else None,
        "max_above": float(max(np.max(e), 0.0)) if some else None,
        "max_below": float(min(np.min(e), 0.0)) if some else None,
    }


class AccuracyParams(StageParams):
    checkpoints: InputFile | None = Field(
        None, description="CSV of check points (x, y, z[, land_cover]); none = no check"
    )
    truth_dtm: InputFile | None = Field(
        None,
        description="raster of the true terrain (a simulated survey's truth/terrain.tif), compared with the DTM "
        "at every cell (bilinear onto the DTM's cells); none = no such check",
    )
    truth_land_cover: InputFile | None = Field(
        None,
        description="raster of land-cover codes (ASPRS class numbers: 2 ground, 5 vegetation, 6 building, 9 water, "
        "17 bridge deck) for the truth_dtm figures by land cover (nearest cell onto the DTM's); none = not split",
    )
    land_cover_column: str = Field("land_cover", description="name of the land-cover column in the check points")
    vegetated: list[str] = Field(["vegetated"], description="land-cover values counted as vegetated (for VVA)")

    @model_validator(mode="after")
    def _land_cover_needs_truth(self):
        if self.truth_land_cover is not None and self.truth_dtm is None:
            raise ValueError("truth_land_cover splits the truth_dtm figures: set truth_dtm too")
        return self


class Accuracy(Stage):
    name = "accuracy"
    version = "3"  # 3: truth figures by relief; 2: the DTM against a truth raster (truth_dtm)
    Params = AccuracyParams
    description = "DTM vertical accuracy at check points and against a truth raster (runs when either is set)"
    inputs = ("dtm",)
    outputs: ClassVar = {"accuracy": "accuracy.json"}
    products: ClassVar = {"accuracy": "accuracy.json"}

    def is_enabled(self, params, config) -> bool:
        return params.enabled and (params.checkpoints is not None or params.truth_dtm is not None)

    def external_files(self, params, config) -> list[Path]:
        return [f for f in (params.checkpoints, params.truth_dtm, params.truth_land_cover) if f is not None]

    def run(self, ctx) -> None:
        import json

        p = ctx.params
        result: dict = {}
        if p.checkpoints is not None:
            points, cover = read_checkpoints(p.checkpoints, p.land_cover_column)
            errors = checkpoint_errors(ctx.inputs["dtm"], points)  # metres, whatever the CRS's units
            result = vertical_accuracy(errors, cover, p.vegetated)
            ctx.log.info(
                "RMSEz %.3f m at %d check points (%d outside the DTM)",
                result["rmse_z"] or float("nan"),
                result["n"],
                result["outside"],
            )
        if p.truth_dtm is not None:
            result["truth"] = truth = _truth_block(ctx.inputs["dtm"], p.truth_dtm, p.truth_land_cover)
            ctx.log.info(
                "against %s: RMS %.3f m over %d cells, %.1f %% more than 1 m off, %.1f %% more than 5 m",
                Path(p.truth_dtm).name,
                truth["rmse"] or float("nan"),
                truth["n"],
                100 * (truth["off_1m"] or 0.0),
                100 * (truth["off_5m"] or 0.0),
            )
        ctx.metrics.update(result)
        ctx.outputs["accuracy"].write_text(json.dumps(result, indent=2))


def _truth_block(dtm_path: Path, truth_path: Path, land_cover_path: Path | None = None) -> dict:
    """accuracy.json's ``truth``: the files, how they were resampled, :func:`truth_accuracy`."""
    from rasterio.errors import RasterioError

    path = truth_path
    try:
        dtm, truth = truth_on_dtm_cells(dtm_path, truth_path)
        cover = None
        if land_cover_path is not None:
            path = land_cover_path
            cover = land_cover_on_dtm_cells(dtm_path, land_cover_path)
    except RasterioError as exc:
        raise InputDataError(f"{path}: cannot be read as a raster ({exc}).") from None
    out: dict = {"file": Path(truth_path).name, "resampling": "bilinear"}
    if land_cover_path is not None:
        out["land_cover_file"] = Path(land_cover_path).name
    out.update(truth_accuracy(dtm, truth, cover))
    if out["n"] == 0:
        raise InputDataError(
            f"{truth_path}: no DTM cell has a truth value (does the raster cover the survey, in the same CRS?)."
        )
    return out
