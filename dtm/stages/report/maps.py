"""The report's maps as PNG (matplotlib, Agg): rasters with a colour bar, categories with a legend, a histogram.

Every map has coordinate ticks in the CRS's units, a scale bar and a
grid-north arrow; rasters larger than ``max_size`` cells on a side are
thinned (every n-th cell) before they are drawn.  A map is drawn once, in
a figure sized to it with fixed margins (a crop to the drawn content,
``bbox_inches="tight"``, or a layout engine draws it twice), outside pyplot.
"""

from __future__ import annotations

import io
from dataclasses import dataclass

import numpy as np

#: Resolution of the PNGs, dots per inch.
DPI = 110
#: A map's axes: width and largest height, inches (a tall raster's are narrower).
MAP_WIDTH, MAP_MAX_HEIGHT = 4.4, 7.0
#: Fixed margins around a map's axes, inches: the northing ticks and label
#: (left), the rotated easting ticks and label (bottom), the title (top), the
#: colour bar with its ticks and label or nothing (right).
MARGIN_LEFT, MARGIN_BOTTOM, MARGIN_TOP, MARGIN_RIGHT_BAR, MARGIN_RIGHT = 0.95, 0.8, 0.3, 1.15, 0.2

RELIEF = "relief"  # matplotlib's terrain without its blue (sea) end: registered by _new_axes

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

    def extent(self, shape: tuple[int, int], step: int = 1) -> tuple[float, float, float, float]:
        rows, cols = shape
        return (self.x0, self.x0 + cols * step * self.cell, self.y1 - rows * step * self.cell, self.y1)


def _thin(array: np.ndarray, max_size: int) -> tuple[np.ndarray, int]:
    step = max(1, int(np.ceil(max(array.shape[:2]) / max_size)))
    return array[::step, ::step], step


def _nice_length(span: float) -> float:
    raw = span / 5.0
    mag = 10 ** np.floor(np.log10(raw)) if raw > 0 else 1.0
    return float(max(v * mag for v in (1, 2, 5) if v * mag <= raw) if raw >= mag else mag)


def _decorate(ax, extent, unit: str) -> None:
    """Coordinate ticks, a scale bar and a grid-north arrow."""
    from matplotlib.patches import FancyArrow, Rectangle

    x0, x1, y0, y1 = extent
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.ticklabel_format(useOffset=False, style="plain")
    ax.tick_params(labelsize=7)
    for label in ax.get_xticklabels():
        label.set_rotation(30)
    ax.set_xlabel(f"easting ({unit})", fontsize=8)
    ax.set_ylabel(f"northing ({unit})", fontsize=8)
    width, height = x1 - x0, y1 - y0
    length = _nice_length(width)
    bx, by = x0 + 0.05 * width, y0 + 0.05 * height
    ax.add_patch(Rectangle((bx, by), length, 0.012 * height, facecolor="black", edgecolor="black", zorder=5))
    ax.add_patch(Rectangle((bx, by), length / 2, 0.012 * height, facecolor="white", edgecolor="black", zorder=6))
    ax.text(
        bx + length / 2,
        by + 0.025 * height,
        f"{length:g} {unit}",
        ha="center",
        fontsize=7,
        zorder=6,
        bbox={"facecolor": "white", "alpha": 0.7, "edgecolor": "none", "pad": 1},
    )
    ax_x, ax_y = x1 - 0.06 * width, y1 - 0.2 * height
    ax.add_patch(
        FancyArrow(
            ax_x,
            ax_y,
            0,
            0.1 * height,
            width=0.012 * width,
            head_width=0.035 * width,
            head_length=0.04 * height,
            length_includes_head=True,
            color="black",
            zorder=6,
        )
    )
    ax.text(ax_x, ax_y + 0.115 * height, "N", ha="center", fontsize=8, weight="bold", zorder=6)


