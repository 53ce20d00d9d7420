"""QGIS layer styles as XML, written with the standard library (QGIS is not imported: it is GPL, not a dependency).

Each function returns the elements of one layer's style: the children of a
``.qml`` file's ``<qgis>`` root (:func:`qml`) and of a project's
``<maplayer>`` alike.  The formats are QGIS 3.22's (what its
``saveNamedStyle`` writes, cut to what it reads back); later versions read
them.  docs/stages/qgis.md.

>>> [e.tag for e in line_style((8, 81, 156), 0.4)]
['renderer-v2', 'blendMode', 'featureBlendMode', 'layerOpacity', 'layerGeometryType']
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from xml.etree import ElementTree as ET

import numpy as np

#: The QGIS version whose formats these are (the ``version`` attribute of a style or project).
QGIS_VERSION = "3.22.0-Białowieża"

#: QGIS's blend modes (``QgsPainting::BlendMode``): a layer's colours multiplied with those below it.
BLEND_NORMAL, BLEND_MULTIPLY = 0, 6

#: Colour ramp items of a raster style: the colour map sampled at this many evenly spaced values.
RAMP_STOPS = 17

#: QGIS's ``layerGeometryType`` of a vector style (``QgsWkbTypes::GeometryType``).
LINE, POLYGON = 1, 2

RGB = tuple[int, int, int]
RGBA = tuple[int, int, int, int]


def _sub(parent: ET.Element, tag: str, text: str | None = None, **attrib: str) -> ET.Element:
    element = ET.SubElement(parent, tag, attrib)
    if text is not None:
        element.text = text
    return element


def _element(tag: str, text: str) -> ET.Element:
    element = ET.Element(tag)
    element.text = text
    return element


def _number(value: float) -> str:
    """*value* as QGIS reads it back exactly (the shortest repr of the double)."""
    return repr(float(value))


def _colour(rgba: Sequence[int]) -> str:
    """``r,g,b,a`` as QGIS writes a symbol's colour (alpha 255 when not given)."""
    return ",".join(str(int(c)) for c in (*rgba, 255)[:4])


def ramp_items(lo: float, hi: float, table: np.ndarray, stops: int = RAMP_STOPS) -> list[tuple[float, RGB]]:
    """(value, colour) pairs: the (256, 3) colour *table* sampled at *stops* values from *lo* to *hi*.

    >>> table = np.stack([np.arange(256)] * 3, axis=1)
    >>> ramp_items(10.0, 20.0, table, stops=3)
    [(10.0, (0, 0, 0)), (15.0, (128, 128, 128)), (20.0, (255, 255, 255))]
    >>> ramp_items(5.0, 5.0, table)  # a raster of one value: one item
    [(5.0, (0, 0, 0))]
    """
    if not hi > lo:
        return [(float(lo), tuple(int(c) for c in table[0]))]
    out = []
    for k in range(stops):
        t = k / (stops - 1)
        value = hi if k == stops - 1 else lo + t * (hi - lo)  # the ends exactly the raster's
        out.append((float(value), tuple(int(c) for c in table[round(t * 255)])))
    return out


def _min_max_origin(parent: ET.Element) -> None:
    """The renderer's range is set by hand (``None``): QGIS keeps it, as computed from the raster's values."""
    origin = _sub(parent, "minMaxOrigin")
    for tag, text in (("limits", "None"), ("extent", "WholeRaster"), ("statAccuracy", "Exact")):
        _sub(origin, tag, text)


def raster_ramp_style(
    lo: float, hi: float, table: np.ndarray, *, unit: str = "", blend: int = BLEND_NORMAL
) -> list[ET.Element]:
    """A single-band pseudocolour style: the colour *table* interpolated from *lo* to *hi* (band 1)."""
    renderer = ET.Element(
        "rasterrenderer",
        type="singlebandpseudocolor",
        band="1",
        opacity="1",
        alphaBand="-1",
        classificationMin=_number(lo),
        classificationMax=_number(hi),
    )
    _min_max_origin(renderer)
    shader = _sub(_sub(renderer, "rastershader"), "colorrampshader")
    shader.attrib.update(
        colorRampType="INTERPOLATED",
        classificationMode="1",
        clip="0",
        minimumValue=_number(lo),
        maximumValue=_number(hi),
    )
    for value, (r, g, b) in ramp_items(lo, hi, table):
        label = f"{value:.2f} {unit}".strip()
        _sub(shader, "item", value=_number(value), color=f"#{r:02x}{g:02x}{b:02x}", alpha="255", label=label)
    return _raster(renderer, blend)


def raster_grey_style(lo: float, hi: float) -> list[ET.Element]:
    """A single-band grey style stretched from *lo* (black) to *hi* (white)."""
    renderer = ET.Element(
        "rasterrenderer", type="singlebandgray", grayBand="1", gradient="BlackToWhite", opacity="1", alphaBand="-1"
    )
    _min_max_origin(renderer)
    contrast = _sub(renderer, "contrastEnhancement")
    _sub(contrast, "minValue", _number(lo))
    _sub(contrast, "maxValue", _number(hi))
    _sub(contrast, "algorithm", "StretchToMinimumMaximum")
    return _raster(renderer, BLEND_NORMAL)


def _raster(renderer: ET.Element, blend: int) -> list[ET.Element]:
    pipe = ET.Element("pipe")
    pipe.append(renderer)
    return [pipe, _element("blendMode", str(blend))]


