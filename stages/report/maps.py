"""The report's maps as inline SVG: rasters with a colour bar, categories with a legend, a histogram.

Every map has coordinate ticks in the CRS's units, a scale bar and a
grid-north arrow; rasters larger than ``max_size`` cells on a side are
thinned (every n-th cell) before they are drawn.  The raster itself is one
PNG inside the SVG, coloured here (nearest cell, no smoothing); ticks,
labels, bars, lines and points are vectors the browser draws, sharp at any
zoom.

Drawn by hand, not with matplotlib (which drew them up to report version 8):
importing matplotlib and drawing five maps took 0.8 s of a 1,000-point
file's 2.2 s run (issue 36), the same five maps now take milliseconds.
The colour maps are matplotlib's, as tables (:mod:`lidar.colormaps`).
"""

from __future__ import annotations

import base64
import html
import io
import math
from dataclasses import dataclass

import contourpy
import numpy as np
from affine import Affine
from PIL import Image

from lidar.colormaps import table

#: A map's plot area: width and largest height, SVG pixels (a tall raster's is narrower).
MAP_WIDTH, MAP_MAX_HEIGHT = 440.0, 700.0
#: Fixed margins around a map's plot area, pixels: the northing ticks and label
#: (left), the rotated easting ticks and label (bottom), the title (top), the
#: colour bar with its ticks and label or nothing (right).
MARGIN_LEFT, MARGIN_BOTTOM, MARGIN_TOP, MARGIN_RIGHT_BAR, MARGIN_RIGHT = 80.0, 66.0, 26.0, 112.0, 16.0
#: Text sizes, pixels.
FONT, FONT_SMALL, FONT_TITLE = 10.0, 9.0, 11.5
_FONTS = 'font-family="DejaVu Sans, Helvetica, Arial, sans-serif"'

RELIEF = "relief"  # matplotlib's terrain without its blue (sea) end (lidar/colormaps.py)

#: One colour a flight strip (matplotlib's tab10), RGB 0-255.
STRIP_COLOURS = np.array(
    [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ],
    dtype=np.float64,
)


@dataclass
class MapFrame:
    """Where a raster sits: upper-left corner, cell size (CRS units) and the unit's symbol."""

    x0: float
    y1: float
    cell: float
    unit: str

    @property
    def transform(self):
        """The raster's north-up affine transform (CRS units)."""
        return Affine(self.cell, 0.0, self.x0, 0.0, -self.cell, self.y1)

    def extent(self, shape: tuple[int, int], step: int = 1) -> tuple[float, float, float, float]:
        rows, cols = shape
        return (self.x0, self.x0 + cols * step * self.cell, self.y1 - rows * step * self.cell, self.y1)


@dataclass(frozen=True)
class _Box:
    """A plot area: its place in the SVG (pixels, y down) and the data extent ``(x0, x1, y0, y1)`` it shows."""

    left: float
    top: float
    width: float
    height: float
    extent: tuple[float, float, float, float]

    def px(self, x, y):
        """Data coordinates to pixels inside the box (its upper-left corner is 0, 0)."""
        x0, x1, y0, y1 = self.extent
        return (np.asarray(x) - x0) / (x1 - x0) * self.width, (y1 - np.asarray(y)) / (y1 - y0) * self.height


def _thin(array: np.ndarray, max_size: int) -> tuple[np.ndarray, int]:
    step = max(1, int(np.ceil(max(array.shape[:2]) / max_size)))
    return array[::step, ::step], step


def _nice_length(span: float) -> float:
    raw = span / 5.0
    mag = 10 ** np.floor(np.log10(raw)) if raw > 0 else 1.0
    return float(max(v * mag for v in (1, 2, 5) if v * mag <= raw) if raw >= mag else mag)


