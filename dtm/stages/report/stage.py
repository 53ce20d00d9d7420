"""Stage ``report``: ``report.html``, one self-contained QC page a reviewer signs off.

Everything is inside the file (images as base64 PNG, CSS inline), so it opens
offline, can be mailed, and is archived with the products.  Figures are in
the survey's units (the CRS's: metres, feet or US survey feet) unless a
heading says metres; accuracy figures are in metres whatever the CRS.

Content: the acceptance table against the specification chosen with
``stages.report.specification`` (:mod:`dtm.stages.report.acceptance`; also written to
``qc/acceptance.json``), a summary, maps with a colour bar, scale bar,
north arrow and coordinate ticks (DTM relief over hillshade, pulse density
with the specification's threshold, strip coverage, strip differences before
and after adjustment, voids, check-point residuals, DTM uncertainty, the
flight lines of a raw flight), a lasinfo-like table of every input file and of
the delivered cloud, the classes, the strip adjustment strip by strip (from
``strip_corrections.json``) and the check points one per row with their
histogram and the ASPRS figures, each labelled with what it is computed on.
"""

from __future__ import annotations

import html
import json
import time
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
from pydantic import Field

from dtm.common import glossary
from dtm.stages.report.acceptance import DEFAULT_SPECIFICATION, MEASURES, SPECIFICATIONS
from dtm.stages.report.cloud import las_info, summarise_cloud
from dtm.stages.report.inputs import ReportInputs, checkpoint_rows, read_flight_lines
from dtm.stages.report.maps import RELIEF, STRIP_COLOURS, MapFrame, category_map, histogram_png, raster_map
from dtm.stages.report.markup import figure, fmt, grid, table, unit_symbol
from dtm.stages.report.measures import measure
from pipeline import __version__
from pipeline.stage import Stage, StageContext, StageIO, StageParams, get_dotted


class ReportParams(StageParams):
    max_image_size: int = Field(1200, ge=100, description="largest side of the rasters drawn in the maps, cells")
    specification: Literal[tuple(SPECIFICATIONS)] = Field(  # type: ignore[valid-type]
        DEFAULT_SPECIFICATION,
        description="specification the survey is accepted against (qc/acceptance.json, the report's PASS/FAIL "
        "table): usgs-lbs-ql2 (default: the 3DEP baseline most public lidar contracts cite), usgs-lbs-ql1, "
        "asprs-2023-10cm, or none (measured values only)",
    )


# --------------------------------------------------------------------------- the page


def _strip_label(ids: np.ndarray) -> str:
    ids = [int(s) for s in ids if s > 0]
    if not ids:
        return "none (every point has point_source_id 0)"
    shown = ", ".join(map(str, ids)) if len(ids) <= 12 else f"{ids[0]} – {ids[-1]}"
    return f"{len(ids):,} (point_source_id {shown})"


def _mounting_table(corrections: dict) -> str:
    """The system calibration (``strip_adjust.model: mounting``): each unknown, its estimate, sigma and fate."""
    rows = []
    for u in corrections.get("unknowns", []):
        if u["held_because"]:
            fate = f"not determined ({u['held_because']}): held at the configured value; {u['determined_by']}"
        elif not u["estimated"]:
            fate = "not estimated (configuration)"
        elif not u["applied"]:
            fate = f"not applied ({u['not_applied_because']})"
        else:
            fate = "applied"
        digits = 5 if u["unit"] == "deg" else 4
        est = None if u["estimate"] is None else f"{u['estimate']:+.{digits}f}"
        sd = None if u["sigma"] is None else f"{u['sigma']:.{digits}f}"
        rows.append([u["name"], u["unit"], est, sd, f"{u['correction']:+.{digits}f}", fate])
    header = ["unknown", "unit", "estimate", "1-σ", "correction applied", "status"]
    mounting = corrections.get("mounting") or {}
    lead = "<p>System calibration from the strip overlaps (<code>strip_adjust.model: mounting</code>)"
    if mounting.get("estimated_boresight_deg"):
        roll, pitch, yaw = mounting["estimated_boresight_deg"]
        lead += f"; boresight to configure (input.boresight_deg): {roll:+.5f}, {pitch:+.5f}, {yaw:+.5f}°"
    if corrections.get("residual_sigma_m") is not None:
        lead += f"; residual σ of one point {corrections['residual_sigma_m']:.4f} m"
    if corrections.get("largest_point_move_m") is not None:
        lead += f"; largest point move {corrections['largest_point_move_m']:.4f} m"
    return lead + ".</p>" + grid(header, rows)


