"""The report's sections but the maps: one function a section, each taking what it shows and returning its HTML.

A section that shows a stage's metrics reads them in one place, at its top,
so the keys it uses are seen there (``metrics[stage][key]`` as the stage
wrote them; a stage that did not run has no entry).
"""

from __future__ import annotations

import html

import numpy as np

from lidar import glossary
from pipeline.runner import LOG_WARNINGS
from stages.report.acceptance import MEASURES
from stages.report.cloud import CloudSummary
from stages.report.figures import Canvas
from stages.report.maps import histogram_svg
from stages.report.markup import figure, fmt, grid, section, table

PAIR_HEADER = ["strips", "overlap (m²)", "patches", "points", "RMS before (m)", "RMS after (m)"]


# --------------------------------------------------------------------------- acceptance, summary, inputs, classes


def acceptance_section(verdict: dict, measured: dict) -> str:
    """The verdict of every limit of the specification, with its source; without one, the measured values."""
    if not verdict["checks"]:
        return section(
            "acceptance",
            "Acceptance",
            "<p>No specification chosen (<code>stages.report.specification: none</code>): measured values only.</p>"
            + table([(MEASURES[k], v) for k, v in measured.items()]),
        )
    rows = "".join(_acceptance_row(c) for c in verdict["checks"])
    return section(
        "acceptance",
        "Acceptance",
        f"<p>Against <b>{html.escape(verdict['title'])}</b> (<code>stages.report.specification: "
        f"{html.escape(verdict['specification'])}</code>): "
        f'<b class="{verdict["status"].lower()}">{verdict["status"]}</b>. Also in <code>qc/acceptance.json</code>.</p>'
        "<table><tr><th>requirement (what is measured)</th><th>limit</th><th>measured</th><th>verdict</th>"
        "<th>source</th></tr>" + rows + "</table>" + _warnings(verdict.get("warnings") or []),
    )


def _warnings(sentences: list[str]) -> str:
    """What the verdict rests on that a reviewer should doubt (too few or bunched check points, a truth that disagrees)."""
    if not sentences:
        return ""
    items = "".join(f"<li>{html.escape(s)}</li>" for s in sentences)
    return f'<p><b>Warnings</b> (they do not change the verdict):</p><ul class="warn">{items}</ul>'


def _limit_and_measured(c: dict) -> tuple[str, str]:
    """A check's limit and measured value as the page shows them (with their unit)."""
    number = (lambda v: f"{float(v):g}") if not c["unit"] else (lambda v: fmt(float(v)))  # a code: no separators
    limit = "reported only" if c["limit"] is None else f"{c['bound']} {number(c['limit'])} {c['unit']}".rstrip()
    value = c["measured"]
    return limit, "—" if value is None else f"{number(value)} {c['unit']}".rstrip()


def failed_checks(verdict: dict) -> list[str]:
    """One sentence per failed check of *verdict*: what is measured, the value, the limit."""
    out = []
    for c in verdict.get("checks", []):
        if c["status"] == "FAIL":
            limit, shown = _limit_and_measured(c)
            out.append(f"{c['description']}: {shown}, limit {limit}")
    return out


def run_warnings_section(metrics: dict) -> str:
    """Every WARNING and ERROR line the stages logged (*metrics*: stage name -> its metrics), stage by stage."""
    lines = [(name, line) for name, m in metrics.items() for line in (m or {}).get(LOG_WARNINGS) or []]
    if not lines:
        return section("warnings", "Warnings of the run", "<p>None: no stage logged a warning.</p>")
    items = "".join(f"<li><b>{html.escape(name)}</b>: {html.escape(line)}</li>" for name, line in lines)
    return section(
        "warnings",
        "Warnings of the run",
        f"<p>{len(lines)} warning(s) the stages logged, as in the log (cached stages' from their first run):</p>"
        f'<ul class="warn">{items}</ul>',
    )


def verdict_banner(verdict: dict) -> str:
    """The verdict at the top of the page, in a box of its colour; a failure lists its failed checks."""
    if not verdict["checks"]:
        return ""
    status, failed = verdict["status"], failed_checks(verdict)
    count = f": {len(failed)} of {len(verdict['checks'])} checks failed" if failed else ""
    items = "".join(f"<li>{html.escape(f)}</li>" for f in failed)
    return (
        f'<div class="banner {status.split()[0].lower()}"><p><b>{html.escape(status)}</b> against '
        f"{html.escape(verdict['title'])}{count} (every check: Acceptance, below).</p>"
        + (f"<ul>{items}</ul>" if items else "")
        + "</div>"
    )


