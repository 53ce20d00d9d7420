"""Stage ``qgis``: the delivery ready for QGIS, a ``.qml`` style beside each product and ``project.qgz``.

After the products: each raster and vector product gets its style beside
it, ``<stem>.qml`` (``dtm.qml`` beside ``dtm.tif``), which QGIS loads as the
layer's default style, and ``project.qgz`` opens them all styled, with
paths relative to it, in the products' CRS (the DTM's WKT).  Colour ramps
span each raster's own values, read here.  The XML is written with the
standard library, QGIS is not imported (:mod:`stages.qgis.styles`,
:mod:`stages.qgis.project`; the layers: :mod:`stages.qgis.layers`).
docs/stages/qgis.md.
"""

from __future__ import annotations

from pathlib import Path, PurePosixPath
from typing import ClassVar

import numpy as np
import pyogrio
import pyproj
import rasterio

from lidar.units import raster_units
from pipeline.runner import UNPUBLISHED
from pipeline.stage import Stage, StageContext, StageIO, StageParams, get_dotted
from stages.qgis.layers import point_layers, product_paths, raster_layer, style_name, vector_layers
from stages.qgis.project import Layer, project_document, qgz
from stages.qgis.styles import qml

#: Point files of the per-input delivery, by their suffix.
POINT_SUFFIXES = (".las", ".laz")


class QgisParams(StageParams):
    pass


def _enabled(config, name: str) -> bool:
    params = get_dotted(config, f"stages.{name}")
    return params is not None and bool(getattr(params, "enabled", True))


def styled_artifacts(config) -> list[str]:
    """The products the stages of *config* make that are styled, in the project's order (:data:`PRODUCT_PATHS`)."""
    on = {"dtm", "dsm", "ndsm", "density"}  # rasterize: this stage needs its DTM
    export = get_dotted(config, "stages.export_las")
    if _enabled(config, "export_las"):
        on.add("points_per_input" if export.files == "per_input" else "points_export")
    if _enabled(config, "footprints"):
        on |= {"survey_index", "buildings"}
        objects = get_dotted(config, "stages.classify_objects")
        if objects is not None and objects.enabled and objects.vegetation.enabled:
            on.add("canopy_height")
    water = get_dotted(config, "stages.classify_water")
    if water is not None and water.enabled and water.bodies.enabled:
        on |= {"water_bodies", "breaklines"}
    for name in ("contours", "hillshade"):
        if _enabled(config, name):
            on.add(name)
    if _enabled(config, "strip_adjust"):
        on |= {"strip_difference_before", "strip_difference_after"}
    if config.input.format != "las":
        on.add("trajectory_lines")
        if get_dotted(config, "stages.georeference.uncertainty") is not None:
            on.add("dtm_uncertainty")
    return [a for a in product_paths(True) if a in on]


def style_outputs(artifacts: list[str], compress: bool) -> dict[str, tuple[str, str]]:
    """Each style the stage writes: output name -> (its file in the workspace, its product path)."""
    paths = product_paths(compress)
    out = {}
    for artifact in artifacts:
        if artifact != "points_per_input":  # styled in the project only (no file of a known name)
            qml_path = style_name(paths[artifact])
            out[f"{artifact}_style"] = (PurePosixPath(qml_path).name, qml_path)
    return out


class Qgis(Stage, name="qgis", version="1", params=QgisParams):
    """a QGIS style beside each product (dtm.qml beside dtm.tif) and a project of them all (project.qgz)."""

    inputs = ("dtm",)
    outputs: ClassVar = {"project": "project.qgz"}
    products: ClassVar = {"project": "project.qgz"}
    config_keys = ("name", "stages.contours.interval", "stages.export_las.compress")

    def declare(self, params, config) -> StageIO:
        artifacts = styled_artifacts(config)
        compress = get_dotted(config, "stages.export_las.compress") is not False
        styles = style_outputs(artifacts, compress)
        outputs = {**self.outputs, **{k: name for k, (name, _) in styles.items()}}
        products = {**self.products, **{k: path for k, (_, path) in styles.items()}}
        return StageIO(tuple(artifacts), outputs, products)

    def run(self, ctx: StageContext[QgisParams]) -> None:
        crs_wkt, extent, metres_per_unit = _frame(ctx.inputs["dtm"])
        layers = []
        for artifact, path in product_paths(ctx.setting("stages.export_las.compress")).items():
            if artifact in ctx.inputs:
                found = _layers(ctx, artifact, path, metres_per_unit)
                _write_style(ctx, artifact, found)
                layers += found
        title = ctx.setting("name") or "survey"
        ctx.outputs["project"].write_bytes(qgz(project_document(layers, title=title, crs_wkt=crs_wkt, extent=extent)))
        styles = len(ctx.outputs) - 1 - len(ctx.metrics.get(UNPUBLISHED, []))
        ctx.metrics.update(layers=[layer.name for layer in layers], styles=styles)
        ctx.log.info("project.qgz: %d layers; %d styles beside the products", len(layers), styles)


def _write_style(ctx: StageContext[QgisParams], artifact: str, layers: list[Layer]) -> None:
    """The product's ``.qml``: its first layer's style; not published when the product has no layer to draw."""
    name = f"{artifact}_style"
    if name not in ctx.outputs:
        return  # the per-input points: styled in the project only
    ctx.outputs[name].write_bytes(qml(layers[0].style if layers else []))
    if not layers:
        ctx.metrics.setdefault(UNPUBLISHED, []).append(name)


def _frame(dtm: Path) -> tuple[str, tuple[float, float, float, float], float]:
    """The DTM's CRS as WKT, its extent, and metres per unit of its heights."""
    with rasterio.open(dtm) as ds:
        crs = pyproj.CRS.from_user_input(ds.crs.to_wkt())
        return crs.to_wkt(), tuple(ds.bounds), raster_units(ds.crs).vertical


def _layers(ctx: StageContext[QgisParams], artifact: str, path: str, metres_per_unit: float) -> list[Layer]:
    """The project's layers of one product (none for a raster without a value: nothing to draw)."""
    source = ctx.inputs[artifact]
    if artifact.startswith("points"):
        files = (
            sorted(p.name for p in source.iterdir() if p.suffix.lower() in POINT_SUFFIXES) if source.is_dir() else []
        )
        return point_layers(artifact, path, files)
    if path.endswith(".gpkg"):
        tables = [(str(name), str(geometry)) for name, geometry in pyogrio.list_layers(source)]
        return vector_layers(path, tables, ctx.setting("stages.contours.interval"), metres_per_unit)
    span = value_range(source)
    if span is None:
        ctx.log.info("%s has no value: left out of the project", path)
        return []
    return [raster_layer(artifact, path, *span)]


def value_range(path: Path) -> tuple[float, float] | None:
    """The lowest and highest value of a raster's band 1 (nodata and NaN left out), block by block; None if none."""
    lo, hi = np.inf, -np.inf
    with rasterio.open(path) as ds:
        for _, window in ds.block_windows(1):
            band = ds.read(1, window=window, masked=True)
            values = band.compressed()
            values = values[np.isfinite(values)]
            if values.size:
                lo, hi = min(lo, float(values.min())), max(hi, float(values.max()))
    return (lo, hi) if lo <= hi else None