def _render(fig) -> bytes:
    """The figure as PNG, drawn once: its layout is fixed when it is made (no layout engine, no crop)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI)
    return buf.getvalue()


def _new_axes(shape: tuple[int, int], with_bar: bool):
    """A figure sized to a map of *shape* cells (rows, columns), its axes and the colour bar's axes (or None).

    The map's axes have the raster's aspect, ``MAP_WIDTH`` wide (narrower
    when that would make them taller than ``MAP_MAX_HEIGHT``), inside fixed
    margins for the ticks, the labels, the title and the colour bar; the
    figure is that size, so it is drawn once and needs no crop.
    """
    import matplotlib
    from matplotlib.colors import ListedColormap
    from matplotlib.figure import Figure

    if RELIEF not in matplotlib.colormaps:
        terrain = matplotlib.colormaps["terrain"]
        matplotlib.colormaps.register(ListedColormap(terrain(np.linspace(0.25, 1.0, 256)), name=RELIEF))
    rows, cols = shape
    aspect = rows / max(cols, 1)
    width = MAP_WIDTH if MAP_WIDTH * aspect <= MAP_MAX_HEIGHT else MAP_MAX_HEIGHT / aspect
    height = width * aspect
    right = MARGIN_RIGHT_BAR if with_bar else MARGIN_RIGHT
    fig_w, fig_h = MARGIN_LEFT + width + right, MARGIN_BOTTOM + height + MARGIN_TOP
    fig = Figure(figsize=(fig_w, fig_h))
    ax = fig.add_axes((MARGIN_LEFT / fig_w, MARGIN_BOTTOM / fig_h, width / fig_w, height / fig_h))
    cax = None
    if with_bar:  # 0.8 of the map's height, centred, as matplotlib's colorbar(shrink=0.8)
        bar_h = max(0.8 * height, 0.5)
        bottom = MARGIN_BOTTOM + (height - bar_h) / 2
        cax = fig.add_axes(((MARGIN_LEFT + width + 0.15) / fig_w, bottom / fig_h, 0.15 / fig_w, bar_h / fig_h))
    return fig, ax, cax


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
) -> bytes:
    """A map as PNG: *values* coloured with a colour bar labelled *label*, over an optional hillshade.

    *threshold* draws a line on the colour bar and the contour on the map;
    *points* ``(x, y, value)`` are drawn as dots coloured on the same scale;
    *lines* ``(x, y, name)`` as labelled lines.
    """
    fig, ax, cax = _new_axes(_thin(values, max_size)[0].shape, with_bar=True)
    thin, step = _thin(values, max_size)
    extent = frame.extent(thin.shape, step)
    if shade is not None:
        ax.imshow(_thin(shade, max_size)[0], cmap="gray", extent=extent, vmin=0, vmax=255, interpolation="nearest")
    finite = np.isfinite(thin)
    lo = vmin if vmin is not None else (float(np.nanmin(thin)) if finite.any() else 0.0)
    hi = vmax if vmax is not None else (float(np.nanmax(thin)) if finite.any() else 1.0)
    hi = hi if hi > lo else lo + 1.0
    mappable = ax.imshow(
        np.ma.masked_invalid(thin),
        cmap=cmap,
        vmin=lo,
        vmax=hi,
        extent=extent,
        alpha=0.6 if shade is not None else 1.0,
        interpolation="nearest",
    )
    if points is not None and len(points[0]):
        mappable = ax.scatter(
            points[0],
            points[1],
            c=points[2],
            cmap=cmap,
            vmin=lo,
            vmax=hi,
            s=28,
            edgecolors="black",
            linewidths=0.6,
            zorder=4,
        )
    if lines:
        _draw_lines(ax, lines)
    bar = fig.colorbar(mappable, cax=cax)
    bar.set_label(label, fontsize=8)
    bar.ax.tick_params(labelsize=7)
    if threshold is not None and lo < threshold < hi:
        _draw_threshold(ax, bar, thin, extent, threshold, threshold_label, hi)
    ax.set_title(title, fontsize=9)
    _decorate(ax, extent, frame.unit)
    return _render(fig)


def _draw_lines(ax, lines: list[tuple[np.ndarray, np.ndarray, str]]) -> None:
    """Lines ``(x, y, name)`` in the strip colours, with a legend of their names."""
    from matplotlib.lines import Line2D

    colours = [tuple(c / 255 for c in rgb) for rgb in STRIP_COLOURS]
    handles = []
    for i, (x, y, name) in enumerate(lines):
        ax.plot(x, y, color=colours[i % len(colours)], lw=1.6, zorder=4)
        handles.append(Line2D([0], [0], color=colours[i % len(colours)], lw=2, label=name))
    ax.legend(handles=handles, fontsize=7, loc="lower right", framealpha=0.8)


def _draw_threshold(ax, bar, thin: np.ndarray, extent, threshold: float, label: str, hi: float) -> None:
    """A red line at *threshold* on the colour bar, and its contour on the map (NaN cells taken as *hi*)."""
    bar.ax.axhline(threshold, color="red", lw=2)
    bar.ax.text(1.05, threshold, label, color="red", fontsize=7, transform=bar.ax.get_yaxis_transform())
    if np.isfinite(thin).any() and min(thin.shape) >= 2:  # a contour needs 2 x 2 cells
        ys = np.linspace(extent[3], extent[2], thin.shape[0])
        xs = np.linspace(extent[0], extent[1], thin.shape[1])
        ax.contour(xs, ys, np.nan_to_num(thin, nan=hi), levels=[threshold], colors="red", linewidths=0.8)


def category_map(
    classes: np.ndarray,
    frame: MapFrame,
    names: list[tuple[int, str, tuple]],
    *,
    title: str,
    max_size: int,
    shade: np.ndarray | None = None,
) -> bytes:
    """A map of categories (-1: none) with a legend of ``(value, name, rgb 0-255)``."""
    from matplotlib.patches import Patch

    fig, ax, _ = _new_axes(_thin(classes, max_size)[0].shape, with_bar=False)
    thin, step = _thin(classes, max_size)
    extent = frame.extent(thin.shape, step)
    rgba = np.zeros(thin.shape + (4,))
    for value, _, rgb in names:
        rgba[thin == value] = (*(c / 255 for c in rgb), 1.0)
    if shade is not None:
        ax.imshow(_thin(shade, max_size)[0], cmap="gray", extent=extent, vmin=0, vmax=255, interpolation="nearest")
        rgba[..., 3] = np.where(rgba[..., 3] > 0, 0.75, 0.0)
    ax.imshow(rgba, extent=extent, interpolation="nearest")
    ax.legend(
        handles=[Patch(color=tuple(c / 255 for c in rgb), label=name) for _, name, rgb in names],
        fontsize=7,
        loc="upper left",
        framealpha=0.85,
    )
    ax.set_title(title, fontsize=9)
    _decorate(ax, extent, frame.unit)
    return _render(fig)


def histogram_png(errors: np.ndarray, labels: np.ndarray) -> bytes:
    """Histogram of check-point errors (metres), one colour per land cover."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(5.0, 2.8))
    ax = fig.add_axes((0.13, 0.2, 0.84, 0.76))
    finite = np.isfinite(errors)
    bins = np.linspace(float(np.min(errors[finite])), float(np.max(errors[finite])), 16) if finite.sum() > 1 else 10
    groups = sorted(set(labels[finite].tolist()))
    ax.hist([errors[finite & (labels == g)] for g in groups], bins=bins, stacked=True, label=groups)
    ax.axvline(0.0, color="black", lw=0.8)
    ax.set_xlabel("DTM − check point (m)", fontsize=8)
    ax.set_ylabel("check points", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, title="land cover", title_fontsize=7)
    return _render(fig)