def _acceptance_row(c: dict) -> str:
    """One check of :func:`~stages.report.acceptance.evaluate` as a table row, coloured by its status."""
    src = c["source"]
    limit, shown = _limit_and_measured(c)
    note = "<br><small>" + html.escape(c["note"]) + "</small>" if c["note"] else ""
    return (
        f'<tr class="{c["status"].split()[0].lower()}"><td>{html.escape(c["description"])}</td>'
        f"<td>{html.escape(limit)}</td><td>{html.escape(shown)}</td><td><b>{html.escape(c['status'])}</b>{note}</td>"
        f"<td>{html.escape(src['document'])}, {html.escape(src['edition'])}, {html.escape(src['table'])}</td></tr>"
    )


def summary_section(
    metrics: dict,
    verdict: dict,
    cv: Canvas,
    strips: np.ndarray,
    input_files: int,
    anpd: float | None,
    class_counts: np.ndarray,
) -> str:
    """The survey in one table: its verdict, points, CRS, strips, noise, ground, DTM grid and pulse density.

    The ground is the delivered cloud's class 2 (*class_counts*: its points per class), as the class table
    counts it; the ground filter's own count is larger where later stages took roofs, decks and water out.
    """
    parse = metrics.get("parse", {})
    geo = metrics.get("georeference")
    noise = metrics.get("denoise", {})
    ground = metrics.get("classify_ground", {})
    raster = metrics.get("rasterize", {})
    rows = [
        ("specification", f"{verdict['title']}: {verdict['status']}"),
        ("points read", parse.get("points_read") or (geo or {}).get("points")),
        ("input files", input_files or len(parse.get("points_per_file", {})) or None),
        ("CRS", parse.get("crs") or (geo or {}).get("crs")),
        ("units of the products", raster.get("units") or cv.units.describe()),
        ("vertical datum of the heights", (geo or {}).get("heights") or parse.get("heights")),
        ("flight strips", strip_label(strips)),
        (
            "low noise (7) / high noise (18)",
            f"{noise.get('low_noise', 0):,} / {noise.get('high_noise', 0):,}" if noise else None,
        ),
        ("ground points (class 2, delivered)", f"{int(class_counts[2]):,} ({_share(class_counts[2], class_counts)})"),
        ("ground points by the ground filter", ground.get("ground")),
        ("ground algorithm", (ground.get("algorithm") or {}).get("name")),
        *_dtm_rows(raster, cv),
        ("aggregate pulse density (first returns)", f"{anpd:.2f} per m²" if anpd else None),
    ]
    return section("summary", "Summary", table(rows))


def _dtm_rows(g: dict, cv: Canvas) -> list[tuple[str, object]]:
    """The summary's DTM rows: its grid and nodata cells (*g*: metrics of ``rasterize``), its elevation range."""
    hu = cv.hu
    return [
        (
            "DTM grid",
            f"{g.get('cols')} × {g.get('rows')} cells of {cv.frame.cell:g} {hu}"
            + (f" ({cv.cell_m:g} m)" if hu != "m" else "")
            + f", {g.get('method')}"
            if g
            else None,
        ),
        (
            "DTM nodata cells",
            f"{g.get('nodata_cells', 0):,} ({100 * g.get('nodata_fraction', 0):.2f} %)" if g else None,
        ),
        ("DTM elevation range", f"{cv.lo:,.2f} – {cv.hi:,.2f} {cv.vu}"),
    ]


def strip_label(ids: np.ndarray) -> str:
    """How many strips (point_source_id > 0) and which: '3 (point_source_id 1, 2, 3)'."""
    ids = [int(s) for s in ids if s > 0]
    if not ids:
        return "none (every point has point_source_id 0)"
    shown = ", ".join(map(str, ids)) if len(ids) <= 12 else f"{ids[0]} – {ids[-1]}"
    return f"{len(ids):,} (point_source_id {shown})"


def inputs_section(files: list[tuple[str, str]], infos: list[dict], delivered: dict) -> str:
    """The input files (role, path), and a lasinfo-like row for each LAS input and the delivered cloud."""
    files_html = grid(["role", "file"], [[r, p] for r, p in files]) if files else ""
    info_rows = [list(i.values()) for i in infos] + ([list(delivered.values())] if delivered else [])
    roles = ["input"] * len(infos) + (["delivered (classified)"] if delivered else [])
    info_html = (
        grid(["role", *delivered.keys()], [[r, *row] for r, row in zip(roles, info_rows, strict=True)], "wide")
        if delivered
        else ""
    )
    return section("inputs", "Input files", files_html + info_html)


