"""The report's Maps section: one function a map, each returning its ``<figure>`` (or '' when there is nothing to draw)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import ndimage

from lidar import glossary
from lidar.shading import hillshade
from pipeline.log import stage_progress
from stages.report.acceptance import block_sum, pulse_density
from stages.report.cloud import CloudSummary
from stages.report.inputs import ReportInputs
from stages.report.maps import RELIEF, STRIP_COLOURS, MapFrame, category_map, raster_map
from stages.report.markup import figure, unit_symbol

if TYPE_CHECKING:
    from lidar.units import Units


@dataclass(frozen=True)
class Canvas:
    """What the maps share: the DTM, its frame, range and hillshade, the survey's units and the largest image side."""

    dtm: np.ndarray
    frame: MapFrame
    units: Units
    max_size: int
    valid: np.ndarray  # DTM cells with a value
    lo: float  # DTM range (0, 1 when it has no value)
    hi: float
    shade: np.ndarray  # hillshade 0-255, nodata white

    @classmethod
    def of(cls, dtm: np.ndarray, frame: MapFrame, units: Units, max_size: int) -> Canvas:
        valid = np.isfinite(dtm)
        lo, hi = (float(np.nanmin(dtm)), float(np.nanmax(dtm))) if valid.any() else (0.0, 1.0)
        shade = hillshade(np.where(valid, dtm, lo), frame.cell * units.horizontal / units.vertical)
        shade = np.where(valid, np.nan_to_num(shade, nan=180.0), 255.0)
        return cls(dtm, frame, units, max_size, valid, lo, hi, shade)

    @property
    def hu(self) -> str:
        return unit_symbol(self.units.horizontal_name)

    @property
    def vu(self) -> str:
        return unit_symbol(self.units.vertical_name)

    @property
    def cell_m(self) -> float:
        return self.frame.cell * self.units.horizontal

    def per_square_m(self, counts: np.ndarray) -> tuple[np.ndarray, int, MapFrame]:
        """*counts* per cell summed in squares of about 5 m, per m² (NaN: none), the squares' side in cells and frame."""
        cell_m = self.cell_m
        k = max(1, int(round(5.0 / cell_m)))
        per_m2 = block_sum(counts, k) / (k * cell_m) ** 2
        per_m2[per_m2 == 0] = np.nan
        return per_m2, k, MapFrame(self.frame.x0, self.frame.y1, self.frame.cell * k, self.hu)


def map_figures(cv: Canvas, data: ReportInputs, measured: dict, voids: dict, anpd_limit: float | None) -> list[str]:
    """Every map of the section, in the page's order; *voids*: ``void_mask`` and ``void_side_m`` when counted.

    The stage's progress moves by the maps drawn (:func:`~pipeline.log.stage_progress`).
    """
    draw = [lambda: relief_figure(cv)]
    if data.cloud.first_returns is not None:
        draw.append(lambda: pulse_density_figure(cv, data.cloud.first_returns, data.density, anpd_limit))
    draw.append(lambda: point_density_figure(cv, data.density))
    draw.append(lambda: strips_figure(cv, data.cloud))
    if data.cloud.class_grid is not None:
        draw.append(lambda: classes_figure(cv, data.cloud.class_grid))
    if data.differences is not None:
        draw.append(lambda: difference_figures(cv, *data.differences))
    if "void_mask" in voids:
        draw.append(lambda: voids_figure(cv, voids["void_mask"], voids["void_side_m"], measured["voids"]))
    if data.checkpoints is not None:
        draw.append(lambda: checkpoints_figure(cv, data.checkpoints))
    if data.uncertainty is not None:
        draw.append(lambda: uncertainty_figure(cv, data.uncertainty))
    if data.trajectory:
        draw.append(lambda: flight_lines_figure(cv, data.trajectory))
    figures = []
    with stage_progress(len(draw), "maps drawn", unit="maps") as bar:
        for one in draw:
            figures.append(one())
            bar.update(1)
    return figures


def relief_figure(cv: Canvas) -> str:
    """The DTM in colour relief over its hillshade."""
    return figure(
        relief_map(cv, "DTM over hillshade"),
        "DTM colour relief over hillshade",
        f"DTM, colour relief over hillshade: {cv.lo:,.2f} to {cv.hi:,.2f} {cv.vu}; nodata white.",
    )