def ticks(lo: float, hi: float, target: int = 5) -> tuple[np.ndarray, int]:
    """Round tick values inside ``[lo, hi]`` (about *target* of them, steps of 1, 2, 2.5 or 5 × 10^k) and their decimals."""
    span = hi - lo
    if not (np.isfinite(span) and span > 0):
        return np.array([lo]), 2
    raw = span / target
    mag = 10.0 ** math.floor(math.log10(raw))
    step = next(s * mag for s in (1.0, 2.0, 2.5, 5.0, 10.0) if s * mag >= raw * 0.999)
    first = math.ceil(lo / step - 1e-9)
    values = (first + np.arange(int(math.floor(hi / step + 1e-9)) - first + 1)) * step
    power = math.floor(math.log10(step) + 1e-9)
    decimals = max(0, -power + (1 if round(step / 10.0**power, 6) == 2.5 else 0))
    return values, decimals


def _num(value: float, decimals: int) -> str:
    text = f"{value:.{decimals}f}"
    return "0" if text.lstrip("-").strip("0.") == "" else text.replace("-", "−")


def _esc(text: str) -> str:
    return html.escape(text, quote=True)


def _rgb(colour) -> str:
    r, g, b = (int(round(c)) for c in colour[:3])
    return f"#{r:02x}{g:02x}{b:02x}"


def _png(pixels: np.ndarray) -> bytes:
    """An (rows, cols, 3 or 4) uint8 array as PNG bytes (Pillow)."""
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(pixels)).save(buf, format="PNG", compress_level=6)
    return buf.getvalue()


def _image(pixels: np.ndarray, x: float, y: float, width: float, height: float) -> str:
    data = base64.b64encode(_png(pixels)).decode("ascii")
    return (
        f'<image x="{x:.1f}" y="{y:.1f}" width="{width:.1f}" height="{height:.1f}" preserveAspectRatio="none" '
        f'style="image-rendering:pixelated" href="data:image/png;base64,{data}"/>'
    )


def _text(x: float, y: float, text: str, *, size: float = FONT, anchor: str = "middle", extra: str = "") -> str:
    return f'<text x="{x:.1f}" y="{y:.1f}" font-size="{size:g}" text-anchor="{anchor}"{extra}>{_esc(text)}</text>'


def _halo(x: float, y: float, text: str, *, size: float = FONT_SMALL, weight: str = "normal") -> str:
    """Text with a white outline, legible over the map."""
    return _text(
        x,
        y,
        text,
        size=size,
        extra=f' font-weight="{weight}" stroke="white" stroke-width="3" stroke-opacity="0.8" paint-order="stroke"',
    )


def _colour(values: np.ndarray, cmap: str, lo: float, hi: float) -> np.ndarray:
    """*values* through the colour map over ``[lo, hi]`` (matplotlib's rule: 256 bins, ends clamped) as RGB floats."""
    t = (np.nan_to_num(values, nan=lo) - lo) / (hi - lo)
    idx = np.clip(np.floor(t * 256.0), 0, 255).astype(np.intp)
    return table(cmap)[idx].astype(np.float64)


def _layer(colour: np.ndarray, opaque: np.ndarray, shade: np.ndarray | None, alpha: float) -> np.ndarray:
    """RGBA uint8: *colour* where *opaque*, over the grey *shade* with *alpha* when one is given; elsewhere the shade or nothing."""
    rows, cols = opaque.shape
    out = np.zeros((rows, cols, 4), dtype=np.float64)
    if shade is not None:
        grey = shade[..., None].astype(np.float64)
        out[..., :3] = np.where(opaque[..., None], alpha * colour + (1.0 - alpha) * grey, grey)
        out[..., 3] = 255.0
    else:
        out[..., :3] = colour
        out[..., 3] = np.where(opaque, 255.0, 0.0)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _svg(width: float, height: float, body: list[str]) -> str:
    return (
        f'<svg viewBox="0 0 {width:.0f} {height:.0f}" width="{width:.0f}" '
        f'height="{height:.0f}" {_FONTS} font-size="{FONT:g}">'
        f'<rect width="100%" height="100%" fill="white"/>{"".join(body)}</svg>'
    )


