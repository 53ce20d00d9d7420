"""DTM vertical accuracy: NVA and VVA at check points (ASPRS), and the DTM against a truth raster cell by cell.

Both editions of the ASPRS Positional Accuracy Standards for Digital
Geospatial Data.  Edition 1 (2014, doi:10.14358/PERS.81.3.A1-A26; the USGS
Lidar Base Specification to 2023 rev. A): NVA = 1.96 RMSEz at non-vegetated
check points (``nva_95``), VVA = the 95th percentile of |error| at vegetated
ones (``vva_95``).  Edition 2 (2023; the LBS from 2024 rev. A) drops the 95 %
measures: NVA is the RMSEz at non-vegetated check points (``nva_95`` / 1.96),
VVA the RMSEz at vegetated ones (``vva_rmse_z``), reported without pass/fail.
Errors are DTM - reference, in metres whatever the CRS.  The truth raster is
resampled onto the DTM's cells and every cell compared; why the figures are
split by relief and land cover: ``docs/stages/accuracy.md``.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import rasterio
from rasterio.warp import Resampling, reproject
from scipy import ndimage

from lidar.glossary import class_name
from lidar.rasters import read_raster
from lidar.units import raster_units


def vertical_accuracy(
    errors: np.ndarray, land_cover: np.ndarray | None = None, vegetated: Sequence[str] = ("vegetated",)
) -> dict:
    """RMSEz, mean, NVA (1.96 RMSEz, non-vegetated) and VVA (95th percentile |e| and RMSEz, vegetated).

    >>> r = vertical_accuracy(np.array([0.1, -0.1, 0.1, -0.1]))
    >>> round(r["rmse_z"], 6), round(r["nva_95"], 6), r["vva_95"], r["vva_rmse_z"]
    (0.1, 0.196, None, None)
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
        "vva_rmse_z": float(np.sqrt(np.mean(vv**2))) if len(vv) else None,
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
    dtm, transform, crs, _ = read_raster(dtm_path)
    truth, truth_crs = _onto(truth_path, dtm.shape, transform, crs, Resampling.bilinear)
    return dtm * raster_units(crs).vertical, truth * raster_units(truth_crs).vertical


def land_cover_on_dtm_cells(dtm_path: Path, land_cover_path: Path) -> np.ndarray:
    """The codes of a land-cover raster at the DTM's cells (the nearest cell's; -1 outside it or on its nodata)."""
    dtm, transform, crs, _ = read_raster(dtm_path)
    codes, _ = _onto(land_cover_path, dtm.shape, transform, crs, Resampling.nearest)
    return np.where(np.isfinite(codes), np.nan_to_num(codes), -1).astype(np.int64)


def _onto(path: Path, shape: tuple[int, int], transform, crs, resampling):
    """Band 1 of a raster resampled onto a grid (float64, NaN = nodata or outside), and the raster's CRS."""
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
#: lidar DTM's error on open ground (ASPRS 2023's 10-cm class: RMSEz 10 cm, 19.6 cm at 95 % in Edition 1),
#: so a misclassification, not noise; 5 m, a building or a bridge deck left in the DTM.
TRUTH_OFF_M = (1.0, 5.0)


#: Relief of the truth (max - min over the 3 x 3 DTM cells around a cell, metres) from which
#: :func:`truth_accuracy` counts a cell as steep: twice :data:`TRUTH_OFF_M`'s 1 m, so that the truth
#: changes by 1 m or more within one cell of it and a cell's shift is already a 1 m error (a wall, a
#: bank, a terrace's step; a 1 m truth raster resampled onto 0.5 m cells blurs each wall over a metre).
TRUTH_STEEP_M = 2.0


def truth_accuracy(dtm: np.ndarray, truth: np.ndarray, land_cover: np.ndarray | None = None) -> dict:
    """The DTM against a truth raster over every DTM cell with a value (metres; errors are DTM - truth).

    Keys: ``cells`` (DTM cells with a value), ``no_truth`` (of those, without
    truth), ``n`` (cells compared), ``rmse``, ``mean``, ``off_1m`` and
    ``off_5m`` (fractions more than 1 m / 5 m off), ``max_abs``, ``max_above``,
    ``max_below``; the same figures in ``by_relief`` (``under_2m`` and
    ``2m_or_more``: the truth's relief over 3 x 3 cells against
    :data:`TRUTH_STEEP_M`) and, with *land_cover* (codes per cell, -1 none),
    per code in ``by_land_cover`` with its ASPRS class name.

    >>> r = truth_accuracy(np.array([[10.0, 10.0], [10.0, np.nan]]), np.array([[10.0, 8.0], [np.nan, 10.0]]))
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
        out["by_land_cover"] = {
            str(code): {"name": class_name(int(code)), **_error_figures((dtm - truth)[both & (land_cover == code)])}
            for code in np.unique(land_cover[both])
            if code >= 0
        }
    return out


def truth_relief(truth: np.ndarray) -> np.ndarray:
    """Max - min of *truth* over the 3 x 3 cells around each cell (cells without a value left out; NaN where
    none has one)."""
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