def _strip_table(corrections: dict, cloud_strips: np.ndarray) -> str:
    if corrections.get("model") == "mounting":
        pairs = corrections.get("pairs") or []
        pair_rows = [[f"{p['strips'][0]} – {p['strips'][1]}", p.get("overlap_area_m2"), p.get("patches"),
                      p.get("points"), p.get("rms_before_m"), p.get("rms_after_m")] for p in pairs]  # fmt: skip
        header = ["strips", "overlap (m²)", "patches", "points", "RMS before (m)", "RMS after (m)"]
        note = corrections.get("note")
        out = f"<p>{html.escape(note)}</p>" if note else ""
        out += _mounting_table(corrections)
        return out + ("<h3>Overlaps (planar patches)</h3>" + grid(header, pair_rows) if pairs else "")
    datum = corrections.get("datum") or ""
    ref = int(datum.split()[1]) if datum.startswith("strip ") else None
    weak = {int(k) for k in corrections.get("not_determined", {})}
    rows = []
    for key, c in sorted(corrections.get("strips", {}).items(), key=lambda kv: int(kv[0])):
        s = int(key)
        status = "datum (held fixed)" if s == ref else "not determined: left as it is" if s in weak else "adjusted"
        t, r, st = c["translation_m"], c["rotation_deg"], c["sigma_translation_m"]
        rows.append([str(s), c["points"], status, f"{t[0]:+.3f} / {t[1]:+.3f} / {t[2]:+.3f}",
                     f"{r[0]:+.4f} / {r[1]:+.4f} / {r[2]:+.4f}", f"{st[0]:.3f} / {st[1]:.3f} / {st[2]:.3f}"])  # fmt: skip
    listed = {int(k) for k in corrections.get("strips", {})}
    for s in cloud_strips:
        if s > 0 and int(s) not in listed:
            rows.append([str(int(s)), None, "no overlap with another strip: not adjusted", None, None, None])
    header = ["strip", "points", "status", "shift x / y / z (m)", "rotation x / y / z (°)", "1-σ shift (m)"]
    strips_html = grid(header, rows)
    pairs = corrections.get("pairs") or []
    pair_rows = [[f"{p['strips'][0]} – {p['strips'][1]}", p["overlap_area_m2"], p["patches"], p["points"],
                  p["rms_before_m"], p["rms_after_m"]] for p in pairs]  # fmt: skip
    pair_html = (
        "<h3>Overlaps (planar patches)</h3>"
        + grid(["strips", "overlap (m²)", "patches", "points", "RMS before (m)", "RMS after (m)"], pair_rows)
        if pairs
        else ""
    )
    note = corrections.get("note")
    lead = (
        f"<p>Datum: {html.escape(datum)}.</p>"
        if datum
        else f"<p>{html.escape(note or 'Strips were not adjusted.')}</p>"
    )
    return lead + strips_html + pair_html


