"""A QGIS project (``.qgs`` inside a ``.qgz``) of styled layers, written with the standard library.

The project holds what QGIS 3.22 needs to open the layers as styled: each
layer's source relative to the project (``./dtm.tif``), its provider and
style (:mod:`stages.qgis.styles`), the layer tree (visibility, groups), the
project's CRS as WKT and the map's first extent.  QGIS fills in everything
else with its defaults.  The ``.qgz`` is a ZIP of the ``.qgs`` with fixed
times, so the same layers make the same bytes.
"""

from __future__ import annotations

import hashlib
import io
import re
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from xml.etree import ElementTree as ET

from stages.qgis.styles import QGIS_VERSION, document

#: The ``.qgs`` file inside a ``.qgz``.
QGS_NAME = "project.qgs"


@dataclass(frozen=True)
class Layer:
    """One layer of the project: *source* relative to the project's folder (``points/a.laz``, ``survey.gpkg``).

    ``kind``: ``raster``, ``vector`` or ``point-cloud``; ``provider``:
    ``gdal``, ``ogr`` or ``pdal``; ``table``: the GeoPackage layer;
    ``geometry``: a vector layer's (``Line``, ``Polygon``); ``group``: the
    layer tree group it is in (None: the top).
    """

    name: str
    kind: str
    provider: str
    source: str
    style: list[ET.Element] = field(default_factory=list)
    visible: bool = True
    table: str | None = None
    geometry: str | None = None
    group: str | None = None

    @property
    def id(self) -> str:
        """The layer's id: a word of its name and a digest of its source, as QGIS makes them (``dtm_7d1c0e5a``)."""
        word = re.sub(r"\W+", "_", self.name).strip("_") or "layer"
        return f"{word}_{hashlib.sha256(self.datasource.encode()).hexdigest()[:8]}"

    @property
    def datasource(self) -> str:
        """The source as QGIS stores it: relative (``./``), a GeoPackage's layer after ``|layername=``."""
        path = "./" + self.source
        return f"{path}|layername={self.table}" if self.table else path


def _spatialrefsys(parent: ET.Element, wkt: str) -> None:
    ET.SubElement(ET.SubElement(parent, "spatialrefsys"), "wkt").text = wkt


def _checked(visible: bool) -> str:
    return "Qt::Checked" if visible else "Qt::Unchecked"


def _layer_tree(root: ET.Element, layers: Sequence[Layer]) -> None:
    """The legend: layers top to bottom as listed, each group where its first layer is."""
    tree = ET.SubElement(root, "layer-tree-group")
    groups: dict[str, ET.Element] = {}
    for layer in layers:
        parent = tree
        if layer.group is not None:
            if layer.group not in groups:
                visible = any(other.visible for other in layers if other.group == layer.group)
                groups[layer.group] = ET.SubElement(
                    tree, "layer-tree-group", name=layer.group, checked=_checked(visible), expanded="1"
                )
            parent = groups[layer.group]
        ET.SubElement(
            parent,
            "layer-tree-layer",
            id=layer.id,
            name=layer.name,
            source=layer.datasource,
            providerKey=layer.provider,
            checked=_checked(layer.visible),
            expanded="1",
        )


def _map_layer(parent: ET.Element, layer: Layer, crs_wkt: str) -> None:
    element = ET.SubElement(parent, "maplayer", type=layer.kind)
    if layer.geometry:
        element.set("geometry", layer.geometry)
    ET.SubElement(element, "id").text = layer.id
    ET.SubElement(element, "datasource").text = layer.datasource
    ET.SubElement(element, "layername").text = layer.name
    _spatialrefsys(ET.SubElement(element, "srs"), crs_wkt)  # without it QGIS gives the layer no CRS
    provider = ET.SubElement(element, "provider")
    provider.text = layer.provider
    if layer.kind == "vector":
        provider.set("encoding", "UTF-8")
    element.extend(layer.style)


def project_document(
    layers: Sequence[Layer], *, title: str, crs_wkt: str, extent: tuple[float, float, float, float]
) -> bytes:
    """The ``.qgs`` of *layers* (top to bottom), all in the CRS *crs_wkt*, the map on *extent* (x0, y0, x1, y1)."""
    root = ET.Element("qgis", projectname=title, version=QGIS_VERSION)
    ET.SubElement(root, "homePath", path="")
    ET.SubElement(root, "title").text = title
    _spatialrefsys(ET.SubElement(root, "projectCrs"), crs_wkt)
    _layer_tree(root, layers)
    canvas = ET.SubElement(root, "mapcanvas", name="theMapCanvas", annotationsVisible="1")
    box = ET.SubElement(canvas, "extent")
    for tag, value in zip(("xmin", "ymin", "xmax", "ymax"), extent, strict=True):
        ET.SubElement(box, tag).text = repr(float(value))
    ET.SubElement(canvas, "rotation").text = "0"
    _spatialrefsys(ET.SubElement(canvas, "destinationsrs"), crs_wkt)
    project_layers = ET.SubElement(root, "projectlayers")
    for layer in layers:
        _map_layer(project_layers, layer, crs_wkt)
    order = ET.SubElement(root, "layerorder")
    for layer in layers:
        ET.SubElement(order, "layer", id=layer.id)
    properties = ET.SubElement(root, "properties")
    ET.SubElement(ET.SubElement(properties, "Paths"), "Absolute", type="bool").text = "false"
    # without it QGIS reads no project CRS
    ET.SubElement(ET.SubElement(properties, "SpatialRefSys"), "ProjectionsEnabled", type="int").text = "1"
    return document(root)


def qgz(qgs: bytes) -> bytes:
    """A ``.qgz``: a ZIP holding *qgs* as :data:`QGS_NAME`, dated 1980-01-01 (the same bytes every run)."""
    info = zipfile.ZipInfo(QGS_NAME, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w") as archive:
        archive.writestr(info, qgs)
    return out.getvalue()