def maps_section(figures: list[str]) -> str:
    """The maps, side by side (:mod:`stages.report.figures`)."""
    return section("maps", "Maps", '<div class="maps">\n' + "".join(figures) + "\n</div>")


def classes_section(cloud: CloudSummary) -> str:
    """Points per ASPRS class of the delivered cloud and their share; with two strips or more, per strip too."""
    classes = np.flatnonzero(cloud.class_counts)
    rows = [
        [int(k), glossary.class_name(int(k)), int(n), f"{100 * n / max(cloud.points, 1):.2f} %"]
        for k, n in zip(classes, cloud.class_counts[classes], strict=True)
    ]
    body = grid(["class", "name", "points", "share"], rows)
    if len(cloud.class_by_strip) > 1:
        header = ["strip (point_source_id)"] + [f"{int(k)} {glossary.class_name(int(k))}" for k in classes] + ["all"]
        per_strip = [
            [s, *(int(counts[k]) for k in classes), int(counts.sum())]
            for s, counts in sorted(cloud.class_by_strip.items())
        ]
        body += "<h3>Per strip (points)</h3>" + grid(header, per_strip, "wide")
    return section("classes", "Classification", body)


# --------------------------------------------------------------------------- raw flight, strip adjustment


def raw_section(parse: dict, geo: dict | None) -> str:
    """A raw flight's counters: what was read and skipped (metrics of ``parse``), and the georeferencing."""
    if not geo:
        return section("raw", "Raw flight", "<p>Georeferenced input (LAS/LAZ): no raw flight to report on.</p>")
    counters = [(k.replace("_", " "), v) for k, v in parse.items() if isinstance(v, (int, float)) and k != "gps_week"]
    return section(
        "raw",
        "Raw flight",
        f"<h3>Read and skipped (qc/debug.txt)</h3>{table(counters)}"
        f"<h3>Georeferencing</h3>{table(_georeference_rows(geo))}",
    )


def _georeference_rows(geo: dict) -> list[tuple[str, object]]:
    """The metrics of ``georeference``: pulses, points, what was dropped, frame, and the map transform's error."""
    return [
        ("pulses", geo.get("pulses")),
        ("points written", geo.get("points")),
        ("dropped: flown in turns", geo.get("dropped_in_turns")),
        ("dropped: no trajectory (outside it or in a gap)", geo.get("rejected_no_trajectory")),
        ("points per strip", ", ".join(f"{k}: {v:,}" for k, v in geo.get("strips", {}).items())),
        ("frame / CRS", f"{geo.get('frame')} / {geo.get('crs')}"),
        ("attitude convention", geo.get("attitude_convention")),
        (
            "map transform (largest difference from PROJ, m)",
            f"{geo.get('map_transform')} ({geo.get('map_transform_max_error_m', 0):.1e})"
            if geo.get("map_transform")
            else None,
        ),
        (
            "ltp vs exact, largest horizontal / vertical difference (m)",
            f"{geo.get('ltp_vs_exact_max_horizontal_m', 0):.3f} / {geo.get('ltp_vs_exact_max_vertical_m', 0):.3f} "
            f"over {geo.get('ltp_vs_exact_extent_m', 0):,.0f} m (geometry predicts "
            f"{geo.get('ltp_predicted_max_horizontal_m', 0):.3f} / {geo.get('ltp_predicted_max_vertical_m', 0):.3f})",
        ),
    ]


def strips_section(corrections: dict | None, strips: np.ndarray, adjust: dict) -> str:
    """The strip adjustment (``strip_corrections.json``) and its overlap RMS before and after (metrics of ``strip_adjust``)."""
    if corrections is None:
        return section(
            "strips",
            "Strip adjustment",
            "<p>Strip adjustment did not run for this survey: discrepancies between strips were not measured or "
            "corrected.</p>",
        )
    body = strip_table(corrections, strips)
    if adjust.get("overlap_rms_before_m") is not None:
        body += table(
            [
                ("overlap RMS before adjustment (m)", adjust.get("overlap_rms_before_m")),
                ("overlap RMS after adjustment (m)", adjust.get("overlap_rms_after_m")),
            ]
        )
    return section("strips", "Strip adjustment", body)


