"""Stage ``classify_ground``: split points into ground (class 2) and the rest (class 1).

The driver does the shared work; the algorithm (chosen by
``algorithm.name``) is a pure function on coordinates returning a ground
mask.  Points already classified as noise (7, 18) or flagged withheld keep
their class and are not given to the algorithm.  With ``last_returns`` (the
default), only last (or single) returns may become ground: first and
intermediate returns of a multi-return pulse hit something above the ground.

Algorithms in this version: ``pmf`` (Zhang et al. 2003).  SMRF, CSF and the
noise stage come with the ground-classification issue.
"""

from __future__ import annotations

from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field

from pipeline.config import StrictModel
from pipeline.stage import Stage, StageParams
from stages import glossary
from stages.io import read_cloud, write_cloud, xyz


class PmfParams(StrictModel):
    """Progressive morphological filter (Zhang et al. 2003); see :func:`stages.ground.pmf.pmf`."""

    name: Literal["pmf"] = Field(description="ground algorithm; this version has: pmf")
    cell_size: float = glossary.cell_size(1.0)
    max_window_size: float = glossary.max_window_size(33.0)
    slope: float = glossary.slope(0.15)
    initial_distance: float = Field(0.15, ge=0, description="dh_0: first elevation-difference threshold, metres")
    max_distance: float = Field(2.5, ge=0, description="dh_max: largest elevation-difference threshold, metres")


GroundAlgorithm = Annotated[PmfParams, Field(discriminator="name")]


class ClassifyGroundParams(StageParams):
    algorithm: GroundAlgorithm = Field(default_factory=lambda: PmfParams(name="pmf"))
    last_returns: bool = Field(True, description="only last or single returns can be ground")


def ground_mask(points: np.ndarray, algorithm: StrictModel) -> np.ndarray:
    """Run the configured algorithm on (n, 3) coordinates; True = ground."""
    params = algorithm.model_dump(exclude={"name"})
    if algorithm.name == "pmf":
        from stages.ground.pmf import pmf

        return pmf(points, **params)
    raise ValueError(f"unknown ground algorithm {algorithm.name}")  # pragma: no cover - config rejects it


class ClassifyGround(Stage):
    name = "classify_ground"
    version = "1"
    Params = ClassifyGroundParams
    description = "ground / non-ground classification"
    inputs = ("points_georef",)
    outputs: ClassVar = {"points_classified": "points.las"}
    passthrough: ClassVar = {"points_classified": "points_georef"}

    def run(self, ctx) -> None:
        las = read_cloud(ctx.inputs["points_georef"])
        cls = np.asarray(las.classification).copy()
        keep = np.isin(cls, (glossary.LOW_NOISE, glossary.HIGH_NOISE)) | np.asarray(las.withheld, dtype=bool)
        candidates = ~keep
        if ctx.params.last_returns:
            last = np.asarray(las.return_number) >= np.asarray(las.number_of_returns)
            candidates &= last
        pts = xyz(las)
        ground = np.zeros(len(cls), dtype=bool)
        if candidates.any():
            ground[candidates] = ground_mask(pts[candidates], ctx.params.algorithm)
        cls[~keep] = glossary.UNCLASSIFIED
        cls[ground] = glossary.GROUND
        las.classification = cls
        n = len(cls)
        ctx.metrics.update(
            algorithm=ctx.params.algorithm.model_dump(),
            points=int(n),
            ground=int(ground.sum()),
            non_ground=int((~ground & ~keep).sum()),
            noise_kept=int(keep.sum()),
            ground_fraction=round(float(ground.sum()) / n, 4) if n else 0.0,
        )
        ctx.log.info("%d of %d points are ground (%.1f %%)", ground.sum(), n, 100.0 * ground.sum() / max(n, 1))
        write_cloud(las, ctx.outputs["points_classified"])