def build_report(*, name: str, metrics: dict, data: ReportInputs, max_size: int) -> tuple[str, dict]:
    """The report page as an HTML string, and the acceptance verdicts (``qc/acceptance.json``)."""
    from dtm.common.shading import hillshade
    from dtm.stages.report.acceptance import evaluate

    parse = metrics.get("parse", {})
    noise = metrics.get("denoise", {})
    ground = metrics.get("classify_ground", {})
    dtm_grid = metrics.get("rasterize", {})
    accuracy = metrics.get("accuracy")
    geo = metrics.get("georeference")
    cloud, frame = data.cloud, data.frame
    units = cloud.units
    hu, vu = unit_symbol(units.horizontal_name), unit_symbol(units.vertical_name)
    cell_m = frame.cell * units.horizontal
    dtm = data.dtm
    valid = np.isfinite(dtm)
    lo, hi = (float(np.nanmin(dtm)), float(np.nanmax(dtm))) if valid.any() else (0.0, 1.0)
    shade = hillshade(np.where(valid, dtm, lo), frame.cell * units.horizontal / units.vertical)
    shade = np.where(valid, np.nan_to_num(shade, nan=180.0), 255.0)

    measured, why, extra = measure(metrics, data)
    verdict = evaluate(data.specification, measured, why)
    spec_title = verdict["title"]
    anpd_limit = next((c["limit"] for c in verdict["checks"] if c["measure"] == "anpd"), None)

    # ---- maps
    figures = []
    png = raster_map(dtm, frame, cmap=RELIEF, label=f"elevation ({vu})", title="DTM over hillshade",
                     max_size=max_size, vmin=lo, vmax=hi, shade=shade)  # fmt: skip
    figures.append(figure(png, "DTM colour relief over hillshade",
                           f"DTM, colour relief over hillshade: {lo:,.2f} to {hi:,.2f} {vu}; nodata white."))  # fmt: skip
    if cloud.first_returns is not None:
        k = max(1, int(round(5.0 / cell_m)))
        from dtm.stages.report.acceptance import block_sum

        per_m2 = block_sum(cloud.first_returns.astype(float), k) / (k * cell_m) ** 2
        per_m2[per_m2 == 0] = np.nan
        dens_frame = MapFrame(frame.x0, frame.y1, frame.cell * k, hu)
        vmax = float(np.nanpercentile(per_m2, 99)) if np.isfinite(per_m2).any() else 1.0
        png = raster_map(per_m2, dens_frame, cmap="viridis", label="first returns (pulses) per m²",
                         title="pulse density", max_size=max_size, vmin=0.0,
                         vmax=max(vmax, (anpd_limit or 0) * 1.2, 1.0), threshold=anpd_limit,
                         threshold_label=f"{anpd_limit:g}/m²" if anpd_limit else "")  # fmt: skip
        limit_txt = (
            f"; the red line is the specification's {anpd_limit:g} pulses/m² (cells below it inside the contour)"
            if anpd_limit
            else ""
        )
        mean_pts = float(np.nansum(data.density)) / max(float(np.isfinite(data.density).sum()), 1.0) / cell_m**2
        figures.append(figure(png, "pulse density",
                               f"First returns (noise and withheld excluded) per m², in squares of {k * cell_m:.1f} m"
                               f"{limit_txt}. All points: {mean_pts:.2f} per m² on average over the DTM grid."))  # fmt: skip
    # all points per m² (density.tif: points per cell, noise and withheld excluded), in the same squares
    k = max(1, int(round(5.0 / cell_m)))
    from dtm.stages.report.acceptance import block_sum

    pts_m2 = block_sum(np.nan_to_num(data.density), k) / (k * cell_m) ** 2
    pts_m2[pts_m2 == 0] = np.nan
    if np.isfinite(pts_m2).any():
        png = raster_map(pts_m2, MapFrame(frame.x0, frame.y1, frame.cell * k, hu), cmap="viridis",
                         label="points per m²", title="point density (all returns)", max_size=max_size, vmin=0.0,
                         vmax=max(float(np.nanpercentile(pts_m2, 99)), 1.0))  # fmt: skip
        figures.append(figure(png, "point density",
                               f"Points of every return (density.tif; noise and withheld excluded) per m², in "
                               f"squares of {k * cell_m:.1f} m."))  # fmt: skip
    # strip coverage
    unique = [int(s) for s in cloud.strips]
    if unique:
        idx = np.full(cloud.strip_grid.shape, -1)
        has = cloud.strip_grid >= 0
        idx[has] = np.searchsorted(np.array(unique), cloud.strip_grid[has])
        names = [(i, f"strip {s}" if s > 0 else "not a strip (0)", tuple(STRIP_COLOURS[i % 10])) for i, s in enumerate(unique)][:20]  # fmt: skip
        png = category_map(idx, frame, names, title="flight strips (point_source_id)", max_size=max_size)
        figures.append(figure(png, "flight strip coverage",
                               "Flight strips: the strip of the last point read in each DTM cell."))  # fmt: skip
    if data.differences is not None:
        before, after, dframe = data.differences
        scale = 0.16 / units.vertical
        for label, arr in (("before", before), ("after", after)):
            if not np.isfinite(arr).any():
                continue  # no planar overlap between strips: nothing to draw (the strip table says why)
            png = raster_map(arr, dframe, cmap="RdBu_r", label=f"strip-to-strip difference ({vu})",
                             title=f"strip differences {label} adjustment", max_size=max_size, vmin=-scale, vmax=scale,
                             shade=None)  # fmt: skip
            figures.append(figure(png, f"strip differences {label} adjustment",
                                   f"Mean signed distance between overlapping strips at planar patches, {label} "
                                   f"adjustment (strip_difference_{label}.tif), ±{scale:.3g} {vu} (±16 cm); "
                                   "blank where no planar overlap."))  # fmt: skip
    if "void_mask" in extra:
        nodata_inside = ~valid
        from scipy import ndimage

        area = ndimage.binary_fill_holes(valid)
        cats = np.full(dtm.shape, -1)
        cats[valid] = 0
        cats[area & nodata_inside] = 1
        cats[extra["void_mask"]] = 2
        png = category_map(cats, frame, [(0, "DTM", (200, 200, 200)), (1, "DTM nodata inside the area", (255, 170, 0)),
                                         (2, f"void ≥ {extra['void_side_m']:.1f} m square", (200, 0, 0))],
                           title="voids", max_size=max_size, shade=shade)  # fmt: skip
        figures.append(figure(png, "voids",
                               f"Voids: DTM nodata cells enclosed by the DTM (orange), and squares of "
                               f"{extra['void_side_m']:.1f} m (4 × the measured pulse spacing) without a first "
                               f"return inside the covered area (red): {measured['voids']} of them. Water and other surfaces that "
                               "return no pulse count too: the specification exempts them only where breaklines "
                               "(not made here) delineate them."))  # fmt: skip
    if data.checkpoints is not None:
        cp = data.checkpoints
        err = cp["error"]
        # colour scale: the 95th percentile of |error|, so one blunder does not wash out the others
        span = max(float(np.nanpercentile(np.abs(err), 95)), 0.01) if np.isfinite(err).any() else 0.1
        png = raster_map(np.full(dtm.shape, np.nan), frame, cmap="RdBu_r", label="DTM − check point (m)",
                         title="check-point residuals", max_size=max_size, vmin=-span, vmax=span, shade=shade,
                         points=(cp["x"][np.isfinite(err)], cp["y"][np.isfinite(err)], err[np.isfinite(err)]))  # fmt: skip
        figures.append(figure(png, "check-point residuals",
                               f"Check points coloured by DTM − check point (metres, scale ±{span:.3f} m: the 95th percentile "
                               "of |error|; larger errors take the end colours), over the hillshade."))  # fmt: skip
    if data.uncertainty is not None:
        u = data.uncertainty
        ulo, uhi = (float(np.nanpercentile(u, 1)), float(np.nanpercentile(u, 99))) if np.isfinite(u).any() else (0, 1)
        png = raster_map(u, frame, cmap="viridis", label=f"DTM 1-σ ({vu})", title="DTM uncertainty",
                         max_size=max_size, vmin=ulo, vmax=uhi)  # fmt: skip
        figures.append(figure(png, "DTM uncertainty",
                               f"DTM uncertainty (dtm_uncertainty.tif), 1 σ in {vu}, propagated from the "
                               f"georeferencing errors; colours from the 1st ({ulo:.3f}) to the 99th ({uhi:.3f}) percentile."))  # fmt: skip
    if data.trajectory:
        png = raster_map(dtm, frame, cmap=RELIEF, label=f"elevation ({vu})",
                         title="flight lines", max_size=max_size, vmin=lo, vmax=hi, shade=shade,
                         lines=data.trajectory)  # fmt: skip
        figures.append(figure(png, "flight lines",
                               "Trajectory over the survey: one colour per flight line (qc/trajectory.gpkg)."))  # fmt: skip

    # ---- tables
    inputs_html = grid(["role", "file"], [[r, p] for r, p in data.input_files]) if data.input_files else ""
    info_rows = [list(i.values()) for i in data.input_info] + ([list(cloud.header.values())] if cloud.header else [])
    roles = ["input"] * len(data.input_info) + (["delivered (classified)"] if cloud.header else [])
    info_html = (
        grid(["role", *cloud.header.keys()], [[r, *row] for r, row in zip(roles, info_rows, strict=True)], "wide")
        if cloud.header
        else ""
    )
    classes = np.flatnonzero(cloud.class_counts)
    class_rows = [
        [int(k), glossary.class_name(int(k)), int(n), f"{100 * n / max(cloud.points, 1):.2f} %"]
        for k, n in zip(classes, cloud.class_counts[classes], strict=True)
    ]
    summary = [
        ("specification", f"{spec_title}: {verdict['status']}"),
        ("points read", parse.get("points_read") or (geo or {}).get("points")),
        ("input files", len(data.input_files) or len(parse.get("points_per_file", {})) or None),
        ("CRS", parse.get("crs") or (geo or {}).get("crs")),
        ("units of the products", dtm_grid.get("units") or units.describe()),
        ("flight strips", _strip_label(cloud.strips)),
        (
            "low noise (7) / high noise (18)",
            f"{noise.get('low_noise', 0):,} / {noise.get('high_noise', 0):,}" if noise else None,
        ),
        ("ground points", ground.get("ground")),
        ("ground fraction", ground.get("ground_fraction")),
        ("ground algorithm", (ground.get("algorithm") or {}).get("name")),
        (
            "DTM grid",
            f"{dtm_grid.get('cols')} × {dtm_grid.get('rows')} cells of {frame.cell:g} {hu}"
            + (f" ({cell_m:g} m)" if hu != "m" else "")
            + f", {dtm_grid.get('method')}"
            if dtm_grid
            else None,
        ),
        (
            "DTM nodata cells",
            f"{dtm_grid.get('nodata_cells', 0):,} ({100 * dtm_grid.get('nodata_fraction', 0):.2f} %)"
            if dtm_grid
            else None,
        ),
        ("DTM elevation range", f"{lo:,.2f} – {hi:,.2f} {vu}"),
        ("aggregate pulse density (first returns)", f"{measured['anpd']:.2f} per m²" if measured["anpd"] else None),
    ]
    # acceptance
    acc_rows = []
    for c in verdict["checks"]:
        src = c["source"]
        limit = "reported only" if c["limit"] is None else f"{c['bound']} {fmt(c['limit'])} {c['unit']}"
        value = c["measured"]
        shown = "—" if value is None else f"{fmt(float(value))} {c['unit']}"
        acc_rows.append(
            f'<tr class="{c["status"].split()[0].lower()}"><td>{html.escape(c["description"])}</td><td>{html.escape(limit)}</td>'
            f"<td>{html.escape(shown)}</td><td><b>{html.escape(c['status'])}</b>"
            f"{'<br><small>' + html.escape(c['note']) + '</small>' if c['note'] else ''}</td>"
            f"<td>{html.escape(src['document'])}, {html.escape(src['edition'])}, {html.escape(src['table'])}</td></tr>"
        )
    if verdict["checks"]:
        acceptance_html = (
            f"<p>Against <b>{html.escape(spec_title)}</b> (<code>stages.report.specification: {html.escape(data.specification)}</code>): "
            f'<b class="{verdict["status"].lower()}">{verdict["status"]}</b>. Also in <code>qc/acceptance.json</code>.</p>'
            "<table><tr><th>requirement (what is measured)</th><th>limit</th><th>measured</th><th>verdict</th><th>source</th></tr>"
            + "".join(acc_rows)
            + "</table>"
        )
    else:
        acceptance_html = (
            "<p>No specification chosen (<code>stages.report.specification: none</code>): measured values only.</p>"
            + table([(MEASURES[k], v) for k, v in measured.items()])
        )
    if geo:
        counters = [
            (k.replace("_", " "), v) for k, v in parse.items() if isinstance(v, (int, float)) and k != "gps_week"
        ]
        geo_rows = [
            ("pulses", geo.get("pulses")),
            ("points written", geo.get("points")),
            ("dropped: flown in turns", geo.get("dropped_in_turns")),
            ("dropped: no trajectory (outside it or in a gap)", geo.get("rejected_no_trajectory")),
            ("points per strip", ", ".join(f"{k}: {v:,}" for k, v in geo.get("strips", {}).items())),
            ("frame / CRS", f"{geo.get('frame')} / {geo.get('crs')}"),
            ("attitude convention", geo.get("attitude_convention")),
            ("map transform (largest difference from PROJ, m)",
             f"{geo.get('map_transform')} ({geo.get('map_transform_max_error_m', 0):.1e})" if geo.get("map_transform") else None),
            ("ltp vs exact, largest horizontal / vertical difference (m)",
             f"{geo.get('ltp_vs_exact_max_horizontal_m', 0):.3f} / {geo.get('ltp_vs_exact_max_vertical_m', 0):.3f} "
             f"over {geo.get('ltp_vs_exact_extent_m', 0):,.0f} m (geometry predicts "
             f"{geo.get('ltp_predicted_max_horizontal_m', 0):.3f} / {geo.get('ltp_predicted_max_vertical_m', 0):.3f})"),
        ]  # fmt: skip
        raw_html = f"<h3>Read and skipped (qc/debug.txt)</h3>{table(counters)}<h3>Georeferencing</h3>{table(geo_rows)}"
    else:
        raw_html = "<p>Georeferenced input (LAS/LAZ): no raw flight to report on.</p>"
    if data.corrections is not None:
        adjust_html = _strip_table(data.corrections, cloud.strips)
        adj = metrics.get("strip_adjust") or {}
        if adj.get("overlap_rms_before_m") is not None:
            adjust_html += table(
                [
                    ("overlap RMS before adjustment (m)", adj.get("overlap_rms_before_m")),
                    ("overlap RMS after adjustment (m)", adj.get("overlap_rms_after_m")),
                ]
            )
    else:
        adjust_html = "<p>Strip adjustment did not run for this survey: discrepancies between strips were not measured or corrected.</p>"
    accuracy_html = _accuracy_html(accuracy, data.checkpoints)
    made = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>QC report — {html.escape(name)}</title>