def _map_box(shape: tuple[int, int], extent, with_bar: bool) -> tuple[_Box, float, float]:
    """The plot area for a raster of *shape* (rows, columns), and the SVG's width and height.

    The plot area has the raster's aspect, ``MAP_WIDTH`` wide (narrower when
    that would make it taller than ``MAP_MAX_HEIGHT``), inside fixed margins.
    """
    rows, cols = shape
    aspect = rows / max(cols, 1)
    width = MAP_WIDTH if MAP_WIDTH * aspect <= MAP_MAX_HEIGHT else MAP_MAX_HEIGHT / aspect
    height = max(width * aspect, 1.0)
    right = MARGIN_RIGHT_BAR if with_bar else MARGIN_RIGHT
    box = _Box(MARGIN_LEFT, MARGIN_TOP, width, height, extent)
    return box, MARGIN_LEFT + width + right, MARGIN_TOP + height + MARGIN_BOTTOM


def _frame(box: _Box, unit: str, title: str) -> list[str]:
    """The plot area's border, coordinate ticks and labels, title, scale bar and grid-north arrow."""
    x0, x1, y0, y1 = box.extent
    left, top, w, h = box.left, box.top, box.width, box.height
    out = [
        f'<rect x="{left:.1f}" y="{top:.1f}" width="{w:.1f}" height="{h:.1f}" fill="none" stroke="black" '
        'stroke-width="0.8"/>',
        _text(left + w / 2, top - 9, title, size=FONT_TITLE),
    ]
    xs, xd = ticks(x0, x1)
    for v in xs:
        px = left + box.px(v, y1)[0]
        out.append(f'<line x1="{px:.1f}" y1="{top + h:.1f}" x2="{px:.1f}" y2="{top + h + 4:.1f}" stroke="black"/>')
        out.append(
            _text(
                px + 3,
                top + h + 13,
                _num(v, xd),
                size=FONT_SMALL,
                anchor="end",
                extra=f' transform="rotate(-30 {px + 3:.1f} {top + h + 13:.1f})"',
            )
        )
    ys, yd = ticks(y0, y1)
    for v in ys:
        py = top + box.px(x0, v)[1]
        out.append(f'<line x1="{left - 4:.1f}" y1="{py:.1f}" x2="{left:.1f}" y2="{py:.1f}" stroke="black"/>')
        out.append(_text(left - 6, py + 3.2, _num(v, yd), size=FONT_SMALL, anchor="end"))
    out.append(_text(left + w / 2, top + h + 58, f"easting ({unit})"))
    label_x = left - 66
    out.append(
        _text(label_x, top + h / 2, f"northing ({unit})", extra=f' transform="rotate(-90 {label_x} {top + h / 2:.1f})"')
    )
    # scale bar, lower left: black, its first half white
    length = _nice_length(x1 - x0)
    bar_w = length / (x1 - x0) * w
    bx, by = left + 0.05 * w, top + 0.95 * h - 5
    out.append(f'<rect x="{bx:.1f}" y="{by:.1f}" width="{bar_w:.1f}" height="5" fill="black" stroke="black"/>')
    out.append(f'<rect x="{bx:.1f}" y="{by:.1f}" width="{bar_w / 2:.1f}" height="5" fill="white" stroke="black"/>')
    out.append(_halo(bx + bar_w / 2, by - 4, f"{length:g} {unit}"))
    # grid-north arrow, upper right
    ax, ay = left + 0.94 * w, top + max(0.08 * h, 22.0)
    out.append(
        f'<path d="M{ax:.1f} {ay:.1f} l-6 14 l4.5 0 l0 16 l3 0 l0 -16 l4.5 0 z" fill="black" stroke="white" '
        'stroke-width="0.8"/>'
    )
    out.append(_halo(ax, ay - 4, "N", size=FONT, weight="bold"))
    return out


