"""The report's SVG maps: colours, places and ticks checked against matplotlib, geometry and hand-made answers."""

from __future__ import annotations

import base64
import io
import re
from xml.etree import ElementTree

import matplotlib
import numpy as np
import pytest
from PIL import Image

from lidar import colormaps
from stages.report.maps import MapFrame, category_map, histogram_svg, raster_map, ticks

SVG = ""  # inline in HTML: no namespace declared (the HTML parser gives it)


def _images(svg: str) -> list[np.ndarray]:
    """Every PNG embedded in *svg*, as RGBA arrays, in the order they are drawn."""
    return [
        np.asarray(Image.open(io.BytesIO(base64.b64decode(data))).convert("RGBA"))
        for data in re.findall(r'href="data:image/png;base64,([^"]+)"', svg)
    ]


def _plot_area(svg: str) -> ElementTree.Element:
    """The nested ``<svg>`` that holds the map's raster, points and lines."""
    return ElementTree.fromstring(svg).find(f"{SVG}svg")


@pytest.mark.parametrize("name", colormaps.NAMES)
def test_colour_tables_are_matplotlibs(name):
    if name == "relief":  # terrain without its blue sea end
        rgba = matplotlib.colormaps["terrain"](np.linspace(0.25, 1.0, 256))
    else:
        rgba = matplotlib.colormaps[name](np.arange(256))
    np.testing.assert_array_equal(colormaps.table(name), np.round(rgba[:, :3] * 255).astype(np.uint8))


@pytest.mark.parametrize(
    ("lo", "hi", "want"),
    [
        (4474180.0, 4474330.0, ["4474200", "4474250", "4474300"]),
        (645.19, 666.58, ["650", "655", "660", "665"]),
        (0.0, 12.0, ["0.0", "2.5", "5.0", "7.5", "10.0"]),
        (-0.16, 0.16, ["-0.1", "0.0", "0.1"]),
        (0.0, 0.07, ["0.00", "0.02", "0.04", "0.06"]),
    ],
)
def test_ticks_are_round_values_inside_the_range(lo, hi, want):
    values, decimals = ticks(lo, hi)
    assert [f"{v:.{decimals}f}" for v in values] == want


def test_raster_colours_are_the_colour_map_and_nodata_is_clear():
    values = np.array([[0.0, 5.0, 10.0], [np.nan, 2.5, 7.5]])
    svg = raster_map(values, MapFrame(0.0, 2.0, 1.0, "m"), cmap="viridis", label="v", title="t", max_size=100)
    raster, bar = _images(svg)
    lut = colormaps.table("viridis")
    # matplotlib's rule: 256 equal bins from vmin to vmax, the top value in the last one
    np.testing.assert_array_equal(raster[0, :, :3], lut[[0, 128, 255]])
    np.testing.assert_array_equal(raster[1, 1:, :3], lut[[64, 192]])
    assert raster[1, 0, 3] == 0 and (raster[0, :, 3] == 255).all()
    np.testing.assert_array_equal(bar[::-1, 0, :3], lut)  # the colour bar: low at the bottom


def test_raster_over_a_hillshade_blends_sixty_percent_colour():
    values = np.array([[0.0, np.nan]])
    shade = np.array([[100.0, 200.0]])
    svg = raster_map(
        values,
        MapFrame(0.0, 1.0, 1.0, "m"),
        cmap="RdBu_r",
        label="v",
        title="t",
        max_size=100,
        vmin=0,
        vmax=1,
        shade=shade,
    )
    raster = _images(svg)[0]
    lo = colormaps.table("RdBu_r")[0].astype(float)
    np.testing.assert_array_equal(raster[0, 0, :3], np.round(0.6 * lo + 0.4 * 100.0))
    np.testing.assert_array_equal(raster[0, 1], [200, 200, 200, 255])  # no value: the shade alone


def test_points_and_lines_sit_where_their_coordinates_are():
    """A 100 m x 50 m map: its centre and its corners land on the plot area's centre and corners."""
    frame = MapFrame(1000.0, 2050.0, 1.0, "m")
    svg = raster_map(
        np.zeros((50, 100)),
        frame,
        cmap="viridis",
        label="v",
        title="t",
        max_size=100,
        points=(np.array([1050.0, 1000.0]), np.array([2025.0, 2050.0]), np.array([0.0, 0.0])),
        lines=[(np.array([1000.0, 1100.0]), np.array([2000.0, 2050.0]), "strip 1")],
    )
    area = _plot_area(svg)
    w, h = float(area.get("width")), float(area.get("height"))
    assert w / h == pytest.approx(2.0, abs=0.01)
    centre, corner = area.findall(f"{SVG}circle")
    assert (float(centre.get("cx")), float(centre.get("cy"))) == pytest.approx((w / 2, h / 2), abs=0.06)
    assert (float(corner.get("cx")), float(corner.get("cy"))) == (0.0, 0.0)
    points = area.find(f"{SVG}polyline").get("points").split()
    assert [float(v) for p in points for v in p.split(",")] == pytest.approx([0.0, h, w, 0.0], abs=0.06)
    assert "strip 1" in svg and "20 m" in svg  # the legend, and a scale bar of a fifth of 100 m


def test_threshold_contour_runs_between_the_cells_either_side():
    """Columns valued 0..5: the contour at 2.5 runs halfway between the centres of columns 2 and 3 (x = 3 cells)."""
    values = np.tile(np.arange(6.0), (4, 1))
    svg = raster_map(
        values, MapFrame(0.0, 4.0, 1.0, "m"), cmap="viridis", label="v", title="t", max_size=100, threshold=2.5
    )
    area = _plot_area(svg)
    w = float(area.get("width"))
    xs = {float(p.split(",")[0]) for line in area.findall(f"{SVG}polyline") for p in line.get("points").split()}
    assert xs and all(x == pytest.approx(w / 2, abs=0.06) for x in xs)


def test_categories_take_their_legend_colours():
    classes = np.array([[0, 1], [-1, 1]])
    names = [(0, "DTM", (200, 200, 200)), (1, "void", (200, 0, 0))]
    svg = category_map(classes, MapFrame(0.0, 2.0, 1.0, "m"), names, title="t", max_size=100)
    raster = _images(svg)[0]
    np.testing.assert_array_equal(raster[0, 0], [200, 200, 200, 255])
    np.testing.assert_array_equal(raster[:, 1], [[200, 0, 0, 255]] * 2)
    assert raster[1, 0, 3] == 0
    assert ">DTM<" in svg and ">void<" in svg


def test_histogram_stacks_one_bar_a_land_cover_and_bin():
    errors = np.array([-0.1, -0.1, 0.0, 0.1, np.nan])
    labels = np.array(["open", "forest", "open", "open", "open"], dtype=object)
    svg = histogram_svg(errors, labels)
    area = _plot_area(svg)
    bars = area.findall(f"{SVG}rect")
    # bins of 0.2 / 15: forest 1 at -0.1, open 1 at -0.1, 1 at 0, 1 at 0.1 (the NaN left out)
    assert len(bars) == 4
    heights = sorted(round(float(b.get("height")), 1) for b in bars)
    assert len(set(heights)) == 1  # each bar one check point tall
    stacked = [b for b in bars if float(b.get("x")) < 1.0 + min(float(c.get("x")) for c in bars)]
    assert len(stacked) == 2  # forest on open at -0.1
    assert ">land cover<" in svg and ">forest<" in svg and ">open<" in svg