def relief_map(cv: Canvas, title: str, lines: list[tuple[np.ndarray, np.ndarray, str]] | None = None) -> str:
    """The DTM in colour relief over its hillshade as SVG, with *lines* ``(x, y, name)`` drawn on it."""
    return raster_map(
        cv.dtm,
        cv.frame,
        cmap=RELIEF,
        label=f"elevation ({cv.vu})",
        title=title,
        max_size=cv.max_size,
        vmin=cv.lo,
        vmax=cv.hi,
        shade=cv.shade,
        lines=lines,
    )


def pulse_density_figure(cv: Canvas, first_returns: np.ndarray, density: np.ndarray, limit: float | None) -> str:
    """First returns per m² in squares of about 5 m, with the specification's *limit* drawn (contour and bar)."""
    per_m2, k, frame = cv.per_square_m(first_returns.astype(float))
    vmax = float(np.nanpercentile(per_m2, 99)) if np.isfinite(per_m2).any() else 1.0
    svg = density_map(
        cv,
        per_m2,
        frame,
        "first returns (pulses) per m²",
        "pulse density",
        max(vmax, (limit or 0) * 1.2, 1.0),
        threshold=limit,
        threshold_label=f"{limit:g}/m²" if limit else "",
    )
    limit_txt = (
        f"; the red line is the specification's {limit:g} pulses/m² (cells below it inside the contour)"
        if limit
        else ""
    )
    _, covered_m2 = pulse_density(first_returns, cv.cell_m)  # the area the aggregate density is over
    mean_pts = float(np.nansum(density)) / covered_m2 if covered_m2 else 0.0
    return figure(
        svg,
        "pulse density",
        f"First returns (noise and withheld excluded) per m², in squares of {k * cv.cell_m:.1f} m"
        f"{limit_txt}. All points: {mean_pts:.2f} per m² over the same covered area.",
    )


def point_density_figure(cv: Canvas, density: np.ndarray) -> str:
    """All points per m² (density.tif: points per cell, noise and withheld excluded), in the same squares."""
    pts_m2, k, frame = cv.per_square_m(np.nan_to_num(density))
    if not np.isfinite(pts_m2).any():
        return ""
    vmax = max(float(np.nanpercentile(pts_m2, 99)), 1.0)
    svg = density_map(cv, pts_m2, frame, "points per m²", "point density (all returns)", vmax)
    return figure(
        svg,
        "point density",
        f"Points of every return (density.tif; noise and withheld excluded) per m², in "
        f"squares of {k * cv.cell_m:.1f} m.",
    )


def density_map(
    cv: Canvas,
    per_m2: np.ndarray,
    frame: MapFrame,
    label: str,
    title: str,
    vmax: float,
    threshold: float | None = None,
    threshold_label: str = "",
) -> str:
    """A density per m² as SVG, coloured from 0 to *vmax*, with the *threshold* drawn when one is given."""
    return raster_map(
        per_m2,
        frame,
        cmap="viridis",
        label=label,
        title=title,
        max_size=cv.max_size,
        vmin=0.0,
        vmax=vmax,
        threshold=threshold,
        threshold_label=threshold_label,
    )


def strips_figure(cv: Canvas, cloud: CloudSummary) -> str:
    """Strip coverage: the strip of the last point read in each DTM cell (20 strips named at most)."""
    unique = [int(s) for s in cloud.strips]
    if not unique:
        return ""
    idx = np.full(cloud.strip_grid.shape, -1)
    has = cloud.strip_grid >= 0
    idx[has] = np.searchsorted(np.array(unique), cloud.strip_grid[has])
    names = [
        (i, f"strip {s}" if s > 0 else "not a strip (0)", tuple(STRIP_COLOURS[i % 10])) for i, s in enumerate(unique)
    ][:20]
    svg = category_map(idx, cv.frame, names, title="flight strips (point_source_id)", max_size=cv.max_size)
    return figure(svg, "flight strip coverage", "Flight strips: the strip of the last point read in each DTM cell.")


def classes_figure(cv: Canvas, class_grid: np.ndarray) -> str:
    """The class of the highest point (noise and withheld left out) in each DTM cell, over the hillshade."""
    present = [int(k) for k in np.unique(class_grid) if k >= 0]
    if not present:
        return ""
    names = [(k, f"{k} {glossary.class_name(k)}", glossary.CLASS_COLOURS.get(k, (0, 0, 0))) for k in present]
    svg = category_map(
        class_grid, cv.frame, names, title="classes (highest point)", max_size=cv.max_size, shade=cv.shade
    )
    return figure(
        svg,
        "point classes",
        "ASPRS class of the highest point in each DTM cell (noise and withheld left out): what stands on the "
        "ground as classified, seen from above.",
    )


