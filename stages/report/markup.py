"""The report's HTML pieces: values as the page prints them, tables, inline figures, sections."""

from __future__ import annotations

import html

import numpy as np

UNIT_SYMBOLS = {"metre": "m", "foot": "ft", "US survey foot": "US ft"}


def unit_symbol(name: str) -> str:
    """'m', 'ft' or 'US ft' for a unit name of :class:`lidar.units.Units`."""
    return UNIT_SYMBOLS.get(name, name)


def fmt(value: object) -> str:
    """A value as a table cell shows it: yes/no, up to 3 decimals, thousands separated, '—' for none."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        if not np.isfinite(value):
            return "—"
        return f"{value:,.3f}".rstrip("0").rstrip(".") if abs(value) < 1e6 else f"{value:,.0f}"
    if isinstance(value, (int, np.integer)):
        return f"{int(value):,}"
    return "—" if value is None else str(value)


def figure(svg: str, alt: str, caption: str) -> str:
    """An SVG drawing inline in a ``<figure>``, named *alt* for screen readers, with its caption (HTML, not escaped)."""
    labelled = svg.replace("<svg ", f'<svg role="img" aria-label="{html.escape(alt)}" ', 1)
    return f"<figure>{labelled}<figcaption>{caption}</figcaption></figure>"


def table(rows: list[tuple[str, object]]) -> str:
    """A two-column table: one ``(heading, value)`` a row."""
    body = "".join(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(fmt(v))}</td></tr>" for k, v in rows)
    return f"<table>{body}</table>"


def grid(header: list[str], rows: list[list[object]], cls: str = "") -> str:
    """A table with a header row, one list of values a row, of CSS class *cls*."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(fmt(v))}</td>" for v in row) + "</tr>" for row in rows)
    return f'<table class="{cls}"><tr>{head}</tr>{body}</table>'


def section(key: str, title: str, body: str) -> str:
    """One section of the page: its anchor *key*, its heading, its HTML."""
    return f'<section id="{key}"><h2>{title}</h2>{body}</section>'
