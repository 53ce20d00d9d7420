"""The report page: its sections in order (:mod:`~stages.report.sections`), under one heading and style."""

from __future__ import annotations

import html
import time

from pipeline import __version__
from stages.report.acceptance import evaluate, truth_disagreement
from stages.report.figures import Canvas, map_figures
from stages.report.inputs import ReportInputs
from stages.report.measures import measure, sampling_warnings
from stages.report.sections import (
    acceptance_section,
    accuracy_section,
    classes_section,
    inputs_section,
    maps_section,
    raw_section,
    run_warnings_section,
    strips_section,
    summary_section,
    verdict_banner,
)

STYLE = """<style>
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:1300px;color:#222;padding:0 1em}
h1{margin-bottom:0} .sub{color:#666;margin-top:.2em}
section{margin:1.5em 0} table{border-collapse:collapse;margin:.5em 0} th,td{padding:.25em .8em;border-bottom:1px solid #ddd;text-align:left;vertical-align:top}
th{font-weight:600;color:#444} .maps{display:flex;flex-wrap:wrap;gap:1.5em} figure{margin:0;max-width:620px}
figure svg{max-width:100%;height:auto;border:1px solid #ccc} figcaption{color:#555;font-size:.9em}
table.wide td{font-size:.85em} .pass{color:#17692d} .fail{color:#b00020} .incomplete,.not{color:#8a5a00}
ul.warn li{color:#8a5a00} .banner{border:2px solid;border-radius:4px;padding:.2em .8em;margin:.6em 0}
.banner.fail{border-color:#b00020;background:#fce8e6} .banner.pass{border-color:#17692d;background:#e6f4ea}
.banner.incomplete{border-color:#8a5a00;background:#fff4e0} tr.pass td:nth-child(4){background:#e6f4ea} tr.fail td:nth-child(4){background:#fce8e6} tr.not td:nth-child(4){background:#fff4e0}
</style>"""


def build_report(*, name: str, metrics: dict, data: ReportInputs, max_size: int) -> tuple[str, dict]:
    """The report page as an HTML string, and the acceptance verdicts (``qc/acceptance.json``).

    Parameters
    ----------
    name : str
        The survey's name, in the title.
    metrics : dict
        Stage name -> the metrics of every stage that ran.
    data : ReportInputs
        The rasters, cloud summary and files the page draws.
    max_size : int
        Largest side of the rasters drawn in the maps, cells.
    """
    measured, why, voids = measure(metrics, data)
    verdict = evaluate(data.specification, measured, why)
    verdict["warnings"] = sampling_warnings(data, voids["covered_m2"])
    disagree = truth_disagreement(verdict, (metrics.get("accuracy") or {}).get("truth"))
    if disagree:
        verdict["warnings"].append(disagree)
    anpd_limit = next((c["limit"] for c in verdict["checks"] if c["measure"] == "anpd"), None)
    cv = Canvas.of(data.dtm, data.frame, data.cloud.units, max_size)
    sections = [
        verdict_banner(verdict),
        acceptance_section(verdict, measured),
        run_warnings_section(metrics),
        summary_section(
            metrics, verdict, cv, data.cloud.strips, len(data.input_files), measured["anpd"], data.cloud.class_counts
        ),
        inputs_section(data.input_files, data.input_info, data.cloud.header),
        maps_section(map_figures(cv, data, measured, voids, anpd_limit)),
        classes_section(data.cloud),
        raw_section(metrics.get("parse", {}), metrics.get("georeference")),
        strips_section(data.corrections, data.cloud.strips, metrics.get("strip_adjust") or {}),
        accuracy_section(metrics.get("accuracy"), data.checkpoints),
    ]
    return page(name, data.cloud.units.describe(), sections, heights_datum(metrics)), verdict


def heights_datum(metrics: dict) -> str:
    """What the products' heights are measured from, as the parse (LAS) or georeference (raw) stage said it."""
    return (
        (metrics.get("georeference") or {}).get("heights")
        or (metrics.get("parse") or {}).get("heights")
        or ("unknown: not stated by this run")
    )


def page(name: str, lengths: str, sections: list[str], heights: str = "") -> str:
    """The whole page: title, the line of version, date, units (*lengths*: :meth:`Units.describe`) and the
    heights' vertical datum (*heights*), the sections one a line."""
    made = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    head = (
        "<!DOCTYPE html>\n"
        f'<html lang="en"><head><meta charset="utf-8"><title>QC report — {html.escape(name)}</title>\n'
        f"{STYLE}</head><body>\n"
        f"<h1>QC report: {html.escape(name)}</h1>\n"
        f'<p class="sub">dtm-pipeline {__version__} · made {made} · {html.escape(lengths)}'
        f"{'' if '(' not in lengths else '; accuracy figures and headings marked m in metres'}"
        f"{f' · vertical datum: {html.escape(heights)}' if heights else ''}</p>\n"
    )
    return head + "".join(s + "\n" for s in sections) + "</body></html>\n"