def strip_table(corrections: dict, cloud_strips: np.ndarray) -> str:
    """The corrections strip by strip (or, for the mounting model, unknown by unknown), then the overlaps.

    *cloud_strips*: every strip of the cloud, so that those without an
    overlap are listed too.
    """
    if corrections.get("model") == "mounting":
        pairs = corrections.get("pairs") or []
        pair_rows = [
            [
                f"{p['strips'][0]} – {p['strips'][1]}",
                p.get("overlap_area_m2"),
                p.get("patches"),
                p.get("points"),
                p.get("rms_before_m"),
                p.get("rms_after_m"),
            ]
            for p in pairs
        ]
        note = corrections.get("note")
        out = f"<p>{html.escape(note)}</p>" if note else ""
        return out + mounting_table(corrections) + _overlaps(pair_rows)
    datum = corrections.get("datum") or ""
    header = ["strip", "points", "status", "shift x / y / z (m)", "rotation x / y / z (°)", "1-σ shift (m)"]
    pair_rows = [
        [
            f"{p['strips'][0]} – {p['strips'][1]}",
            p["overlap_area_m2"],
            p["patches"],
            p["points"],
            p["rms_before_m"],
            p["rms_after_m"],
        ]
        for p in corrections.get("pairs") or []
    ]
    note = corrections.get("note")
    lead = (
        f"<p>Datum: {html.escape(datum)}.</p>"
        if datum
        else f"<p>{html.escape(note or 'Strips were not adjusted.')}</p>"
    )
    return lead + grid(header, _strip_rows(corrections, datum, cloud_strips)) + _overlaps(pair_rows)


def _strip_rows(corrections: dict, datum: str, cloud_strips: np.ndarray) -> list[list[object]]:
    """One row a strip: its points, status (datum, adjusted, not determined, no overlap), shift, rotation, sigma."""
    ref = int(datum.split()[1]) if datum.startswith("strip ") else None
    weak = {int(k) for k in corrections.get("not_determined", {})}
    rows = []
    for key, c in sorted(corrections.get("strips", {}).items(), key=lambda kv: int(kv[0])):
        s = int(key)
        status = "datum (held fixed)" if s == ref else "not determined: left as it is" if s in weak else "adjusted"
        t, r, st = c["translation_m"], c["rotation_deg"], c["sigma_translation_m"]
        rows.append(
            [
                str(s),
                c["points"],
                status,
                f"{t[0]:+.3f} / {t[1]:+.3f} / {t[2]:+.3f}",
                f"{r[0]:+.4f} / {r[1]:+.4f} / {r[2]:+.4f}",
                f"{st[0]:.3f} / {st[1]:.3f} / {st[2]:.3f}",
            ]
        )
    listed = {int(k) for k in corrections.get("strips", {})}
    for s in cloud_strips:
        if s > 0 and int(s) not in listed:
            rows.append([str(int(s)), None, "no overlap with another strip: not adjusted", None, None, None])
    return rows


def _overlaps(pair_rows: list[list[object]]) -> str:
    """The strip pairs' overlaps (planar patches) as a table; '' without a pair."""
    return "<h3>Overlaps (planar patches)</h3>" + grid(PAIR_HEADER, pair_rows) if pair_rows else ""


def mounting_table(corrections: dict) -> str:
    """The system calibration (``strip_adjust.model: mounting``): each unknown, its estimate, sigma and fate."""
    rows = []
    for u in corrections.get("unknowns", []):
        digits = 5 if u["unit"] == "deg" else 4
        if u["held_because"]:
            fate = f"not determined ({u['held_because']}): held at the configured value; {u['determined_by']}"
        elif not u["estimated"]:
            fate = "not estimated (configuration)"
        elif not u["applied"]:
            fate = f"not applied: {u['not_applied_because']}"
        else:
            fate = "applied"
            held = u.get("sigma_from_held")
            if held and held["shift"] >= 0.1 * (u["sigma"] or 0):
                fate += f"; its 1-σ includes {held['shift']:.{digits}f} from the held {held['unknown']}"
        # an estimate that is not significant is not a value: only its bound is (in the status)
        shown = u["estimate"] is not None and (u["applied"] or not u["estimated"])
        est = f"{u['estimate']:+.{digits}f}" if shown else None
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
    lead += (
        "; 1-σ of an applied unknown: the larger of the formal one and the one the geometry alone gives "
        "(surface slopes only where significant), with the held unknowns' possible error added"
    )
    if corrections.get("largest_point_move_m") is not None:
        lead += f"; largest point move {corrections['largest_point_move_m']:.4f} m"
    return lead + ".</p>" + grid(header, rows)


# --------------------------------------------------------------------------- vertical accuracy


