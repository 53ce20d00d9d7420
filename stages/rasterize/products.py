"""The rasters of one tile from its points (DTM, DSM, nDSM, density, uncertainty), and the survey's figures.

Grids are in metres and NaN means nodata; the tile task
(:func:`stages.rasterize.tile_rasters.rasterize_tile`) converts the heights to
the CRS's unit when it writes them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from lidar.grid import Grid, cell_mean, fill_nearest
from pipeline.log import stage_progress
from stages.rasterize.decks import across_decks, deck_footprint
from stages.rasterize.floor import understory
from stages.rasterize.interpolate import in_hull
from stages.rasterize.interpolators import INTERPOLATORS
from stages.rasterize.params import RasterizeParams

if TYPE_CHECKING:
    from collections.abc import Callable

    from pipeline.log import Progress


def interpolate_dtm(
    ground: np.ndarray | list[np.ndarray], grid: Grid, params: RasterizeParams, progress: Progress | None = None
) -> np.ndarray:
    """The DTM of *ground* points on *grid* by the configured method (NaN = nodata)."""
    return INTERPOLATORS[params.method].function(ground, grid, params, progress)


@dataclass
class TileCloud:
    """What the rasters of a tile need of its points (core plus buffer), on the tile's wide grid.

    ``ground``: x, y, z of the ground points (n, 3), in file order (None once
    handed to the TIN); ``highest`` and ``count``: the highest usable return
    and the usable points per cell; ``sigma``: the ground points' vertical
    sigma (None when the uncertainty is not made).
    """

    ground: np.ndarray | None
    highest: np.ndarray
    count: np.ndarray
    sigma: np.ndarray | None = None
    decks: np.ndarray | None = None  # bridge-deck points (class 17) per cell; None: none in the tile


def tile_rasters(
    cloud: TileCloud,
    core: Grid,
    wide: Grid,
    crop: tuple[slice, slice],
    params: RasterizeParams,
    inside: np.ndarray | None = None,
    flat: Callable[[Grid], np.ndarray] | None = None,
    breaklines: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The rasters of a tile's *core* cells (*crop* of its *wide* grid), in metres; NaN = nodata.

    ``dtm`` (:func:`interpolate_dtm`, of the ground points but the
    understory's, :mod:`stages.rasterize.floor`), ``dsm`` (the highest return, gaps
    filled from the nearest cell within ``nodata_distance``, else the DTM),
    ``ndsm`` (DSM - DTM, at least 0), ``density`` (points per cell) and,
    with sigmas, ``dtm_uncertainty`` (their mean per cell, gaps filled as
    the DSM's, where the DTM has a value).  *flat*: the water level of
    each cell of a grid (NaN: none), that the DTM takes there
    (hydro-flattening, :mod:`lidar.water_bodies`); *breaklines*: the
    water bodies' outlines as 3-D vertices (n, 3), interpolated with the
    ground points (enforced in the TIN).  Under bridge decks
    (``cloud.decks``, when ``params.bridge_decks``) the DTM is interpolated
    across each deck (:mod:`stages.rasterize.decks`), on the core and
    ``max_deck_width`` around it.  Core cells not *inside* the survey's
    outline (:mod:`stages.rasterize.outline`) are nodata in all but the
    density.  With the TIN and no sigma, the ground points are handed over:
    *cloud* no longer holds them.
    """
    max_cells = params.nodata_distance / params.resolution
    dsm = fill_nearest(cloud.highest, max_cells=max_cells)[crop]
    ground = cloud.ground
    if params.floor_tolerance is not None and len(ground) >= 3:  # the DTM's ground: without the understory
        above = understory(ground, cloud.highest, wide, cell=params.floor_cell, tolerance=params.floor_tolerance)
        if above.any():  # else no copy: a dense open survey's ground is left as it is
            ground = ground[~above]
    if breaklines is not None and len(breaklines) and len(ground) >= 3:
        ground = np.vstack((ground, breaklines[inside_hull(ground, breaklines)]))
    decks = cloud.decks is not None and params.bridge_decks and bool(cloud.decks.any())
    grid, sub = _around(core, wide, crop, params.max_deck_width if decks else 0.0)
    dtm = np.full((grid.rows, grid.cols), np.nan)
    method = INTERPOLATORS[params.method]
    if core.rows and core.cols and len(ground) >= method.min_points:
        if method.hands_over and cloud.sigma is None:
            ground, cloud.ground = [ground], None  # handed over: the TIN frees the points once it has what it needs
        with stage_progress(grid.rows, f"{params.method} DTM", unit="rows") as bar:  # heard when the tile runs here
            dtm = interpolate_dtm(ground, grid, params, bar)  # collinear or coincident ground points: all nodata
    levels = flat(grid) if flat is not None else None
    if levels is not None:
        dtm = np.where(np.isfinite(levels), levels, dtm)
    if decks:
        feet = deck_footprint(cloud.decks)[sub_of(wide, grid)]  # on the wide grid: the closing's edge is far
        dtm = across_decks(dtm, feet, params.max_deck_width / params.resolution)
        if levels is not None:  # a water body under a deck's edge keeps its level
            dtm = np.where(np.isfinite(levels), levels, dtm)
    dtm = dtm[sub]
    if inside is not None:
        dtm[~inside] = np.nan
        dsm = np.where(inside, dsm, np.nan)
    dsm = np.where(np.isnan(dsm), dtm, dsm)  # no return at all: the surface is the ground
    ndsm = np.where(np.isnan(dsm) | np.isnan(dtm), np.nan, np.maximum(dsm - dtm, 0.0))
    density = cloud.count[crop].astype(np.float64)
    out = {"dtm": dtm, "dsm": dsm, "ndsm": ndsm, "density": density}
    if inside is not None:
        out["outside_outline"] = int((~inside).sum())
    if cloud.sigma is not None:
        unc = fill_nearest(cell_mean(cloud.ground, cloud.sigma, wide), max_cells=max_cells)[crop]
        out["dtm_uncertainty"] = np.where(np.isnan(dtm), np.nan, unc)
    return out


