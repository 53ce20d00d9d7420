"""The QGIS styles and project as XML, without QGIS: ramps, classes, contour rules, the layers each job styles."""

from __future__ import annotations

import io
import zipfile
from pathlib import Path
from xml.etree import ElementTree

import numpy as np
import pytest
import rasterio
from affine import Affine

from lidar import glossary
from lidar.colormaps import table
from pipeline.config import load_config
from pipeline.runner import build_plan
from pipeline.stage import config_model
from stages.plugin import plugin
from stages.qgis.layers import contour_style, point_classes, product_paths, raster_layer, style_name
from stages.qgis.project import QGS_NAME, Layer, project_document, qgz
from stages.qgis.stage import value_range
from stages.qgis.styles import (
    BLEND_MULTIPLY,
    RAMP_STOPS,
    multiple_of,
    point_classes_style,
    qml,
)

ROOT = Path(__file__).resolve().parents[3]


def _parse(data: bytes) -> ElementTree.Element:
    assert data.startswith(b"<!DOCTYPE qgis ")
    return ElementTree.fromstring(data.split(b"\n", 1)[1])


def test_the_dtm_ramp_spans_the_rasters_values_in_the_reports_colours():
    lo, hi = float(np.float32(644.7378540039062)), float(np.float32(678.1737060546875))
    root = _parse(qml(raster_layer("dtm", "dtm.tif", lo, hi).style))
    renderer = root.find("pipe/rasterrenderer")
    assert renderer.get("type") == "singlebandpseudocolor" and renderer.get("band") == "1"
    assert float(renderer.get("classificationMin")) == lo and float(renderer.get("classificationMax")) == hi
    assert renderer.find("minMaxOrigin/limits").text == "None"  # QGIS keeps the range, does not recompute it
    shader = renderer.find("rastershader/colorrampshader")
    assert shader.get("colorRampType") == "INTERPOLATED"
    assert float(shader.get("minimumValue")) == lo and float(shader.get("maximumValue")) == hi
    items = shader.findall("item")
    assert len(items) == RAMP_STOPS
    values = [float(i.get("value")) for i in items]
    assert values[0] == lo and values[-1] == hi and values == sorted(values)
    relief = table("relief")
    assert items[0].get("color") == "#{:02x}{:02x}{:02x}".format(*relief[0])
    assert items[-1].get("color") == "#{:02x}{:02x}{:02x}".format(*relief[255])
    assert root.find("blendMode").text == str(BLEND_MULTIPLY)  # multiplied with the hillshade below it


def test_a_difference_ramp_is_centred_on_zero():
    renderer = _parse(qml(raster_layer("strip_difference_after", "s.tif", -0.05, 0.2).style)).find(
        "pipe/rasterrenderer"
    )
    assert (float(renderer.get("classificationMin")), float(renderer.get("classificationMax"))) == (-0.2, 0.2)


def test_the_hillshade_is_grey_between_its_values():
    layer = raster_layer("hillshade", "hillshade.tif", 37.0, 250.0)
    renderer = _parse(qml(layer.style)).find("pipe/rasterrenderer")
    assert renderer.get("type") == "singlebandgray" and layer.visible
    assert renderer.find("contrastEnhancement/minValue").text == "37.0"
    assert renderer.find("contrastEnhancement/maxValue").text == "250.0"


def test_points_are_drawn_by_asprs_class_in_the_reports_colours():
    root = _parse(qml(point_classes_style(point_classes())))
    renderer = root.find("renderer")
    assert renderer.get("type") == "classified" and renderer.get("attribute") == "Classification"
    cats = {int(c.get("value")): c for c in renderer.findall("categories/category")}
    assert sorted(cats) == list(range(23))  # every ASPRS class name: no point is left undrawn
    assert cats[2].get("color") == "166,124,82,255" and cats[2].get("label") == "2 ground"
    for code, rgb in glossary.CLASS_COLOURS.items():
        assert cats[code].get("color") == ",".join(map(str, (*rgb, 255))) and cats[code].get("render") == "true"
    assert cats[7].get("render") == cats[18].get("render") == "false"  # noise off at first, as in the report