def difference_figures(cv: Canvas, before: np.ndarray, after: np.ndarray, frame: MapFrame) -> str:
    """Strip-to-strip differences before and after adjustment, ±16 cm (each left out where it has no value)."""
    out = ""
    scale = 0.16 / cv.units.vertical
    for label, arr in (("before", before), ("after", after)):
        if not np.isfinite(arr).any():
            continue  # no planar overlap between strips: nothing to draw (the strip table says why)
        svg = raster_map(
            arr,
            frame,
            cmap="RdBu_r",
            label=f"strip-to-strip difference ({cv.vu})",
            title=f"strip differences {label} adjustment",
            max_size=cv.max_size,
            vmin=-scale,
            vmax=scale,
            shade=None,
        )
        out += figure(
            svg,
            f"strip differences {label} adjustment",
            f"Mean signed distance between overlapping strips at planar patches, {label} "
            f"adjustment (strip_difference_{label}.tif), ±{scale:.3g} {cv.vu} (±16 cm); "
            "blank where no planar overlap.",
        )
    return out


def voids_figure(cv: Canvas, void_mask: np.ndarray, side_m: float, count: int) -> str:
    """DTM nodata enclosed by the DTM, and the squares without a first return (the specification's voids)."""
    nodata_inside = ~cv.valid
    area = ndimage.binary_fill_holes(cv.valid)
    cats = np.full(cv.dtm.shape, -1)
    cats[cv.valid] = 0
    cats[area & nodata_inside] = 1
    cats[void_mask] = 2
    legend = [
        (0, "DTM", (200, 200, 200)),
        (1, "DTM nodata inside the area", (255, 170, 0)),
        (2, f"void ≥ {side_m:.1f} m square", (200, 0, 0)),
    ]
    svg = category_map(cats, cv.frame, legend, title="voids", max_size=cv.max_size, shade=cv.shade)
    return figure(
        svg,
        "voids",
        f"Voids: DTM nodata cells enclosed by the DTM (orange), and squares of "
        f"{side_m:.1f} m (4 × the measured pulse spacing) without a first "
        f"return inside the covered area (red): {count} of them. Water and other surfaces that "
        "return no pulse count too: the specification exempts water delineated by breaklines "
        "(breaklines.gpkg), which this count does not yet leave out.",
    )


def checkpoints_figure(cv: Canvas, cp: dict) -> str:
    """The check points on the DTM's hillshade, coloured by DTM − check point."""
    err = cp["error"]
    # colour scale: the 95th percentile of |error|, so one blunder does not wash out the others
    span = max(float(np.nanpercentile(np.abs(err), 95)), 0.01) if np.isfinite(err).any() else 0.1
    svg = raster_map(
        np.full(cv.dtm.shape, np.nan),
        cv.frame,
        cmap="RdBu_r",
        label="DTM − check point (m)",
        title="check-point residuals",
        max_size=cv.max_size,
        vmin=-span,
        vmax=span,
        shade=cv.shade,
        points=(cp["x"][np.isfinite(err)], cp["y"][np.isfinite(err)], err[np.isfinite(err)]),
    )
    return figure(
        svg,
        "check-point residuals",
        f"Check points coloured by DTM − check point (metres, scale ±{span:.3f} m: the 95th percentile "
        "of |error|; larger errors take the end colours), over the hillshade.",
    )


def uncertainty_figure(cv: Canvas, u: np.ndarray) -> str:
    """The DTM's propagated 1-sigma, coloured from its 1st to its 99th percentile."""
    ulo, uhi = (float(np.nanpercentile(u, 1)), float(np.nanpercentile(u, 99))) if np.isfinite(u).any() else (0, 1)
    svg = raster_map(
        u,
        cv.frame,
        cmap="viridis",
        label=f"DTM 1-σ ({cv.vu})",
        title="DTM uncertainty",
        max_size=cv.max_size,
        vmin=ulo,
        vmax=uhi,
    )
    return figure(
        svg,
        "DTM uncertainty",
        f"DTM uncertainty (dtm_uncertainty.tif), 1 σ in {cv.vu}, propagated from the "
        f"georeferencing errors; colours from the 1st ({ulo:.3f}) to the 99th ({uhi:.3f}) percentile.",
    )


def flight_lines_figure(cv: Canvas, lines: list[tuple[np.ndarray, np.ndarray, str]]) -> str:
    """The flight lines over the DTM's relief, one colour a line."""
    svg = relief_map(cv, "flight lines", lines)
    return figure(svg, "flight lines", "Trajectory over the survey: one colour per flight line (qc/trajectory.gpkg).")