def _colour_bar(box: _Box, cmap: str, lo: float, hi: float, label: str) -> tuple[list[str], float, float]:
    """A vertical colour bar right of *box*, 0.8 of its height, with ticks and *label*; and its top and height."""
    bar_h = max(0.8 * box.height, 60.0)
    top = box.top + (box.height - bar_h) / 2
    x = box.left + box.width + 16
    lut = table(cmap)[::-1][:, None, :]
    out = [
        _image(lut, x, top, 12, bar_h),
        f'<rect x="{x:.1f}" y="{top:.1f}" width="12" height="{bar_h:.1f}" fill="none" stroke="black" '
        'stroke-width="0.6"/>',
    ]
    values, decimals = ticks(lo, hi)
    for v in values:
        py = top + (hi - v) / (hi - lo) * bar_h
        out.append(f'<line x1="{x + 12:.1f}" y1="{py:.1f}" x2="{x + 15:.1f}" y2="{py:.1f}" stroke="black"/>')
        out.append(_text(x + 17, py + 3.2, _num(v, decimals), size=FONT_SMALL, anchor="start"))
    lx, ly = x + 80, top + bar_h / 2
    out.append(_text(lx, ly, label, extra=f' transform="rotate(-90 {lx:.1f} {ly:.1f})"'))
    return out, top, bar_h


def _contour(box: _Box, thin: np.ndarray, threshold: float, fill: float) -> list[str]:
    """The *threshold* contour of *thin* (cell centres; NaN taken as *fill*) as red polylines inside the plot area."""
    if not np.isfinite(thin).any() or min(thin.shape) < 2:  # a contour needs 2 x 2 cells
        return []
    x0, x1, y0, y1 = box.extent
    rows, cols = thin.shape
    xs = x0 + (np.arange(cols) + 0.5) * (x1 - x0) / cols
    ys = y1 - (np.arange(rows) + 0.5) * (y1 - y0) / rows
    gen = contourpy.contour_generator(xs, ys, np.nan_to_num(thin, nan=fill), line_type="Separate")
    return [_polyline(box, line[:, 0], line[:, 1], "red", 1.0) for line in gen.lines(threshold)]


def _polyline(box: _Box, x, y, colour: str, width: float) -> str:
    px, py = box.px(x, y)
    pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(px, py, strict=True))
    return f'<polyline points="{pts}" fill="none" stroke="{colour}" stroke-width="{width:g}"/>'


def _legend(
    entries: list[tuple[str, str, str]], x: float, y: float, corner: str = "upper left", title: str = ""
) -> list[str]:
    """A legend box of ``(kind, colour, name)`` rows (kind ``patch`` or ``line``) with its *corner* at (*x*, *y*)."""
    rows = ([title] if title else []) + [name for _, _, name in entries]
    width = 30 + 5.6 * max(len(name) for name in rows)
    height = 6 + 14 * len(rows)
    left = x - width if "right" in corner else x
    top = y - height if "lower" in corner else y
    out = [
        f'<rect x="{left:.1f}" y="{top:.1f}" width="{width:.1f}" height="{height:.1f}" fill="white" '
        'fill-opacity="0.85" stroke="#999" stroke-width="0.6" rx="2"/>'
    ]
    if title:
        out.append(_text(left + width / 2, top + 13.2, title, size=FONT_SMALL))
    for i, (kind, colour, name) in enumerate(entries, start=1 if title else 0):
        cy = top + 10 + 14 * i
        if kind == "line":
            out.append(
                f'<line x1="{left + 5:.1f}" y1="{cy:.1f}" x2="{left + 22:.1f}" y2="{cy:.1f}" stroke="{colour}" '
                'stroke-width="2"/>'
            )
        else:
            out.append(f'<rect x="{left + 6:.1f}" y="{cy - 5:.1f}" width="14" height="9" fill="{colour}"/>')
        out.append(_text(left + 26, cy + 3.2, name, size=FONT_SMALL, anchor="start"))
    return out


def _plot(box: _Box, inner: list[str]) -> str:
    """*inner* drawn in the plot area's own pixels, clipped to it (a nested ``<svg>`` clips its content)."""
    return (
        f'<svg x="{box.left:.1f}" y="{box.top:.1f}" width="{box.width:.1f}" height="{box.height:.1f}" '
        f'viewBox="0 0 {box.width:.1f} {box.height:.1f}" preserveAspectRatio="none">{"".join(inner)}</svg>'
    )


