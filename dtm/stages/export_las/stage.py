"""Stage ``export_las``: the classified point cloud as ``points.laz`` (or ``.las``).

LAS 1.4, point format 6, ASPRS classes, ``point_source_id`` = flight strip,
GPS time, the CRS as WKT.  Copied in chunks, so memory does not grow with the
survey.  With ``copc: true`` also ``points.copc.laz``
(:mod:`dtm.stages.export_las.copc`; docs/stages/export_las.md).
"""

from __future__ import annotations

from pathlib import Path
from typing import ClassVar

from pydantic import Field

from pipeline.stage import Stage, StageContext, StageIO, StageParams


class ExportLasParams(StageParams):
    compress: bool = Field(True, description="write LAZ (points.laz); false writes LAS (points.las)")
    chunk_size: int = Field(1_000_000, ge=1000, description="points copied at a time")
    copc: bool = Field(
        False,
        description="also write points.copc.laz, a Cloud Optimized Point Cloud 1.0 (octree-ordered LAZ that QGIS "
        "and web viewers stream); off by default (it holds the coordinates of every point in memory)",
    )


class ExportLas(Stage, name="export_las", version="1", params=ExportLasParams):
    """classified points to points.laz."""

    inputs = ("points_classified",)
    outputs: ClassVar = {"points_export": "points.laz"}
    products: ClassVar = {"points_export": "points.laz"}

    def declare(self, params, config) -> StageIO:
        name = "points.laz" if params.compress else "points.las"
        outputs = {"points_export": name}
        if params.copc:
            outputs["points_copc"] = "points.copc.laz"
        return StageIO(self.inputs, outputs, dict(outputs))

    def run(self, ctx: StageContext[ExportLasParams]) -> None:
        import laspy

        from dtm.common.clouds import open_las_writer

        src_path = ctx.inputs["points_classified"]
        dst_path = ctx.outputs["points_export"]
        # LazrsParallel: chunks of 50,000 points compressed on every core (same format).
        backend = laspy.LazBackend.LazrsParallel if ctx.params.compress else None
        with laspy.open(str(src_path)) as reader:
            header = reader.header
            with (
                open_las_writer(dst_path, header, do_compress=ctx.params.compress, laz_backend=backend) as writer,
                ctx.progress(header.point_count, "writing", unit="pt") as bar,
            ):
                for chunk in reader.chunk_iterator(ctx.params.chunk_size):
                    writer.write_points(chunk)
                    bar.update(len(chunk))
            ctx.metrics.update(points=int(header.point_count), compressed=ctx.params.compress)
        if "points_copc" in ctx.outputs:
            write_copc_product(ctx, src_path, ctx.outputs["points_copc"])


def write_copc_product(ctx: StageContext[ExportLasParams], src_path: Path, dst_path: Path) -> None:
    """``points.copc.laz`` from the classified points (:mod:`dtm.stages.export_las.copc`), its octree in the metrics."""
    from dtm.stages.export_las.copc import write_copc
    from pipeline.errors import InputDataError

    try:
        tree = write_copc(src_path, dst_path)
    except ValueError as exc:
        raise InputDataError(
            f"points.copc.laz cannot be written: {exc}; or set stages.export_las.copc: false."
        ) from None
    ctx.metrics["copc"] = tree
    ctx.log.info("points.copc.laz: %d octree nodes on %d levels", tree["nodes"], tree["levels"])
