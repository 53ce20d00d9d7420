"""QGIS opens the delivery styled: configs/las.yaml run, then project.qgz and every .qml loaded by QGIS itself.

QGIS is not a dependency (GPL): the test drives the system Python's QGIS
bindings (Debian's ``python3-qgis``, 3.22, which ``scripts/setup.sh --test``
installs as root) in a subprocess, headless (``QT_QPA_PLATFORM=offscreen``).
:data:`PROBE` opens the project and every style and prints what QGIS made of
them as JSON; the tests judge it.  Without QGIS the tests skip on a
workstation and fail under CI (tests/conftest.py, ``in_ci``).

Debian 12's QGIS is built without PDAL, so it has no point cloud provider
for ``points.laz``: there the points layer is unavailable (as QGIS shows
it), and its style is read by QGIS from the project's XML instead.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import pyogrio
import pytest
import rasterio

from lidar import glossary
from pipeline.cli import main
from tests.conftest import in_ci

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "las.yaml"
#: The Python that has QGIS's bindings (the system's: QGIS is not installed into the virtualenv).
QGIS_PYTHON = Path("/usr/bin/python3")

pytestmark = pytest.mark.slow

PROBE = r"""
import json, os, sys, zipfile
from qgis.core import (Qgis, QgsApplication, QgsDataProvider, QgsPointCloudLayer, QgsPointCloudRenderer, QgsProject,
                       QgsProviderRegistry, QgsRasterLayer, QgsReadWriteContext, QgsVectorLayer)
from qgis.gui import QgsMapCanvas
from qgis.PyQt.QtXml import QDomDocument

app = QgsApplication([], True)
app.initQgis()
out = sys.argv[1]
providers = QgsProviderRegistry.instance().providerList()


def rgb(colour):
    return [colour.red(), colour.green(), colour.blue()]


def renderer(r):
    if r is None:
        return None
    kind = r.type()
    info = {"type": kind}
    if kind == "singlebandpseudocolor":
        items = r.shader().rasterShaderFunction().colorRampItemList()
        items = [[i.value, rgb(i.color)] for i in items]
        info.update(min=r.classificationMin(), max=r.classificationMax(), items=items)
    elif kind == "singlebandgray":
        info.update(min=r.contrastEnhancement().minimumValue(), max=r.contrastEnhancement().maximumValue())
    elif kind == "RuleRenderer":
        info["rules"] = [[c.filterExpression(), c.isElse(), c.symbol().width()] for c in r.rootRule().children()]
    elif kind == "singleSymbol":
        info["colour"] = rgb(r.symbol().color())
    elif kind == "classified":
        info["classes"] = {str(c.value()): [rgb(c.color()), c.renderState()] for c in r.categories()}
    return info


def error(layer):
    found = layer.error()
    return "" if found.isEmpty() else found.summary()  # (summary() of no error crashes QGIS 3.22)


def xml_renderer(layer_id):
    # a layer QGIS cannot open keeps no renderer: QGIS reads the project's own XML of it instead
    with zipfile.ZipFile(os.path.join(out, "project.qgz")) as archive:
        name = next(n for n in archive.namelist() if n.endswith(".qgs"))
        doc = QDomDocument()
        doc.setContent(archive.read(name))
    layers = doc.documentElement().firstChildElement("projectlayers").elementsByTagName("maplayer")
    for k in range(layers.count()):
        element = layers.at(k).toElement()
        if element.firstChildElement("id").text() == layer_id:
            return QgsPointCloudRenderer.load(element.firstChildElement("renderer"), QgsReadWriteContext())


said = []  # what QGIS logs while it reads: why a layer cannot be loaded
QgsApplication.messageLog().messageReceived.connect(lambda message, tag, level: said.append([tag, message]))
project = QgsProject.instance()
canvas = QgsMapCanvas()
project.readProject.connect(canvas.readProject)  # as QGIS's window reads its map from the project
facts = {"version": Qgis.QGIS_VERSION, "pdal": "pdal" in providers}
facts["read"] = project.read(os.path.join(out, "project.qgz"))
facts["error"], facts["said"] = project.error(), said
dtm = next((l for l in project.mapLayers().values() if l.source() == os.path.join(out, "dtm.tif")), None)
facts["crs"] = {"valid": project.crs().isValid(), "authid": project.crs().authid(),
                "is_the_dtms": dtm is not None and project.crs() == dtm.crs()}