def point_classes_style(classes: Sequence[tuple[int, RGB, str, bool]]) -> list[ET.Element]:
    """A point cloud style by ASPRS class: (code, colour, label, drawn) per class; other codes are not drawn."""
    renderer = ET.Element(
        "renderer",
        type="classified",
        attribute="Classification",
        pointSize="1",
        pointSizeUnit="MM",
        pointSymbol="0",
        maximumScreenError="0.3",
        maximumScreenErrorUnit="MM",
    )
    categories = _sub(renderer, "categories")
    for code, rgb, label, drawn in classes:
        _sub(categories, "category", value=str(code), color=_colour(rgb), label=label, render=str(drawn).lower())
    return [renderer, _element("blendMode", str(BLEND_NORMAL)), _element("layerOpacity", "1")]


def _symbol_layer(symbol: ET.Element, cls: str, options: dict[str, str]) -> None:
    layer = _sub(symbol, "layer", **{"class": cls, "enabled": "1", "pass": "0", "locked": "0"})
    mapping = _sub(layer, "Option", type="Map")
    for name, value in options.items():
        _sub(mapping, "Option", type="QString", name=name, value=value)


def _symbol(name: str, kind: str) -> ET.Element:
    return ET.Element("symbol", type=kind, name=name, alpha="1", clip_to_extent="1", force_rhr="0")


def _line_symbol(name: str, rgba: Sequence[int], width: float, dashed: bool = False) -> ET.Element:
    symbol = _symbol(name, "line")
    _symbol_layer(
        symbol,
        "SimpleLine",
        {
            "line_color": _colour(rgba),
            "line_width": _number(width),
            "line_width_unit": "MM",
            "line_style": "dash" if dashed else "solid",
            "capstyle": "round",
            "joinstyle": "round",
        },
    )
    return symbol


def _vector(renderer: ET.Element, geometry: int) -> list[ET.Element]:
    tail = [("blendMode", "0"), ("featureBlendMode", "0"), ("layerOpacity", "1"), ("layerGeometryType", str(geometry))]
    return [renderer] + [_element(tag, text) for tag, text in tail]


def _single(symbol: ET.Element) -> ET.Element:
    renderer = ET.Element("renderer-v2", type="singleSymbol", symbollevels="0", forceraster="0", enableorderby="0")
    _sub(renderer, "symbols").append(symbol)
    return renderer


def fill_style(
    fill: Sequence[int] | None, outline: Sequence[int], width: float, *, dashed: bool = False
) -> list[ET.Element]:
    """Polygons filled with *fill* (RGBA; None: outlines only), outlined *width* mm in *outline*."""
    symbol = _symbol("0", "fill")
    _symbol_layer(
        symbol,
        "SimpleFill",
        {
            "color": _colour(fill if fill is not None else (0, 0, 0, 0)),
            "style": "solid" if fill is not None else "no",
            "outline_color": _colour(outline),
            "outline_style": "dash" if dashed else "solid",
            "outline_width": _number(width),
            "outline_width_unit": "MM",
            "joinstyle": "round",
        },
    )
    return _vector(_single(symbol), POLYGON)


def line_style(rgba: Sequence[int], width: float) -> list[ET.Element]:
    """Lines *width* mm wide in *rgba*."""
    return _vector(_single(_line_symbol("0", rgba, width)), LINE)


def index_lines_style(
    rgba: Sequence[int], width: float, index_width: float, index_filter: str, index_label: str, label: str
) -> list[ET.Element]:
    """Lines by rule: those *index_filter* (a QGIS expression) selects *index_width* mm wide, the others *width*."""
    renderer = ET.Element("renderer-v2", type="RuleRenderer", symbollevels="0", forceraster="0", enableorderby="0")
    rules = _sub(renderer, "rules", key="root")
    _sub(rules, "rule", key="index", filter=index_filter, label=index_label, symbol="0")
    _sub(rules, "rule", key="other", filter="ELSE", label=label, symbol="1")
    symbols = _sub(renderer, "symbols")
    symbols.append(_line_symbol("0", rgba, index_width))
    symbols.append(_line_symbol("1", rgba, width))
    return _vector(renderer, LINE)


def multiple_of(field: str, step: float, scale: float = 1.0) -> str:
    """A QGIS expression: *field* × *scale* is a whole multiple of *step* (to a millionth of a step).

    >>> multiple_of("elevation", 5.0)
    'abs("elevation" / 5.0 - round("elevation" / 5.0)) < 1e-06'
    """
    value = f'"{field}"' if scale == 1.0 else f'"{field}" * {_number(scale)}'
    ratio = f"{value} / {_number(step)}"
    return f"abs({ratio} - round({ratio})) < 1e-06"


def qml(style: list[ET.Element]) -> bytes:
    """A ``.qml`` file of *style* (UTF-8, with QGIS's DOCTYPE)."""
    root = ET.Element("qgis", version=QGIS_VERSION, styleCategories="AllStyleCategories")
    root.extend(style)
    return document(root)


def document(root: ET.Element) -> bytes:
    """*root* as a QGIS XML document: the DOCTYPE QGIS writes, then the elements, indented (*root* unchanged)."""
    root = copy.deepcopy(root)  # styles are shared between a .qml and the project: indented in a copy
    ET.indent(root)
    return (
        b"<!DOCTYPE qgis PUBLIC 'http://mrcc.com/qgis.dtd' 'SYSTEM'>\n"
        + ET.tostring(root, encoding="unicode").encode()
        + b"\n"
    )
