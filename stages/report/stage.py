"""Stage ``report``: ``report.html``, one self-contained QC page a reviewer signs off.

Everything is inside the file (maps as inline SVG, CSS inline), so it opens
offline, can be mailed, and is archived with the products.  Figures are in
the survey's units (the CRS's) unless a heading says metres; accuracy figures
are in metres whatever the CRS.  The page is a list of sections
(:func:`~stages.report.page.build_report`); the acceptance against
``stages.report.specification`` (:mod:`~stages.report.acceptance`) is
also written to ``qc/acceptance.json``.  What each section shows:
``docs/stages/report.md``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np
import rasterio
from pydantic import Field

from lidar.clouds import cloud_info
from lidar.rasters import read_raster
from lidar.water_bodies import read_water_bodies
from pipeline.runner import FAILED_CHECKS
from pipeline.stage import Stage, StageContext, StageIO, StageParams, get_dotted
from stages.report.acceptance import DEFAULT_SPECIFICATION, SPECIFICATIONS
from stages.report.cloud import las_info, summarise_cloud
from stages.report.inputs import ReportInputs, checkpoint_rows, read_flight_lines
from stages.report.maps import MapFrame
from stages.report.markup import unit_symbol
from stages.report.page import build_report
from stages.report.sections import failed_checks


class ReportParams(StageParams):
    max_image_size: int = Field(1200, ge=100, description="largest side of the rasters drawn in the maps, cells")
    specification: Literal[tuple(SPECIFICATIONS)] = Field(  # type: ignore[valid-type]
        DEFAULT_SPECIFICATION,
        description="specification the survey is accepted against (qc/acceptance.json, the report's PASS/FAIL "
        "table): usgs-lbs-ql2 (default: the 3DEP baseline most public lidar contracts cite), usgs-lbs-ql1, "
        "asprs-2023-10cm, or none (measured values only)",
    )


def _enabled(config, name: str) -> bool:
    params = get_dotted(config, f"stages.{name}")
    return params is not None and bool(getattr(params, "enabled", True))


class Report(Stage, name="report", version="17", params=ReportParams):
    """self-contained QC page (report.html) and acceptance (qc/acceptance.json)."""

    inputs = ("dtm", "density", "points_objects")
    outputs: ClassVar = {"report": "report.html", "acceptance": "acceptance.json"}
    products: ClassVar = {"report": "report.html", "acceptance": "qc/acceptance.json"}
    reads_metrics = True
    config_keys = ("name", "input", "stages.accuracy", "stages.export_las")  # export_las: the delivered file's name

    def declare(self, params, config) -> StageIO:
        inputs = list(self.inputs)
        if _enabled(config, "strip_adjust"):
            inputs += ["strip_corrections", "strip_difference_before", "strip_difference_after"]
        water, raster = get_dotted(config, "stages.classify_water"), get_dotted(config, "stages.rasterize")
        if water is not None and water.enabled and water.bodies.enabled and raster.hydro_flatten:
            inputs.append("water_bodies")  # the flattened bodies, to judge the DTM flat in them
        geo = get_dotted(config, "stages.georeference")
        if config.input.format != "las":
            inputs.append("trajectory_lines")
            if geo is not None and geo.uncertainty is not None:
                inputs.append("dtm_uncertainty")
        return StageIO(tuple(inputs), dict(self.outputs), dict(self.products))

    def external_files(self, params, config) -> list[Path]:
        acc = get_dotted(config, "stages.accuracy")
        return [acc.checkpoints] if acc is not None and acc.enabled and acc.checkpoints else []

    def run(self, ctx: StageContext[ReportParams]) -> None:
        data = read_inputs(ctx)
        page, verdict = build_report(
            name=ctx.setting("name") or "survey",
            metrics=ctx.upstream_metrics,
            data=data,
            max_size=ctx.params.max_image_size,
        )
        ctx.outputs["report"].write_text(page, encoding="utf-8")
        ctx.outputs["acceptance"].write_text(json.dumps(verdict, indent=2, default=float) + "\n")
        ctx.metrics.update(bytes=len(page), images=page.count("<figure>"), acceptance=verdict["status"])
        failed = failed_checks(verdict)
        ctx.metrics[FAILED_CHECKS] = failed
        if failed:
            ctx.log.warning("acceptance against %s: FAIL, %d of its checks", verdict["title"], len(failed))
        else:
            ctx.log.info("acceptance against %s: %s", verdict["title"], verdict["status"])


def read_inputs(ctx: StageContext[ReportParams]) -> ReportInputs:
    """What the page draws: the DTM, the density, the classified cloud's summary, and the optional inputs the
    survey has (strip adjustment, DTM uncertainty, flight lines, check points)."""
    dtm, transform, _, resolution = read_raster(ctx.inputs["dtm"])
    density, _, _, _ = read_raster(ctx.inputs["density"])
    with ctx.progress(cloud_info(ctx.inputs["points_objects"]).count, "points summarised", unit="pt") as bar:
        cloud = summarise_cloud(
            ctx.inputs["points_objects"],
            origin=(transform.c, transform.f),
            resolution=resolution,
            shape=dtm.shape,
            dtm=dtm,
            advance=bar.update,
        )
    if cloud.header:  # the cloud read is the classified intermediate; the row names the delivered product
        cloud.header["file"] = delivered_name(ctx.setting("stages.export_las"))
    hu = unit_symbol(cloud.units.horizontal_name)
    inp = ctx.setting("input")
    data = ReportInputs(
        dtm=dtm,
        density=density,
        frame=MapFrame(transform.c, transform.f, resolution, hu),
        cloud=cloud,
        input_files=input_files(inp),
        specification=ctx.params.specification,
    )
    data.dem_float_bits, data.dem_nodata = dem_format(ctx.inputs["dtm"])
    if inp.format == "las":
        data.input_info = [las_info(p) for p in inp.paths]
    if "strip_corrections" in ctx.inputs:
        data.corrections = json.loads(Path(ctx.inputs["strip_corrections"]).read_text())
        before, t, _, res = read_raster(ctx.inputs["strip_difference_before"])
        after, _, _, _ = read_raster(ctx.inputs["strip_difference_after"])
        data.differences = (before, after, MapFrame(t.c, t.f, res, hu))
    if "dtm_uncertainty" in ctx.inputs:
        data.uncertainty = read_raster(ctx.inputs["dtm_uncertainty"])[0]
    if "water_bodies" in ctx.inputs:
        data.water_bodies = read_water_bodies(Path(ctx.inputs["water_bodies"]), cloud.units)
    if "trajectory_lines" in ctx.inputs:
        data.trajectory = read_flight_lines(ctx.inputs["trajectory_lines"])
    acc = ctx.setting("stages.accuracy")
    if acc is not None and acc.enabled and acc.checkpoints and ctx.upstream_metrics.get("accuracy"):
        data.checkpoints = checkpoint_rows(acc.checkpoints, acc.land_cover_column, ctx.inputs["dtm"])
    return data


def dem_format(path: Path) -> tuple[int, float | None]:
    """The DEM's floating-point bits (0: not floating point) and its nodata value, as its GeoTIFF tags say."""
    with rasterio.open(path) as ds:
        dtype = np.dtype(ds.dtypes[0])
        return (dtype.itemsize * 8 if dtype.kind == "f" else 0), ds.nodata


def input_files(inp) -> list[tuple[str, str]]:
    """The survey's input files as (role, path): the point files, then the navigation files it names."""
    files = [("scanner / point file", str(p)) for p in inp.paths]
    files += [(k, str(getattr(inp, k))) for k in ("nmea", "ins", "sbet", "smrmsg") if getattr(inp, k, None)]
    return files


def delivered_name(export) -> str:
    """The delivered point cloud's name by ``stages.export_las`` (its settings; None when absent)."""
    if export is None or not export.enabled:
        return "not delivered (stages.export_las is off)"
    if export.files == "per_input":
        return "points/ (one file per input)"
    return "points.laz" if export.compress else "points.las"