<style>
body{{font-family:system-ui,sans-serif;margin:2em auto;max-width:1300px;color:#222;padding:0 1em}}
h1{{margin-bottom:0}} .sub{{color:#666;margin-top:.2em}}
section{{margin:1.5em 0}} table{{border-collapse:collapse;margin:.5em 0}} th,td{{padding:.25em .8em;border-bottom:1px solid #ddd;text-align:left;vertical-align:top}}
th{{font-weight:600;color:#444}} .maps{{display:flex;flex-wrap:wrap;gap:1.5em}} figure{{margin:0;max-width:620px}}
img{{max-width:100%;border:1px solid #ccc}} figcaption{{color:#555;font-size:.9em}}
table.wide td{{font-size:.85em}} .pass{{color:#17692d}} .fail{{color:#b00020}} .incomplete,.not{{color:#8a5a00}}
tr.pass td:nth-child(4){{background:#e6f4ea}} tr.fail td:nth-child(4){{background:#fce8e6}} tr.not td:nth-child(4){{background:#fff4e0}}
</style></head><body>
<h1>QC report: {html.escape(name)}</h1>
<p class="sub">dtm-pipeline {__version__} · made {made} · lengths in {html.escape(units.describe())} unless a heading says m</p>
<section id="acceptance"><h2>Acceptance</h2>{acceptance_html}</section>
<section id="summary"><h2>Summary</h2>{table(summary)}</section>
<section id="inputs"><h2>Input files</h2>{inputs_html}{info_html}</section>
<section id="maps"><h2>Maps</h2><div class="maps">
{"".join(figures)}
</div></section>
<section id="classes"><h2>Classification</h2>{grid(["class", "name", "points", "share"], class_rows)}</section>
<section id="raw"><h2>Raw flight</h2>{raw_html}</section>
<section id="strips"><h2>Strip adjustment</h2>{adjust_html}</section>
<section id="accuracy"><h2>Vertical accuracy</h2>{accuracy_html}</section>
</body></html>
"""
    return page, verdict


def _accuracy_html(accuracy: dict | None, cp: dict | None) -> str:
    truth = _truth_html((accuracy or {}).get("truth"))
    accuracy = {k: v for k, v in (accuracy or {}).items() if k != "truth"}
    if not accuracy:
        return truth + (
            "<p>No check points were configured (<code>stages.accuracy.checkpoints</code>), so no accuracy figures.</p>"
        )
    nva = accuracy.get("nva_95")
    n_nv, n_v = accuracy.get("n_non_vegetated"), accuracy.get("n_vegetated")
    rows = [
        (f"RMSEz, all {accuracy.get('n')} check points on the DTM (m)", accuracy.get("rmse_z")),
        ("mean error, all (m)", accuracy.get("mean_error")),
        (f"RMSEz, non-vegetated ({n_nv} check points) (m)", nva / 1.96 if nva is not None else None),
        (f"NVA at 95 % = 1.96 × RMSEz non-vegetated ({n_nv} check points) (m)", nva),
        (f"VVA = 95th percentile of |error|, vegetated ({n_v} check points) (m)", accuracy.get("vva_95")),
        ("outside the DTM or on nodata", accuracy.get("outside")),
    ]
    out = table(rows) + truth
    if cp is not None:
        table_rows = [
            [i, lc, f"{x:.3f}", f"{y:.3f}", f"{z:.3f}", f"{d:.3f}", f"{e:+.3f}" if np.isfinite(e) else "off the DTM"]
            for i, lc, x, y, z, d, e in zip(
                cp["id"], cp["land_cover"], cp["x"], cp["y"], cp["z"], cp["dtm"], cp["error"], strict=True
            )
        ]
        err = cp["error"]
        if np.isfinite(err).any():
            out += figure(histogram_png(err, np.asarray(cp["land_cover"], dtype=object)), "check-point error histogram",
                           "Errors DTM − check point (metres), stacked by land cover.")  # fmt: skip
        out += "<h3>Check points</h3>" + grid(
            ["id", "land cover", "x", "y", "measured z", "DTM z", "error (m)"], table_rows
        )
    return out


def _truth_html(truth: dict | None) -> str:
    """The DTM against a truth raster (stages.accuracy.truth_dtm): every cell, metres."""
    if not truth or not truth.get("n"):
        return ""
    rows = [
        (f"RMS over {truth['n']:,} cells (m)", truth["rmse"]),
        ("mean error (m)", truth["mean"]),
        ("cells more than 1 m off (%)", 100 * truth["off_1m"]),
        ("cells more than 5 m off (%)", 100 * truth["off_5m"]),
        ("largest error above / below the truth (m)", f"{truth['max_above']:+.3f} / {truth['max_below']:+.3f}"),
    ]
    out = (
        f"<h3>DTM against the true terrain ({html.escape(str(truth['file']))}, resampled {truth['resampling']} onto "
        f"the DTM's cells; DTM − truth)</h3>" + table(rows)
    )
    by_relief = truth.get("by_relief") or {}
    if by_relief:
        relief_rows = [
            [
                label,
                f"{v['n']:,}",
                v["rmse"],
                100 * v["off_1m"] if v["n"] else None,
                100 * v["off_5m"] if v["n"] else None,
            ]
            for label, v in (
                ("truth varies by under 2 m over 3 × 3 cells", by_relief["under_2m"]),
                ("2 m or more (walls, banks, steps)", by_relief["2m_or_more"]),
            )
        ]
        out += (
            "<p>Where the truth itself is steep, a shift of one cell (the truth raster's own resampling "
            "across a wall) is already more than 1 m:</p>"
            + grid(["where", "cells", "RMS (m)", "> 1 m off (%)", "> 5 m off (%)"], relief_rows)
        )
    by_cover = truth.get("by_land_cover") or {}
    if by_cover:
        header = [
            "land cover",
            "cells",
            "RMS (m)",
            "mean (m)",
            "> 1 m off (%)",
            "> 5 m off (%)",
            "max above / below (m)",
        ]
        cover_rows = [
            [
                f"{code} {v['name']}",
                f"{v['n']:,}",
                v["rmse"],
                v["mean"],
                100 * v["off_1m"],
                100 * v["off_5m"],
                f"{v['max_above']:+.3f} / {v['max_below']:+.3f}",
            ]
            for code, v in sorted(by_cover.items(), key=lambda kv: int(kv[0]))
        ]
        out += (
            f"<p>By what covers the ground ({html.escape(str(truth.get('land_cover_file', '')))}, nearest cell):</p>"
            + grid(header, cover_rows)
        )
    return out


def _enabled(config, name: str) -> bool:
    params = get_dotted(config, f"stages.{name}")
    return params is not None and bool(getattr(params, "enabled", True))


class Report(Stage):
    name = "report"
    version = "7"
    Params = ReportParams
    description = "self-contained QC page (report.html) and acceptance (qc/acceptance.json)"
    inputs = ("dtm", "density", "points_classified")
    outputs: ClassVar = {"report": "report.html", "acceptance": "acceptance.json"}
    products: ClassVar = {"report": "report.html", "acceptance": "qc/acceptance.json"}
    reads_metrics = True
    config_keys = ("name", "input", "stages.accuracy")

    def declare(self, params, config) -> StageIO:
        inputs = list(self.inputs)
        if _enabled(config, "strip_adjust"):
            inputs += ["strip_corrections", "strip_difference_before", "strip_difference_after"]
        geo = get_dotted(config, "stages.georeference")
        if config.input.format != "las":
            inputs.append("trajectory_lines")
            if geo is not None and geo.uncertainty is not None:
                inputs.append("dtm_uncertainty")
        return StageIO(tuple(inputs), dict(self.outputs), dict(self.products))

    def external_files(self, params, config) -> list[Path]:
        acc = get_dotted(config, "stages.accuracy")
        return [acc.checkpoints] if acc is not None and acc.enabled and acc.checkpoints else []

    def run(self, ctx: StageContext[ReportParams]) -> None:
        from dtm.common.rasters import read_raster

        dtm, transform, _, resolution = read_raster(ctx.inputs["dtm"])
        density, _, _, _ = read_raster(ctx.inputs["density"])
        cloud = summarise_cloud(
            ctx.inputs["points_classified"], origin=(transform.c, transform.f), resolution=resolution,
            shape=dtm.shape, dtm=dtm,
        )  # fmt: skip
        hu = unit_symbol(cloud.units.horizontal_name)
        frame = MapFrame(transform.c, transform.f, resolution, hu)
        inp = ctx.setting("input")
        files = [("scanner / point file", str(p)) for p in inp.paths]
        files += [(k, str(getattr(inp, k))) for k in ("nmea", "ins", "sbet", "smrmsg") if getattr(inp, k, None)]
        data = ReportInputs(dtm=dtm, density=density, frame=frame, cloud=cloud, input_files=files,
                            specification=ctx.params.specification)  # fmt: skip
        if inp.format == "las":
            data.input_info = [las_info(p) for p in inp.paths]
        if "strip_corrections" in ctx.inputs:
            data.corrections = json.loads(Path(ctx.inputs["strip_corrections"]).read_text())
            before, t, _, res = read_raster(ctx.inputs["strip_difference_before"])
            after, _, _, _ = read_raster(ctx.inputs["strip_difference_after"])
            data.differences = (before, after, MapFrame(t.c, t.f, res, hu))
        if "dtm_uncertainty" in ctx.inputs:
            data.uncertainty = read_raster(ctx.inputs["dtm_uncertainty"])[0]
        if "trajectory_lines" in ctx.inputs:
            data.trajectory = read_flight_lines(ctx.inputs["trajectory_lines"])
        acc = ctx.setting("stages.accuracy")
        if acc is not None and acc.enabled and acc.checkpoints and ctx.upstream_metrics.get("accuracy"):
            data.checkpoints = checkpoint_rows(acc.checkpoints, acc.land_cover_column, ctx.inputs["dtm"])
        page, verdict = build_report(
            name=ctx.setting("name") or "survey", metrics=ctx.upstream_metrics, data=data,
            max_size=ctx.params.max_image_size,
        )  # fmt: skip
        ctx.outputs["report"].write_text(page, encoding="utf-8")
        ctx.outputs["acceptance"].write_text(json.dumps(verdict, indent=2, default=float) + "\n")
        ctx.metrics.update(bytes=len(page), images=page.count("<img"), acceptance=verdict["status"])
        ctx.log.info("acceptance against %s: %s", verdict["title"], verdict["status"])
