"""The measured values the survey is accepted on (:mod:`stages.report.acceptance`), from the cloud and metrics."""

from __future__ import annotations

import numpy as np

from stages.report.acceptance import (
    MEASURES,
    checkpoint_warnings,
    decks_in_dem,
    pulse_density,
    rising_rivers,
    unflat_water_bodies,
    voids,
)
from stages.report.inputs import ReportInputs


def measure(metrics: dict, data: ReportInputs) -> tuple[dict, dict, dict]:
    """The measured values of :data:`~stages.report.acceptance.MEASURES`, why any is missing, and the voids.

    Returns
    -------
    measured : dict
        Measure key -> value (None: not measured), for
        :func:`~stages.report.acceptance.evaluate`.
    why : dict
        Measure key -> why it was not measured.
    extra : dict
        ``void_mask`` (per DTM cell) and ``void_side_m`` when voids were counted;
        ``covered_m2``, the covered area.
    """
    units = data.cloud.units
    cell_m = data.frame.cell * units.horizontal
    out: dict = dict.fromkeys(MEASURES)
    why: dict = {}
    extra: dict = {}
    anpd, covered = (
        pulse_density(data.cloud.first_returns, cell_m) if data.cloud.first_returns is not None else (None, 0.0)
    )
    out["anpd"] = anpd
    extra["covered_m2"] = covered
    if anpd:
        count, mask, side = voids(data.cloud.first_returns, cell_m, 1.0 / np.sqrt(anpd))
        out["voids"] = count
        extra.update(void_mask=mask, void_side_m=side)
    values, reasons = checkpoint_measures(metrics.get("accuracy"))
    out.update(values)
    why.update(reasons)
    out["smooth_surface_repeatability"] = data.cloud.repeatability_m
    if data.cloud.repeatability_m is None:
        why["smooth_surface_repeatability"] = "no level cell with 4 ground single returns of one strip"
    after = data.differences[1] if data.differences is not None else None
    values, reasons = swath_measures(metrics.get("strip_adjust") or {}, after, units.vertical)
    out.update(values)
    why.update(reasons)
    if out["anpd"] is None:
        why["anpd"] = why["voids"] = "no first return"
    out["class_0"] = data.cloud.class_0_kept
    out["dem_float_bits"] = data.dem_float_bits
    out["dem_nodata"] = data.dem_nodata
    if data.dem_nodata is None:
        why["dem_nodata"] = "dtm.tif declares no nodata value"
    if data.water_bodies is not None:
        transform_m = units.transform_to_metres(data.frame.transform)
        out["unflat_water"] = unflat_water_bodies(data.dtm * units.vertical, data.water_bodies, transform_m)
        out["rising_rivers"] = rising_rivers(data.dtm * units.vertical, data.water_bodies, transform_m)
        if out["rising_rivers"] is None:
            why["rising_rivers"] = "no river among the flattened water bodies (all of them flat at one level)"
    else:
        why["unflat_water"] = why["rising_rivers"] = (
            "no water bodies (stages.classify_water and its bodies, stages.rasterize.hydro_flatten)"
        )
    cloud = data.cloud
    if cloud.class_grid is not None and cloud.top_grid is not None:
        v = units.vertical
        out["decks_in_dem"] = decks_in_dem(data.dtm * v, cloud.class_grid, cloud.top_grid * v)
    if out["decks_in_dem"] is None:
        why["decks_in_dem"] = "no bridge deck (class 17, stages.classify_objects.bridges) in the classified points"
    return out, why, extra


def sampling_warnings(data: ReportInputs, covered_m2: float) -> list[str]:
    """Sentences on check points too few or bunched (:func:`~stages.report.acceptance.checkpoint_warnings`)."""
    cp = data.checkpoints
    if cp is None:
        return []
    on = np.isfinite(cp["error"])
    metres = data.cloud.units.horizontal
    return checkpoint_warnings(np.asarray(cp["x"])[on] * metres, np.asarray(cp["y"])[on] * metres, covered_m2)


def checkpoint_measures(accuracy: dict | None) -> tuple[dict, dict]:
    """NVA and VVA at the check points, as both ASPRS editions state them, and why any is missing.

    From the metrics of ``accuracy``: ``nva_95`` and ``vva_95`` (Edition 1),
    ``rmse_z_nv`` (``nva_95`` / 1.96) and ``vva_rmse_z`` (Edition 2).
    """
    keys = ("nva_95", "rmse_z_nv", "vva_95", "vva_rmse_z")
    acc = {k: v for k, v in (accuracy or {}).items() if k != "truth"}  # check points only
    if not acc:
        return {}, dict.fromkeys(keys, "no check points (stages.accuracy.checkpoints)")
    nva = acc.get("nva_95")
    values = {
        "nva_95": nva,
        "rmse_z_nv": nva / 1.96 if nva is not None else None,
        "vva_95": acc.get("vva_95"),
        "vva_rmse_z": acc.get("vva_rmse_z"),
    }
    why = {}
    if nva is None:
        why["nva_95"] = why["rmse_z_nv"] = "no non-vegetated check point on the DTM"
    if values["vva_95"] is None:
        why["vva_95"] = why["vva_rmse_z"] = "no vegetated check point (land cover column and stages.accuracy.vegetated)"
    elif values["vva_rmse_z"] is None:
        why["vva_rmse_z"] = "accuracy.json has no vva_rmse_z (written by accuracy before version 4)"
    return values, why


def swath_measures(adjust: dict, after: np.ndarray | None, vertical: float) -> tuple[dict, dict]:
    """Swath overlap differences, and why they are missing.

    Parameters
    ----------
    adjust : dict
        Metrics of ``strip_adjust`` (``overlap_rms_after_m``, ``note``).
    after : ndarray or None
        ``strip_difference_after.tif`` (CRS units).
    vertical : float
        Metres per vertical unit of the CRS.
    """
    values = {"swath_overlap_rmsdz": adjust.get("overlap_rms_after_m")}
    if after is not None and np.isfinite(after).any():
        values["swath_overlap_max"] = float(np.nanmax(np.abs(after))) * vertical
    why = {}
    if values["swath_overlap_rmsdz"] is None:
        why["swath_overlap_rmsdz"] = why["swath_overlap_max"] = (
            adjust.get("note") or "strip adjustment did not run (stages.strip_adjust)"
        )
    return values, why
