"""Stage ``accuracy``: the DTM against check points and a truth raster, in ``accuracy.json``.

Runs when ``stages.accuracy.checkpoints`` (a CSV of surveyed points) or
``stages.accuracy.truth_dtm`` (a raster of the true terrain) names a file;
``pipeline evaluate dtm`` does the same from the command line.  The figures
are :mod:`stages.accuracy.vertical`'s (ASPRS NVA and VVA at the check
points; RMS and the share of cells far off against the truth, by relief and
land cover).  The check-point format and the reasons for each figure:
``docs/stages/accuracy.md``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import ClassVar

from pydantic import Field, model_validator
from rasterio.errors import RasterioError

from lidar.checkpoints import LAND_COVER_COLUMN, checkpoint_errors, read_checkpoints
from pipeline.config import InputFile
from pipeline.errors import InputDataError
from pipeline.stage import Stage, StageContext, StageParams
from stages.accuracy.vertical import land_cover_on_dtm_cells, truth_accuracy, truth_on_dtm_cells, vertical_accuracy


class AccuracyParams(StageParams):
    checkpoints: InputFile | None = Field(
        None, description="CSV of check points (x, y, z[, land_cover]); none = no check"
    )
    truth_dtm: InputFile | None = Field(
        None,
        description="raster of the true terrain (a simulated survey's truth/terrain.tif), compared with the DTM "
        "at every cell (bilinear onto the DTM's cells); none = no such check",
    )
    truth_land_cover: InputFile | None = Field(
        None,
        description="raster of land-cover codes (ASPRS class numbers: 2 ground, 5 vegetation, 6 building, 9 water, "
        "17 bridge deck) for the truth_dtm figures by land cover (nearest cell onto the DTM's); none = not split",
    )
    land_cover_column: str = Field(LAND_COVER_COLUMN, description="name of the land-cover column in the check points")
    vegetated: list[str] = Field(["vegetated"], description="land-cover values counted as vegetated (for VVA)")

    @model_validator(mode="after")
    def _land_cover_needs_truth(self):
        if self.truth_land_cover is not None and self.truth_dtm is None:
            raise ValueError("truth_land_cover splits the truth_dtm figures: set truth_dtm too")
        return self


class Accuracy(Stage, name="accuracy", version="5", params=AccuracyParams):
    """DTM vertical accuracy at check points and against a truth raster (runs when either is set)."""

    inputs = ("dtm",)
    outputs: ClassVar = {"accuracy": "accuracy.json"}
    products: ClassVar = {"accuracy": "accuracy.json"}

    def is_enabled(self, params, config) -> bool:
        return params.enabled and (params.checkpoints is not None or params.truth_dtm is not None)

    def external_files(self, params, config) -> list[Path]:
        return [f for f in (params.checkpoints, params.truth_dtm, params.truth_land_cover) if f is not None]

    def run(self, ctx: StageContext[AccuracyParams]) -> None:
        p = ctx.params
        result: dict = {}
        if p.checkpoints is not None:
            points, cover = read_checkpoints(p.checkpoints, p.land_cover_column)
            errors = checkpoint_errors(ctx.inputs["dtm"], points)  # metres, whatever the CRS's units
            result = vertical_accuracy(errors, cover, p.vegetated)
            ctx.log.info(
                "RMSEz %.3f m at %d check points (%d outside the DTM)",
                result["rmse_z"] or float("nan"),
                result["n"],
                result["outside"],
            )
            if result["outside"]:
                ctx.log.warning(
                    "%d of %d check points of %s fall outside the DTM's valid cells and measure nothing%s",
                    result["outside"],
                    result["outside"] + result["n"],
                    p.checkpoints,
                    ": none is this survey's; give its own check points or set stages.accuracy.enabled=false"
                    if result["n"] == 0
                    else "",
                )
        if p.truth_dtm is not None:
            result["truth"] = truth = _truth_block(ctx.inputs["dtm"], p.truth_dtm, p.truth_land_cover)
            ctx.log.info(
                "against %s: RMS %.3f m over %d cells, %.1f %% more than 1 m off, %.1f %% more than 5 m",
                Path(p.truth_dtm).name,
                truth["rmse"] or float("nan"),
                truth["n"],
                100 * (truth["off_1m"] or 0.0),
                100 * (truth["off_5m"] or 0.0),
            )
        ctx.metrics.update(result)
        ctx.outputs["accuracy"].write_text(json.dumps(result, indent=2))


def _truth_block(dtm_path: Path, truth_path: Path, land_cover_path: Path | None = None) -> dict:
    """accuracy.json's ``truth``: the files, how they were resampled, :func:`truth_accuracy`."""
    path = truth_path
    try:
        dtm, truth = truth_on_dtm_cells(dtm_path, truth_path)
        cover = None
        if land_cover_path is not None:
            path = land_cover_path
            cover = land_cover_on_dtm_cells(dtm_path, land_cover_path)
    except RasterioError as exc:
        raise InputDataError(f"{path}: cannot be read as a raster ({exc}).") from None
    out: dict = {"file": Path(truth_path).name, "resampling": "bilinear"}
    if land_cover_path is not None:
        out["land_cover_file"] = Path(land_cover_path).name
    out.update(truth_accuracy(dtm, truth, cover))
    if out["n"] == 0:
        raise InputDataError(
            f"{truth_path}: no DTM cell has a truth value (does the raster cover the survey, in the same CRS?)."
        )
    return out