def inside_hull(points: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Which of *xy* lie strictly inside the convex hull of *points* (x, y first), so they do not widen a TIN.

    A breakline vertex beyond the points (a water body's outline reaches
    half a cell past its water) would make the TIN's hull reach out with
    it, and thin triangles from it to the far corners of the survey.
    """

    try:
        hull = ConvexHull(np.asarray(points)[:, :2])
    except QhullError:  # all on a line: no area to be inside
        return np.zeros(len(xy), dtype=bool)
    return in_hull(hull, xy, -1e-9)


def _around(core: Grid, wide: Grid, crop: tuple[slice, slice], margin: float) -> tuple[Grid, tuple[slice, slice]]:
    """The cells of *core* and *margin* m around it, within *wide* (a window of it); the core's slice of them."""
    if margin <= 0:
        return core, (slice(0, core.rows), slice(0, core.cols))
    m = int(np.ceil(margin / wide.resolution))
    r0, c0 = max(crop[0].start - m, 0), max(crop[1].start - m, 0)
    grid = wide.window(r0, min(crop[0].stop + m, wide.rows), c0, min(crop[1].stop + m, wide.cols))
    return grid, sub_of(grid, core)


def sub_of(outer: Grid, inner: Grid) -> tuple[slice, slice]:
    """The slice of *outer* that is *inner* (a window of it)."""
    r0, c0 = inner.row0 - outer.row0, inner.col0 - outer.col0
    return slice(r0, r0 + inner.rows), slice(c0, c0 + inner.cols)


def tile_figures(rasters: dict[str, np.ndarray], vertical: float) -> dict:
    """A tile's figures for the survey's metrics (heights in the CRS's unit, *vertical* metres each)."""
    dtm, ndsm = rasters["dtm"], rasters["ndsm"]
    finite = np.isfinite(dtm)
    return {
        "cells": int(dtm.size),
        "outside_outline": int(rasters.get("outside_outline", 0)),
        "nodata_cells": int((~finite).sum()),
        "dtm_min": float(dtm[finite].min()) / vertical if finite.any() else None,
        "dtm_max": float(dtm[finite].max()) / vertical if finite.any() else None,
        "density_sum": int(rasters["density"].sum()),
        "ndsm_max": float(np.nanmax(ndsm)) / vertical if np.isfinite(ndsm).any() else None,
    }


def survey_figures(results: list[dict], cells: int) -> dict:
    """The survey's figures from its tiles' (:func:`tile_figures`) over a grid of *cells*.

    Cells no tile made are nodata; the lowest and highest DTM and the
    highest nDSM are None when no tile has one.
    """
    empty = sum(r["nodata_cells"] for r in results) + (cells - sum(r["cells"] for r in results))
    mins = [r["dtm_min"] for r in results if r["dtm_min"] is not None]
    maxs = [r["dtm_max"] for r in results if r["dtm_max"] is not None]
    ndsm = [r["ndsm_max"] for r in results if r["ndsm_max"] is not None]
    return {
        "nodata_cells": int(empty),
        "outside_outline_cells": int(sum(r.get("outside_outline", 0) for r in results)),
        "nodata_fraction": round(empty / cells, 4),
        "dtm_min": float(min(mins)) if mins else None,
        "dtm_max": float(max(maxs)) if maxs else None,
        "density_mean": round(sum(r["density_sum"] for r in results) / cells, 3),
        "ndsm_max": float(max(ndsm)) if ndsm else None,
    }