box = canvas.extent()
facts["canvas"] = [box.xMinimum(), box.yMinimum(), box.xMaximum(), box.yMaximum()]
facts["layers"] = []
for node in project.layerTreeRoot().findLayers():
    layer = node.layer()
    entry = {"name": node.name(), "source": os.path.relpath(layer.source(), out), "provider": layer.providerType(),
             "valid": layer.isValid(), "visible": node.isVisible(), "crs": layer.crs().authid(),
             "blend": int(layer.blendMode()), "group": node.parent().name()}
    if isinstance(layer, QgsPointCloudLayer) and not layer.isValid():  # its error() would crash QGIS 3.22
        entry["renderer"], entry["renderer_from"] = renderer(xml_renderer(layer.id())), "project XML"
        entry["error"] = f"no {layer.providerType()!r} provider" if layer.providerType() not in providers else "?"
    else:
        entry["renderer"], entry["error"] = renderer(layer.renderer()), error(layer)
    facts["layers"].append(entry)

facts["styles"] = {}
missing_index = os.path.join(out, "no-such-index", "ept.json")
for folder, _, files in os.walk(out):
    for qml in sorted(f for f in files if f.endswith(".qml")):
        stem = os.path.join(folder, qml[:-4])
        product = next(stem + s for s in (".tif", ".gpkg", ".laz", ".las") if os.path.exists(stem + s))
        if product.endswith(".tif"):
            layers = [QgsRasterLayer(product, qml, "gdal", QgsRasterLayer.LayerOptions(loadDefaultStyle=False))]
        elif product.endswith(".gpkg"):
            whole = QgsVectorLayer(product, qml, "ogr")  # held: its provider lives as long as it
            sublayers = whole.dataProvider().subLayers()
            names = [s.split(QgsDataProvider.sublayerSeparator())[1] for s in sublayers]
            options = QgsVectorLayer.LayerOptions(loadDefaultStyle=False)
            layers = [QgsVectorLayer(f"{product}|layername={n}", qml, "ogr", options) for n in names]
        elif "pdal" in providers:
            options = QgsPointCloudLayer.LayerOptions()
            options.loadDefaultStyle, options.skipIndexGeneration = False, True
            layers = [QgsPointCloudLayer(product, qml, "pdal", options)]
        else:  # no point cloud provider: a point cloud layer without data takes the style
            layers = [QgsPointCloudLayer(missing_index, qml, "ept")]
        for layer in layers:
            message, ok = layer.loadNamedStyle(os.path.join(folder, qml))
            key = os.path.relpath(layer.source(), out) if layer.isValid() else os.path.relpath(product, out)
            facts["styles"][key] = {"qml": os.path.relpath(os.path.join(folder, qml), out), "ok": ok,
                                    "message": message, "valid": layer.isValid(),
                                    "renderer": renderer(layer.renderer())}

# a product opened on its own takes the style beside it
alone = [QgsRasterLayer(os.path.join(out, name), name, "gdal") for name in ("dtm.tif", "hillshade.tif")]
alone.append(QgsVectorLayer(os.path.join(out, "contours.gpkg"), "contours.gpkg", "ogr"))
facts["defaults"] = {layer.name(): layer.renderer().type() for layer in alone}
print(json.dumps(facts))
"""


def _qgis_missing() -> str | None:
    """Why QGIS's Python bindings cannot be used here (None: they can)."""
    if not QGIS_PYTHON.exists():
        return f"{QGIS_PYTHON} not found"
    probe = subprocess.run([str(QGIS_PYTHON), "-c", "import qgis.core"], capture_output=True, text=True)
    return None if probe.returncode == 0 else f"{QGIS_PYTHON} cannot import qgis.core ({probe.stderr.strip()[-200:]})"


def _run(out: Path, *sets: str) -> Path:
    """configs/las.yaml run into *out*/out (the runs share a cache), with ``--set`` *sets*; the output folder."""
    args = ["run", str(CONFIG), "-q", "--set", f"output={out / 'out'}", "--set", f"cache={out.parent / 'cache'}"]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return out / "out"