def raster_map(
    values: np.ndarray,
    frame: MapFrame,
    *,
    cmap: str,
    label: str,
    title: str,
    max_size: int,
    vmin: float | None = None,
    vmax: float | None = None,
    shade: np.ndarray | None = None,
    threshold: float | None = None,
    threshold_label: str = "",
    points: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
    lines: list[tuple[np.ndarray, np.ndarray, str]] | None = None,
) -> str:
    """A map as SVG: *values* coloured with a colour bar labelled *label*, over an optional hillshade (0-255).

    *threshold* draws a line on the colour bar and the contour on the map;
    *points* ``(x, y, value)`` are drawn as dots coloured on the same scale;
    *lines* ``(x, y, name)`` as lines in the strip colours with a legend.
    """
    thin, step = _thin(values, max_size)
    box, width, height = _map_box(thin.shape, frame.extent(thin.shape, step), with_bar=True)
    finite = np.isfinite(thin)
    lo = vmin if vmin is not None else (float(np.nanmin(thin)) if finite.any() else 0.0)
    hi = vmax if vmax is not None else (float(np.nanmax(thin)) if finite.any() else 1.0)
    hi = hi if hi > lo else lo + 1.0
    grey = _thin(shade, max_size)[0] if shade is not None else None
    pixels = _layer(_colour(thin, cmap, lo, hi), finite, grey, 0.6)
    inner = [_image(pixels, 0, 0, box.width, box.height)]
    if threshold is not None and lo < threshold < hi:
        inner += _contour(box, thin, threshold, hi)
    if lines:
        inner += [
            _polyline(box, x, y, _rgb(STRIP_COLOURS[i % len(STRIP_COLOURS)]), 1.6) for i, (x, y, _) in enumerate(lines)
        ]
    if points is not None and len(points[0]):
        px, py = box.px(points[0], points[1])
        colours = _colour(np.asarray(points[2], dtype=np.float64), cmap, lo, hi)
        inner += [
            f'<circle cx="{a:.1f}" cy="{b:.1f}" r="3.5" fill="{_rgb(c)}" stroke="black" stroke-width="0.6"/>'
            for a, b, c in zip(px, py, colours, strict=True)
        ]
    body = [_plot(box, inner)]
    bar, bar_top, bar_h = _colour_bar(box, cmap, lo, hi, label)
    body += bar
    if threshold is not None and lo < threshold < hi:
        ty = bar_top + (hi - threshold) / (hi - lo) * bar_h
        bx = box.left + box.width + 16
        body.append(
            f'<line x1="{bx - 2:.1f}" y1="{ty:.1f}" x2="{bx + 14:.1f}" y2="{ty:.1f}" stroke="red" stroke-width="2"/>'
        )
        body.append(_text(bx + 44, ty + 3.2, threshold_label, size=FONT_SMALL, anchor="start", extra=' fill="red"'))
    if lines:
        entries = [("line", _rgb(STRIP_COLOURS[i % len(STRIP_COLOURS)]), name) for i, (_, _, name) in enumerate(lines)]
        body += _legend(entries, box.left + box.width - 6, box.top + box.height - 18, "lower right")
    body += _frame(box, frame.unit, title)
    return _svg(width, height, body)


def category_map(
    classes: np.ndarray,
    frame: MapFrame,
    names: list[tuple[int, str, tuple]],
    *,
    title: str,
    max_size: int,
    shade: np.ndarray | None = None,
) -> str:
    """A map of categories (-1: none) as SVG, with a legend of ``(value, name, rgb 0-255)``."""
    thin, step = _thin(classes, max_size)
    box, width, height = _map_box(thin.shape, frame.extent(thin.shape, step), with_bar=False)
    colour = np.zeros(thin.shape + (3,))
    known = np.zeros(thin.shape, dtype=bool)
    for value, _, rgb in names:
        hit = thin == value
        colour[hit] = rgb
        known |= hit
    grey = _thin(shade, max_size)[0] if shade is not None else None
    pixels = _layer(colour, known, grey, 0.75)
    body = [_plot(box, [_image(pixels, 0, 0, box.width, box.height)])]
    body += _legend([("patch", _rgb(rgb), name) for _, name, rgb in names], box.left + 6, box.top + 6)
    body += _frame(box, frame.unit, title)
    return _svg(width, height, body)


