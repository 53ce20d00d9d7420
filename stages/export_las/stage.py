"""Stage ``export_las``: the classified point cloud as ``points.laz`` (or ``.las``).

LAS 1.4, point format 6, ASPRS classes, ``point_source_id`` = flight strip,
GPS time, the CRS as WKT.  Copied in chunks, so memory does not grow with the
survey.  With ``files: per_input``, one file per input LAS/LAZ file
instead, ``points/<its name>`` with its points (:func:`output_name`), and
``points.vpc``, a virtual point cloud over them (:mod:`stages.export_las.vpc`).
With ``copc: true`` also ``points.copc.laz``
(:mod:`stages.export_las.copc`; docs/stages/export_las.md).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import ClassVar, Literal

import laspy
from pydantic import Field

from lidar.clouds import open_las_writer, progress_chunk
from lidar.input_files import read_input_files_csv
from pipeline.errors import ConfigError, InputDataError, PipelineError
from pipeline.stage import Stage, StageContext, StageIO, StageParams
from stages.export_las.copc import write_copc
from stages.export_las.vpc import write_vpc


class ExportLasParams(StageParams):
    compress: bool = Field(True, description="write LAZ (points.laz); false writes LAS (points.las)")
    chunk_size: int = Field(1_000_000, ge=1000, description="points copied at a time")
    files: Literal["merged", "per_input"] = Field(
        "merged",
        description="merged: one points.laz (or .las, see compress); per_input: points/<input file name>, one "
        "file per input LAS/LAZ file with its points in their order, .laz or .las as the input was (COPC inputs "
        "as <name>.laz; compress does not apply); input.format las only",
    )
    copc: bool = Field(
        False,
        description="also write points.copc.laz, a Cloud Optimized Point Cloud 1.0 (octree-ordered LAZ that QGIS "
        "and web viewers stream); off by default (it holds the coordinates of every point in memory)",
    )


class ExportLas(Stage, name="export_las", version="3", params=ExportLasParams):
    """classified points to points.laz."""

    inputs = ("points_objects",)
    outputs: ClassVar = {"points_export": "points.laz"}
    products: ClassVar = {"points_export": "points.laz"}

    def declare(self, params, config) -> StageIO:
        inputs = tuple(self.inputs)
        if params.files == "per_input":
            if params.enabled:
                check_per_input(config)
            outputs = {"points_per_input": "points", "points_vpc": "points.vpc"}
            inputs += ("input_files",)
        else:
            outputs = {"points_export": "points.laz" if params.compress else "points.las"}
        if params.copc:
            outputs["points_copc"] = "points.copc.laz"
        return StageIO(inputs, outputs, dict(outputs))

    def run(self, ctx: StageContext[ExportLasParams]) -> None:
        src_path = ctx.inputs["points_objects"]
        if "points_per_input" in ctx.outputs:
            folder = ctx.outputs["points_per_input"]
            write_per_input(ctx, src_path, folder)
            write_vpc(ctx.outputs["points_vpc"], sorted(folder.iterdir()))
            if "points_copc" in ctx.outputs:
                write_copc_product(ctx, src_path, ctx.outputs["points_copc"])
            return
        dst_path = ctx.outputs["points_export"]
        # LazrsParallel: chunks of 50,000 points compressed on every core (same format).
        backend = laspy.LazBackend.LazrsParallel if ctx.params.compress else None
        with laspy.open(str(src_path)) as reader:
            header = reader.header
            with (
                open_las_writer(dst_path, header, do_compress=ctx.params.compress, laz_backend=backend) as writer,
                ctx.progress(header.point_count, "writing", unit="pt") as bar,
            ):
                # smaller chunks in a small file, for the progress: the same file (the LAZ writer makes its own)
                for chunk in reader.chunk_iterator(progress_chunk(header.point_count, ctx.params.chunk_size)):
                    writer.write_points(chunk)
                    bar.update(len(chunk))
            ctx.metrics.update(points=int(header.point_count), compressed=ctx.params.compress)
        if "points_copc" in ctx.outputs:
            write_copc_product(ctx, src_path, ctx.outputs["points_copc"])


def write_copc_product(ctx: StageContext[ExportLasParams], src_path: Path, dst_path: Path) -> None:
    """``points.copc.laz`` from the classified points (:mod:`stages.export_las.copc`), its octree in the metrics."""
    try:
        tree = write_copc(src_path, dst_path)
    except ValueError as exc:
        raise InputDataError(
            f"points.copc.laz cannot be written: {exc}; or set stages.export_las.copc: false."
        ) from None
    ctx.metrics["copc"] = tree
    ctx.log.info("points.copc.laz: %d octree nodes on %d levels", tree["nodes"], tree["levels"])


def output_name(path: Path) -> str:
    """The name of an input file's classified points: its own, a COPC file's ``.copc`` left out.

    ``tile_3.laz`` -> ``tile_3.laz``, ``tile_3.LAS`` -> ``tile_3.LAS``,
    ``tile_3.copc.laz`` -> ``tile_3.laz`` (the file written is LAZ, not COPC).
    """
    name = path.name
    if name.lower().endswith(".copc.laz"):
        return name[: -len(".copc.laz")] + name[-len(".laz") :]
    return name


def check_per_input(config) -> None:
    """Refuse ``files: per_input`` without LAS inputs, or with two inputs that would write one name (exit 2)."""
    block = config.input
    if block.format != "las":
        raise ConfigError(
            f"stages.export_las.files: per_input writes one file per input LAS/LAZ file, and input.format "
            f"{block.format} has none (its points come from a scanner stream); set files: merged."
        )
    seen: dict[str, Path] = {}
    files: set[tuple[int, int]] = set()
    for path in block.paths:
        st = os.stat(path)
        if (st.st_dev, st.st_ino) in files:
            continue  # the same file listed twice: read once (parse warns)
        files.add((st.st_dev, st.st_ino))
        name = output_name(path)
        if name in seen:
            raise ConfigError(
                f"stages.export_las.files: per_input would write both {seen[name]} and {path} as points/{name}; "
                "rename one of them, or set files: merged."
            )
        seen[name] = path


def write_per_input(ctx: StageContext[ExportLasParams], src_path: Path, folder: Path) -> None:
    """``points/<input name>``: the classified cloud cut into its input files, by parse's kept counts, in order.

    Each file holds the points parse kept from that input (those outside
    its header's bounds are left out: ``qc/input_files.csv``), in their
    order, in the product's records, header rules and CRS (its bounds and
    counts its own); LAZ when the input's name ends in ``.laz``.
    """
    rows = read_input_files_csv(ctx.inputs["input_files"])
    kept = [int(r["points_kept"]) for r in rows]
    folder.mkdir()
    with laspy.open(str(src_path)) as reader:
        header = reader.header
        if sum(kept) != int(header.point_count):
            raise PipelineError(
                f"the classified cloud holds {int(header.point_count)} points and parse kept {sum(kept)} from "
                "the input files: they cannot be told apart (a stage added or removed points)."
            )
        written = {}
        with ctx.progress(header.point_count, "writing per input file", unit="pt") as bar:
            for row, n in zip(rows, kept, strict=True):
                name = output_name(Path(row["path"]))
                laz = name.lower().endswith(".laz")
                backend = laspy.LazBackend.LazrsParallel if laz else None
                with open_las_writer(folder / name, header, do_compress=laz, laz_backend=backend) as writer:
                    left = n
                    while left:
                        chunk = reader.read_points(min(progress_chunk(header.point_count, ctx.params.chunk_size), left))
                        if not len(chunk):
                            raise PipelineError(f"{src_path} ended {left} points before parse's count for {name}.")
                        writer.write_points(chunk)
                        left -= len(chunk)
                        bar.update(len(chunk))
                written[name] = n
    ctx.metrics.update(points=int(header.point_count), files=len(written), points_per_file=written)
    ctx.log.info("%d points in %d files under points/", int(header.point_count), len(written))