def test_index_contours_every_fifth_interval():
    root = _parse(qml(contour_style(0.5, 1.0)))
    assert root.find("layerGeometryType").text == "1"
    renderer = root.find("renderer-v2")
    assert renderer.get("type") == "RuleRenderer"
    index, other = renderer.findall("rules/rule")
    assert (
        index.get("filter")
        == multiple_of("elevation", 2.5)
        == 'abs("elevation" / 2.5 - round("elevation" / 2.5)) < 1e-06'
    )
    assert other.get("filter") == "ELSE"
    widths = {
        s.get("name"): float(s.find("layer/Option/Option[@name='line_width']").get("value"))
        for s in renderer.findall("symbols/symbol")
    }
    assert widths[index.get("symbol")] > widths[other.get("symbol")]
    # heights in US survey feet: the rule converts them to metres before it divides
    assert '"elevation" * 0.3048006096012192 / 5.0' in contour_style(1.0, 0.3048006096012192)[0].find("rules/rule").get(
        "filter"
    )


def test_value_range_leaves_nodata_and_nan_out(tmp_path):
    band = np.full((300, 300), -9999.0, np.float32)
    band[10, 20], band[299, 299], band[5, 5] = 3.5, -2.0, np.nan
    path = tmp_path / "r.tif"
    with rasterio.open(
        path, "w", driver="GTiff", width=300, height=300, count=1, dtype="float32", nodata=-9999.0,
        transform=Affine(1, 0, 0, 0, -1, 300), tiled=True, blockxsize=256, blockysize=256,
    ) as ds:  # fmt: skip
        ds.write(band, 1)
    assert value_range(path) == (-2.0, 3.5)
    band[:] = -9999.0
    with rasterio.open(path, "r+") as ds:
        ds.write(band, 1)
    assert value_range(path) is None


def test_the_project_is_relative_and_the_same_bytes_every_time():
    layers = [
        Layer("points", "point-cloud", "pdal", "points.laz", visible=False),
        Layer("survey boundary", "vector", "ogr", "survey.gpkg", table="boundary", geometry="Polygon"),
        raster_layer("dtm", "dtm.tif", 1.0, 2.0),
    ]
    data = qgz(project_document(layers, title="t", crs_wkt="WKT", extent=(0.0, 1.0, 2.0, 3.0)))
    assert data == qgz(project_document(layers, title="t", crs_wkt="WKT", extent=(0.0, 1.0, 2.0, 3.0)))
    with zipfile.ZipFile(io.BytesIO(data)) as archive:
        assert archive.namelist() == [QGS_NAME]
        root = _parse(archive.read(QGS_NAME))
    assert [m.find("datasource").text for m in root.findall("projectlayers/maplayer")] == [
        "./points.laz",
        "./survey.gpkg|layername=boundary",
        "./dtm.tif",
    ]
    assert root.find("properties/Paths/Absolute").text == "false"
    assert root.find("projectCrs/spatialrefsys/wkt").text == "WKT"
    tree = root.findall("layer-tree-group/layer-tree-layer")
    assert [t.get("checked") for t in tree] == ["Qt::Unchecked", "Qt::Checked", "Qt::Checked"]
    assert [t.get("id") for t in tree] == [o.get("id") for o in root.findall("layerorder/layer")]
    assert len({t.get("id") for t in tree}) == 3


#: Published files a project does not open: the points as COPC and VRT mosaics (the untiled rasters are there).
NOT_LAYERS = (".copc.laz", ".vrt")


def _plans():
    model = config_model(plugin)
    for config in sorted((ROOT / "configs").glob("*.yaml")):
        if config.name == "simulate.yaml":
            continue
        variants = [[], ["stages.export_las.compress=false", "stages.footprints.enabled=false"]]
        if config.name == "las.yaml":
            variants += [
                ["stages.export_las.files=per_input", "stages.classify_water.enabled=false"],
                ["stages.export_las.copc=true", "stages.export_tiles.tile_size=200", "stages.hillshade.enabled=false"],
            ]
        for sets in variants:
            yield f"{config.name} {' '.join(sets)}", build_plan(load_config(config, model, sets), plugin)


@pytest.mark.parametrize("name, plan", list(_plans()))
def test_every_raster_vector_and_point_product_is_styled(name, plan):
    step = next(s for s in plan.steps if s.name == "qgis")
    published = {
        artifact: path
        for s in plan.steps
        if s.name != "qgis"
        for artifact, path in s.io.products.items()
        if path.endswith((".tif", ".gpkg", ".laz", ".las")) and not path.endswith(NOT_LAYERS) or path == "points"
    }
    assert set(step.io.inputs) == set(published), name
    paths = product_paths(published.get("points_export", "points.laz") == "points.laz")
    assert {a: paths[a] for a in step.io.inputs} == published
    styles = {p for a, p in step.io.products.items() if a != "project"}
    assert styles == {style_name(p) for a, p in published.items() if a != "points_per_input"}
    assert step.io.products["project"] == "project.qgz"