def accuracy_section(accuracy: dict | None, cp: dict | None) -> str:
    """Vertical accuracy: the check-point figures (metrics of ``accuracy``), the truth raster's, every check point.

    NVA and VVA as ASPRS Edition 2 (and the USGS LBS from 2024 rev. A) state
    them, RMSEz, then the 95 % figures of Edition 1 (and the LBS to 2023 rev. A).

    *cp*: the check points one by one (:func:`~stages.report.inputs.checkpoint_rows`), or None.
    """
    truth = truth_html((accuracy or {}).get("truth"))
    accuracy = {k: v for k, v in (accuracy or {}).items() if k != "truth"}
    if not accuracy:
        body = truth + (
            "<p>No check points were configured (<code>stages.accuracy.checkpoints</code>), so no accuracy figures.</p>"
        )
        return section("accuracy", "Vertical accuracy", body)
    nva = accuracy.get("nva_95")
    n_nv, n_v = accuracy.get("n_non_vegetated"), accuracy.get("n_vegetated")
    before = "ASPRS Edition 1 and the USGS LBS to 2023 rev. A"
    rows = [
        (f"RMSEz, all {accuracy.get('n')} check points on the DTM (m)", accuracy.get("rmse_z")),
        ("mean error, all (m)", accuracy.get("mean_error")),
        (f"NVA = RMSEz, non-vegetated ({n_nv} check points) (m)", nva / 1.96 if nva is not None else None),
        (f"VVA = RMSEz, vegetated ({n_v} check points) (m)", accuracy.get("vva_rmse_z")),
        (f"NVA at 95 % as in {before}: 1.96 × RMSEz, non-vegetated (m)", nva),
        (f"VVA as in {before}: 95th percentile of |error|, vegetated (m)", accuracy.get("vva_95")),
        ("outside the DTM or on nodata", accuracy.get("outside")),
    ]
    body = table(rows) + truth + (checkpoints_html(cp) if cp is not None else "")
    return section("accuracy", "Vertical accuracy", body)


def checkpoints_html(cp: dict) -> str:
    """The check points' error histogram by land cover, and the check points one a row."""
    rows = [
        [i, lc, f"{x:.3f}", f"{y:.3f}", f"{z:.3f}", f"{d:.3f}", f"{e:+.3f}" if np.isfinite(e) else "off the DTM"]
        for i, lc, x, y, z, d, e in zip(
            cp["id"], cp["land_cover"], cp["x"], cp["y"], cp["z"], cp["dtm"], cp["error"], strict=True
        )
    ]
    err = cp["error"]
    out = ""
    if np.isfinite(err).any():
        out += figure(
            histogram_svg(err, np.asarray(cp["land_cover"], dtype=object)),
            "check-point error histogram",
            "Errors DTM − check point (metres), stacked by land cover.",
        )
    header = ["id", "land cover", "x", "y", "measured z", "DTM z", "error (m)"]
    return out + "<h3>Check points</h3>" + grid(header, rows)


def truth_html(truth: dict | None) -> str:
    """The DTM against a truth raster (``stages.accuracy.truth_dtm``): every cell, metres; '' without one."""
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
        out += _truth_by_relief(by_relief)
    by_cover = truth.get("by_land_cover") or {}
    if by_cover:
        out += _truth_by_cover(by_cover, truth.get("land_cover_file", ""))
    return out


def _truth_by_relief(by_relief: dict) -> str:
    """The truth figures where the truth is level (under 2 m over 3 x 3 cells) and where it is steep."""
    rows = [
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
    return (
        "<p>Where the truth itself is steep, a shift of one cell (the truth raster's own resampling "
        "across a wall) is already more than 1 m:</p>"
        + grid(["where", "cells", "RMS (m)", "> 1 m off (%)", "> 5 m off (%)"], rows)
    )


def _truth_by_cover(by_cover: dict, land_cover_file: object) -> str:
    """The truth figures by land cover (ASPRS code and name), from the land-cover raster *land_cover_file*."""
    header = ["land cover", "cells", "RMS (m)", "mean (m)", "> 1 m off (%)", "> 5 m off (%)", "max above / below (m)"]
    rows = [
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
    return f"<p>By what covers the ground ({html.escape(str(land_cover_file))}, nearest cell):</p>" + grid(header, rows)


def _share(n: int, counts: np.ndarray) -> str:
    """*n* as a share of all points in *counts*, per cent."""
    total = int(counts.sum())
    return f"{100.0 * n / total:.2f} %" if total else "—"
