"""Stage ``parse``: read the survey's input files into the common intermediates.

Its parameters are the configuration's ``input`` block; ``input.format``
chooses the reader.  Formats available in this version:

- ``las`` (SPEC 3.D): georeferenced LAS/LAZ.  Output: the point cloud
  (``points_georef``), already in the output CRS, so georeferencing does not
  apply.

The raw formats of SPEC 3.A-3.C (``ldmrs_mtig``, ``lmsq_nmea``, ``lmsq_sbet``)
arrive with the simulator and georeferencing work; until then the
configuration rejects them with the list of formats available.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field, field_validator

from pipeline.config import InputFile, StrictModel
from pipeline.stage import Stage, StageIO
from stages.io import write_cloud


def _check_crs(value: str | None) -> str | None:
    if value is None or value == "auto-utm":
        return value
    import pyproj

    try:
        pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError:
        raise ValueError(f"'{value}' is not a CRS pyproj knows (use e.g. EPSG:25830 or auto-utm)") from None
    return value


class LasInput(StrictModel):
    """Already georeferenced LAS/LAZ files (SPEC 3.D)."""

    format: Literal["las"] = Field(description="input format; this version reads: las")
    paths: Annotated[list[InputFile], Field(min_length=1, description="LAS/LAZ files, relative to the config file")]
    crs: str | None = Field(
        None, description="CRS of input files whose header has none (a header CRS always wins); e.g. EPSG:25830"
    )
    chunk_size: int = Field(1_000_000, ge=1000, description="points read at a time")

    @field_validator("crs")
    @classmethod
    def _known_crs(cls, value: str | None) -> str | None:
        return _check_crs(value)


#: The ``input`` block: one model per format, chosen by ``format``.
InputConfig = Annotated[LasInput, Field(discriminator="format")]


class Parse(Stage):
    """Read the configured input into the pipeline's intermediates."""

    name = "parse"
    version = "1"
    Params = LasInput
    config_path = "input"
    can_disable = False
    config_keys = ("crs",)
    description = "read the input files (format from input.format)"
    outputs: ClassVar = {"points_georef": "points.las"}

    def is_enabled(self, params, config) -> bool:
        return True

    def declare(self, params, config) -> StageIO:
        return StageIO(outputs={"points_georef": "points.las"})

    def external_files(self, params, config) -> list[Path]:
        return list(params.paths)

    def run(self, ctx) -> None:
        import pyproj

        from stages.readers.las import count_points, read_las_files

        params = ctx.params
        total = count_points(list(params.paths))
        assign = pyproj.CRS.from_user_input(params.crs) if params.crs else None
        with ctx.progress(total, "reading LAS/LAZ", unit="pt") as bar:
            las, report = read_las_files(
                list(params.paths),
                crs_setting=ctx.config.crs,
                assign_crs=assign,
                chunk_size=params.chunk_size,
                progress=bar,
            )
        if report.gps_time_missing:
            ctx.log.warning("no GPS time in %s: gps_time set to 0", ", ".join(report.gps_time_missing))
        crs = las.header.parse_crs()
        ctx.metrics.update(
            points_read=int(sum(report.points.values())),
            points_per_file=report.points,
            crs=crs.name,
            crs_epsg=crs.to_epsg(),
            crs_source=report.crs_source,
            strips=[int(s) for s in np.unique(np.asarray(las.point_source_id))],
        )
        ctx.log.info("%d points in %s", ctx.metrics["points_read"], crs.name)
        write_cloud(las, ctx.outputs["points_georef"])