def _probe(delivery: Path) -> dict:
    """What QGIS made of the project and the styles in *delivery* (:data:`PROBE`)."""
    env = {**os.environ, "QT_QPA_PLATFORM": "offscreen", "HOME": str(delivery.parent)}  # QGIS's settings there
    env.pop("PYTHONPATH", None)  # the system Python's own modules, not the virtualenv's
    proc = subprocess.run(
        [str(QGIS_PYTHON), "-c", PROBE, str(delivery)], env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    """A folder for the runs, once QGIS is known to be there."""
    missing = _qgis_missing()
    if missing:  # before the run: a test that cannot look at the result does not wait for it
        message = (
            f"QGIS's Python bindings are needed: {missing}; install them with: sudo apt-get install -y python3-qgis"
        )
        if in_ci():
            pytest.fail(f"CI is set and {message}", pytrace=False)
        pytest.skip(message)
    return tmp_path_factory.mktemp("qgis-runs")


@pytest.fixture(scope="module")
def delivery(runs) -> Path:
    return _run(runs / "merged")


@pytest.fixture(scope="module")
def qgis(delivery) -> dict:
    return _probe(delivery)


def _layers(qgis: dict) -> dict[str, dict]:
    return {layer["source"]: layer for layer in qgis["layers"]}


def _dtm_range(delivery: Path) -> tuple[float, float]:
    with rasterio.open(delivery / "dtm.tif") as ds:
        dtm = ds.read(1, masked=True)
    return float(dtm.min()), float(dtm.max())


def test_the_project_opens_every_product_in_the_products_crs(qgis, delivery):
    assert qgis["read"], qgis["error"]
    expected = {p.name for p in delivery.glob("*.tif")} | {"points.laz"}
    for gpkg in delivery.glob("*.gpkg"):
        expected |= {f"{gpkg.name}|layername={name}" for name, _ in pyogrio.list_layers(gpkg)}
    layers = _layers(qgis)
    assert set(layers) == expected
    assert qgis["crs"] == {"valid": True, "authid": "EPSG:25830", "is_the_dtms": True}
    assert {layer["crs"] for layer in layers.values()} == {"EPSG:25830"}
    x0, y0, x1, y1 = qgis["canvas"]  # the map opens on the survey
    with rasterio.open(delivery / "dtm.tif") as ds:
        b = ds.bounds
    assert x0 <= b.left and x1 >= b.right and y0 <= b.bottom and y1 >= b.top and (x1 - x0) < 2 * (b.right - b.left)


def test_every_layer_is_valid(qgis):
    bad = {s: layer["error"] for s, layer in _layers(qgis).items() if not layer["valid"]}
    if not qgis["pdal"]:  # this QGIS has no point cloud provider: only the points may be unavailable
        assert _layers(qgis)["points.laz"]["provider"] == "pdal"
        bad.pop("points.laz", None)
    assert bad == {}


def test_qgis_says_nothing_but_that_it_has_no_point_cloud_provider(qgis):
    expected = ("Invalid data provider pdal", "unavailable layers found", " * ./points.laz", "/no-such-index/")
    assert [said for said in qgis["said"] if not any(e in said[1] for e in expected)] == []


def test_the_dtm_is_coloured_by_its_heights_over_the_grey_hillshade(qgis, delivery):
    layers = _layers(qgis)
    dtm, shade = layers["dtm.tif"], layers["hillshade.tif"]
    assert dtm["renderer"]["type"] == "singlebandpseudocolor"
    lo, hi = _dtm_range(delivery)
    assert (dtm["renderer"]["min"], dtm["renderer"]["max"]) == (lo, hi)
    assert dtm["renderer"]["items"][0][0] == lo and dtm["renderer"]["items"][-1][0] == hi
    assert dtm["blend"] == 13  # QPainter's CompositionMode_Multiply: the hillshade shows through
    assert shade["renderer"]["type"] == "singlebandgray"
    with rasterio.open(delivery / "hillshade.tif") as ds:
        grey = ds.read(1, masked=True)
    assert (shade["renderer"]["min"], shade["renderer"]["max"]) == (float(grey.min()), float(grey.max()))
    order = [layer["source"] for layer in qgis["layers"]]
    assert order.index("dtm.tif") == order.index("hillshade.tif") - 1  # drawn right over it
    assert dtm["visible"] and shade["visible"] and not layers["dsm.tif"]["visible"]
    for name in ("dsm.tif", "ndsm.tif", "density.tif", "canopy_height.tif"):
        assert layers[name]["renderer"]["type"] == "singlebandpseudocolor", name


def test_points_are_coloured_by_asprs_class(qgis):
    points = _layers(qgis)["points.laz"]
    classes = points["renderer"]["classes"]
    assert points["renderer"]["type"] == "classified"
    assert classes["2"] == [list(glossary.CLASS_COLOURS[2]), True]
    assert classes["6"] == [list(glossary.CLASS_COLOURS[6]), True]
    assert classes["7"][1] is False and classes["18"][1] is False


def test_contours_have_thicker_index_lines_every_fifth_interval(qgis):
    rules = _layers(qgis)["contours.gpkg|layername=contours"]["renderer"]
    assert rules["type"] == "RuleRenderer"
    (index, _, thick), (other, is_else, thin) = rules["rules"]
    assert is_else and thick > thin
    assert index == 'abs("elevation" / 5.0 - round("elevation" / 5.0)) < 1e-06'  # stages.contours.interval: 1 m


def test_vectors_are_styled(qgis):
    layers = _layers(qgis)
    water = layers["water.gpkg|layername=water_bodies"]["renderer"]
    assert water == {"type": "singleSymbol", "colour": list(glossary.CLASS_COLOURS[glossary.WATER])}
    assert layers["buildings.gpkg|layername=buildings"]["renderer"]["colour"] == list(glossary.CLASS_COLOURS[6])
    for name in ("breaklines.gpkg|layername=breaklines", "survey.gpkg|layername=boundary"):
        assert layers[name]["renderer"]["type"] == "singleSymbol", name
    assert not layers["survey.gpkg|layername=input_files"]["visible"]


def test_every_style_loads_on_a_fresh_layer(qgis, delivery):
    styles = qgis["styles"]
    assert {s["qml"] for s in styles.values()} == {p.name for p in delivery.glob("*.qml")}
    assert {s["qml"] for s in styles.values()} == {
        f"{p.stem}.qml" for p in delivery.iterdir() if p.suffix in (".tif", ".gpkg", ".laz")
    }
    assert {k: s["message"] for k, s in styles.items() if not s["ok"]} == {}
    dtm = styles["dtm.tif"]["renderer"]
    assert dtm["type"] == "singlebandpseudocolor" and (dtm["min"], dtm["max"]) == _dtm_range(delivery)
    assert styles["hillshade.tif"]["renderer"]["type"] == "singlebandgray"
    assert styles["contours.gpkg|layername=contours"]["renderer"]["type"] == "RuleRenderer"
    assert styles["points.laz"]["renderer"]["classes"]["2"][0] == list(glossary.CLASS_COLOURS[2])
    # survey.qml, the boundary's outline, suits both layers of survey.gpkg
    assert styles["survey.gpkg|layername=input_files"]["ok"]


def test_a_product_opened_alone_takes_the_style_beside_it(qgis):
    assert qgis["defaults"] == {
        "dtm.tif": "singlebandpseudocolor",
        "hillshade.tif": "singlebandgray",
        "contours.gpkg": "RuleRenderer",
    }


def test_per_input_files_are_layers_of_a_group_and_the_vpc_is_not(runs, delivery):
    """QGIS 3.22 predates virtual point clouds (points.vpc): the project lists the per-input files instead."""
    out = _run(runs / "per_input", "stages.export_las.files=per_input")  # the first run's cache: only the end reruns
    qgis = _probe(out)
    layers = _layers(qgis)
    assert "points.laz" not in layers and not [s for s in layers if s.startswith("points.vpc")]
    points = layers["points/sample.laz"]
    assert points["group"] == "points" and not points["visible"]
    assert points["renderer"]["classes"]["2"] == [list(glossary.CLASS_COLOURS[2]), True]
    assert not [s for s, layer in layers.items() if not layer["valid"] and s != "points/sample.laz"]
    assert {s["qml"] for s in qgis["styles"].values()} == {p.name for p in out.glob("*.qml")}
    assert not list((out / "points").glob("*.qml"))  # styled in the project only
