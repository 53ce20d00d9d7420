"""Stage ``classify_ground``: split points into ground (class 2) and the rest (class 1).

The driver does the shared work; the algorithm (chosen by ``algorithm.name``)
is a pure function on coordinates returning a ground mask:

- ``smrf`` (default): simple morphological filter, Pingel et al. (2013),
  :func:`stages.ground.smrf.smrf`, with the published parameters;
- ``pmf``: progressive morphological filter, Zhang et al. (2003), the seed's
  reference, :func:`stages.ground.pmf.pmf`;
- ``csf``: cloth simulation filter, Zhang W. et al. (2016), through the
  ``cloth-simulation-filter`` package, :func:`stages.ground.csf.csf`.

Points already classified as noise (7, 18) or flagged withheld keep their
class and are not given to the algorithm; so do points the input classified
as water (9), with ``keep_water`` (default): a water surface is not bare
earth (hydro-flattening is left to breaklines).  With ``last_returns`` (default),
only last (or single) returns may become ground: first and intermediate
returns of a multi-return pulse hit something above the ground.  Why SMRF is
the default, and how each algorithm scores: docs/GROUND.md.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, ClassVar, Literal

import numpy as np
from pydantic import Field

from pipeline.config import StrictModel
from pipeline.stage import Stage, StageParams
from stages import glossary


class SmrfParams(StrictModel):
    """Simple morphological filter (Pingel et al. 2013); see :func:`stages.ground.smrf.smrf`."""

    name: Literal["smrf"] = Field(description="ground algorithm: smrf | pmf | csf")
    cell_size: float = glossary.cell_size(1.0)
    slope: float = glossary.slope(0.15)
    max_window_size: float = Field(18.0, gt=0, description="w_max: largest window radius, metres")
    elevation_threshold: float = Field(0.5, ge=0, description="et: base height threshold of the point test, metres")
    elevation_scalar: float = Field(1.25, ge=0, description="es: threshold added per unit of local DEM slope, metres")


class PmfParams(StrictModel):
    """Progressive morphological filter (Zhang et al. 2003); see :func:`stages.ground.pmf.pmf`."""

    name: Literal["pmf"] = Field(description="ground algorithm: smrf | pmf | csf")
    cell_size: float = glossary.cell_size(1.0)
    max_window_size: float = glossary.max_window_size(33.0)
    slope: float = glossary.slope(0.15)
    initial_distance: float = Field(0.15, ge=0, description="dh_0: first elevation-difference threshold, metres")
    max_distance: float = Field(2.5, ge=0, description="dh_max: largest elevation-difference threshold, metres")


class CsfParams(StrictModel):
    """Cloth simulation filter (Zhang W. et al. 2016); see :func:`stages.ground.csf.csf`."""

    name: Literal["csf"] = Field(description="ground algorithm: smrf | pmf | csf")
    cloth_resolution: float = Field(0.5, gt=0, description="GR: spacing of the cloth particles, metres")
    rigidness: int = Field(1, ge=1, le=3, description="RI: 1 steep, 2 relief, 3 flat")
    class_threshold: float = Field(0.5, gt=0, description="hcc: distance to the cloth for ground, metres")
    time_step: float = Field(0.65, gt=0, description="dT: simulation time step")
    iterations: int = Field(500, ge=1, description="maximum simulation iterations")
    slope_smooth: bool = Field(True, description="post-process steep slopes")


GroundAlgorithm = Annotated[SmrfParams | PmfParams | CsfParams, Field(discriminator="name")]
ALGORITHMS = {"smrf": SmrfParams, "pmf": PmfParams, "csf": CsfParams}


class ClassifyGroundParams(StageParams):
    algorithm: GroundAlgorithm = Field(
        default_factory=lambda: SmrfParams(name="smrf"), description="the ground algorithm and its parameters"
    )
    last_returns: bool = Field(True, description="only last or single returns can be ground")
    keep_water: bool = Field(True, description="points the input classified as water (9) keep it; never ground")


def reach(algorithm: StrictModel) -> float:
    """How far (metres) the algorithm looks from a point: the buffer a tile needs.

    SMRF: an opening of radius ``w_max`` reads ``2 w_max`` around a cell, and
    a gap it fills (a building, at most ``2 w_max`` wide by the parameter's
    definition) takes its values from cells that far again, so ``4 w_max``
    plus two cells.  PMF: the largest square window, twice, plus two cells.
    CSF: the cloth is one global simulation; 50 m is a practical margin and
    tiled CSF results may differ from untiled ones within a few metres of
    tile edges (docs/ARCHITECTURE.md).
    """
    if algorithm.name == "smrf":
        return 4.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size
    if algorithm.name == "pmf":
        return 2.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size
    return 50.0


def ground_mask(points: np.ndarray, algorithm: StrictModel) -> np.ndarray:
    """Run the configured algorithm on (n, 3) coordinates; True = ground."""
    params = algorithm.model_dump(exclude={"name"})
    if algorithm.name == "smrf":
        from stages.ground.smrf import smrf

        return smrf(points, **params)
    if algorithm.name == "pmf":
        from stages.ground.pmf import pmf

        return pmf(points, **params)
    if algorithm.name == "csf":
        from stages.ground.csf import csf

        return csf(points, **params)
    raise ValueError(f"unknown ground algorithm {algorithm.name}")  # pragma: no cover - config rejects it


def classify(
    points: np.ndarray,
    classification: np.ndarray,
    return_number: np.ndarray,
    number_of_returns: np.ndarray,
    withheld: np.ndarray,
    params: ClassifyGroundParams,
) -> np.ndarray:
    """New classes: 2 ground, 1 other; noise (7, 18), withheld and (``keep_water``) water (9) points unchanged."""
    cls = np.asarray(classification).copy()
    kept_classes = (glossary.LOW_NOISE, glossary.HIGH_NOISE) + ((glossary.WATER,) if params.keep_water else ())
    keep = np.isin(cls, kept_classes) | np.asarray(withheld, dtype=bool)
    candidates = ~keep
    if params.last_returns:
        candidates &= np.asarray(return_number) >= np.asarray(number_of_returns)
    ground = np.zeros(len(cls), dtype=bool)
    if candidates.any():
        ground[candidates] = ground_mask(points[candidates], params.algorithm)
    cls[~keep] = glossary.UNCLASSIFIED
    cls[ground] = glossary.GROUND
    return cls


class ClassifyGround(Stage):
    name = "classify_ground"
    version = "4"  # 4: grids anchored on whole cells; tiles
    Params = ClassifyGroundParams
    description = "ground / non-ground classification"
    inputs = ("points_denoised",)
    outputs: ClassVar = {"points_classified": "points.las"}
    passthrough: ClassVar = {"points_classified": "points_denoised"}

    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params) -> float:
        return reach(params.algorithm)

    def run(self, ctx) -> None:
        from stages.tiles import classes_by_tile

        results = classes_by_tile(
            ctx,
            ctx.inputs["points_denoised"],
            ctx.outputs["points_classified"],
            buffer=self.tile_buffer(ctx.params),
            columns=_classify_columns,
            task=classify_tile,
            extra={"params": ctx.params.model_dump(mode="json")},
        )
        counts = {k: sum(r[k] for r in results) for k in ("points", "ground", "non_ground")}
        n, ground, other = counts["points"], counts["ground"], counts["non_ground"]
        ctx.metrics.update(
            algorithm=ctx.params.algorithm.model_dump(),
            points=int(n),
            ground=ground,
            non_ground=other,
            noise_or_withheld=int(n - ground - other),
            ground_fraction=round(ground / n, 4) if n else 0.0,
        )
        ctx.log.info("%d of %d points are ground (%.1f %%)", ground, n, 100.0 * ground / max(n, 1))


def _classify_columns(chunk) -> dict[str, np.ndarray]:
    return {
        "classification": np.asarray(chunk.classification, dtype=np.uint8),
        "return_number": np.asarray(chunk.return_number, dtype=np.uint8),
        "number_of_returns": np.asarray(chunk.number_of_returns, dtype=np.uint8),
        "withheld": np.asarray(chunk.withheld, dtype=bool),
    }


def classify_tile(task: dict) -> dict:
    """Classify one tile's points (core plus buffer); write the classes of its core points.

    Runs in a worker process: reads ``task["source"]`` (columns written by
    :func:`stages.tiles.split_cloud`), writes ``idx`` and ``classification``
    of the core points to ``task["result"]``, returns counts.
    """
    from stages.tiles import read_tile, write_result

    cols = read_tile(Path(task["source"]))
    params = ClassifyGroundParams.model_validate(task["params"])
    cls = classify(
        cols["xyz"], cols["classification"], cols["return_number"], cols["number_of_returns"], cols["withheld"], params
    )
    core = cols["core"]
    write_result(Path(task["result"]), idx=cols["idx"][core], classification=cls[core])
    kept = cls[core]
    return {
        "tile": task["tile"],
        "points": int(core.sum()),
        "ground": int((kept == glossary.GROUND).sum()),
        "non_ground": int((kept == glossary.UNCLASSIFIED).sum()),
    }