def histogram_svg(errors: np.ndarray, labels: np.ndarray) -> str:
    """Histogram of check-point errors (metres) as SVG, stacked by land cover, one colour each."""
    width, height = 500.0, 280.0
    finite = np.isfinite(errors)
    e = errors[finite]
    lo, hi = (float(e.min()), float(e.max())) if e.size else (-1.0, 1.0)
    if hi <= lo:
        lo, hi = lo - 0.05, hi + 0.05
    edges = np.linspace(lo, hi, 16)
    groups = sorted(set(labels[finite].tolist()))
    counts = np.array([np.histogram(errors[finite & (labels == g)], bins=edges)[0] for g in groups]).reshape(
        len(groups), len(edges) - 1
    )
    top_count = max(int(counts.sum(axis=0).max()), 1)
    pad = 0.04 * (hi - lo)
    box = _Box(64.0, 14.0, width - 64.0 - 14.0, height - 14.0 - 52.0, (lo - pad, hi + pad, 0.0, top_count * 1.05))
    inner = []
    base = np.zeros(len(edges) - 1)
    for i, row in enumerate(counts):
        colour = _rgb(STRIP_COLOURS[i % len(STRIP_COLOURS)])
        for j in np.flatnonzero(row):
            x_a, y_a = box.px(edges[j], base[j] + row[j])
            x_b, y_b = box.px(edges[j + 1], base[j])
            inner.append(
                f'<rect x="{x_a:.1f}" y="{y_a:.1f}" width="{x_b - x_a:.1f}" height="{y_b - y_a:.1f}" '
                f'fill="{colour}" stroke="white" stroke-width="0.5"/>'
            )
        base += row
    if lo - pad < 0.0 < hi + pad:
        zx = box.px(0.0, 0.0)[0]
        inner.append(
            f'<line x1="{zx:.1f}" y1="0" x2="{zx:.1f}" y2="{box.height:.1f}" stroke="black" stroke-width="0.8"/>'
        )
    body = [
        _plot(box, inner),
        f'<rect x="{box.left}" y="{box.top}" width="{box.width:.1f}" height="{box.height:.1f}" fill="none" '
        'stroke="black" stroke-width="0.8"/>',
    ]
    xs, xd = ticks(lo - pad, hi + pad)
    for v in xs:
        px = box.left + box.px(v, 0.0)[0]
        body.append(
            f'<line x1="{px:.1f}" y1="{box.top + box.height:.1f}" x2="{px:.1f}" y2="{box.top + box.height + 4:.1f}" '
            'stroke="black"/>'
        )
        body.append(_text(px, box.top + box.height + 15, _num(v, xd), size=FONT_SMALL))
    ys, _ = ticks(0.0, top_count * 1.05)
    for v in ys[ys == np.round(ys)]:  # whole check points only
        py = box.top + box.px(0.0, v)[1]
        body.append(f'<line x1="{box.left - 4:.1f}" y1="{py:.1f}" x2="{box.left:.1f}" y2="{py:.1f}" stroke="black"/>')
        body.append(_text(box.left - 6, py + 3.2, f"{int(v)}", size=FONT_SMALL, anchor="end"))
    body.append(_text(box.left + box.width / 2, height - 12, "DTM − check point (m)"))
    ly = box.top + box.height / 2
    body.append(_text(20, ly, "check points", extra=f' transform="rotate(-90 20 {ly:.1f})"'))
    entries = [("patch", _rgb(STRIP_COLOURS[i % len(STRIP_COLOURS)]), str(g)) for i, g in enumerate(groups)]
    body += _legend(entries, box.left + box.width - 6, box.top + 6, "upper right", title="land cover")
    return _svg(width, height, body)
