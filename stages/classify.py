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
from pipeline.errors import InputDataError
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
    plus two cells for the provisional DEM; the second pass (low cells below
    that DEM left out of the openings, :func:`stages.ground.smrf.smrf`)
    opens and fills again around cells decided by it: ``8 w_max`` plus two
    cells.  PMF: the largest square window, twice, plus two cells.
    CSF: the cloth is one global simulation; 50 m is a practical margin and
    tiled CSF results may differ from untiled ones within a few metres of
    tile edges (docs/ARCHITECTURE.md).
    """
    if algorithm.name == "smrf":
        return 8.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size
    if algorithm.name == "pmf":
        return 2.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size
    return 50.0


#: A survey is sparse for a grid filter when its points are farther apart than this many cells.
SPARSE_SPACINGS = 3.0
#: Occupancy cells (in filter cells) over which the nominal point spacing is measured.
OCCUPANCY_CELLS = 32


def grid_cell(algorithm: StrictModel) -> float:
    """The cell (metres) of the algorithm's grid: SMRF's and PMF's ``cell_size``, CSF's cloth spacing."""
    return float(algorithm.cloth_resolution if algorithm.name == "csf" else algorithm.cell_size)


def for_spacing(algorithm: StrictModel, spacing: float | None) -> StrictModel:
    """The algorithm with its grid cell raised to the point spacing of a sparse survey (SMRF, PMF).

    A morphological filter's minimum surface is meaningful only when most of
    its cells hold points.  Where the points lie more than
    ``SPARSE_SPACINGS`` cells apart on average (under 0.11 points/m² with
    1 m cells), the grid would be almost all interpolated — a surface of
    spikes through isolated points — and its cost would follow the area, not
    the points.  The cell is then the nominal spacing, rounded up to a whole
    multiple of the configured cell; windows, slopes and thresholds stay in
    metres.  Surveys denser than that are filtered exactly as configured, and
    CSF always is (its cloth particles need no point in their cell; measured:
    samp51, points 2.5 m apart, went from 12.2 to 50.3 % total error on a
    cloth of 2.5 m instead of 0.5 m).

    >>> from stages.classify import SmrfParams
    >>> for_spacing(SmrfParams(name="smrf"), 19.4).cell_size
    20.0
    >>> for_spacing(SmrfParams(name="smrf"), 1.5).cell_size
    1.0
    """
    if algorithm.name == "csf":  # a cloth particle needs no point in its cell: CSF is run as configured
        return algorithm
    cell = grid_cell(algorithm)
    if spacing is None or not np.isfinite(spacing) or spacing <= SPARSE_SPACINGS * cell:
        return algorithm
    used = float(np.ceil(spacing / cell) * cell)
    return algorithm.model_copy(update={"cell_size": used})


def nominal_spacing(path: Path, cell: float, info) -> float | None:
    """Nominal point spacing (metres) of the usable points, over the area they cover; None when surely dense.

    From the header first (count over the extent's area): a survey at least
    as dense as ``1 / (SPARSE_SPACINGS cell)²`` needs no more (None).  Otherwise one
    pass counts the points that are not noise or withheld and the cells of
    ``OCCUPANCY_CELLS`` x *cell* they occupy, so that stray points and large
    voids do not count as area: spacing = sqrt(occupied area / points).
    """
    import laspy

    xmin, ymin, xmax, ymax = info.extent
    area = max(xmax - xmin, cell) * max(ymax - ymin, cell)
    if info.count and area / info.count <= (SPARSE_SPACINGS * cell) ** 2:
        return None
    big = OCCUPANCY_CELLS * cell
    occupied: set[int] = set()
    count = 0
    with laspy.open(str(path)) as reader:
        for chunk in reader.chunk_iterator(1_000_000):
            cls = np.asarray(chunk.classification)
            keep = glossary.usable(cls, chunk.withheld)
            xy = info.units.to_metres(np.column_stack((np.asarray(chunk.x), np.asarray(chunk.y), np.zeros(len(cls)))))
            col = np.floor(xy[keep, 0] / big).astype(np.int64)
            row = np.floor(xy[keep, 1] / big).astype(np.int64)
            occupied.update(np.unique(row * (1 << 31) + col).tolist())
            count += int(keep.sum())
    if count == 0:
        return None
    return float(np.sqrt(len(occupied) * big * big / count))


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
    version = "6"  # 6: SMRF low outliers as in the paper (canopy), second pass for pits, edge line under the cells; 5: SMRF edge padding from the cells near each edge; sparse surveys; 4: anchored grids; tiles
    Params = ClassifyGroundParams
    description = "ground / non-ground classification"
    inputs = ("points_denoised",)
    outputs: ClassVar = {"points_classified": "points.las"}
    passthrough: ClassVar = {"points_classified": "points_denoised"}

    config_keys = ("tiling.buffer",)

    def tile_buffer(self, params) -> float:
        return reach(params.algorithm)

    def run(self, ctx) -> None:
        from stages.tiles import classes_by_tile, cloud_info

        src = ctx.inputs["points_denoised"]
        params = ctx.params
        spacing = nominal_spacing(src, grid_cell(params.algorithm), cloud_info(src))
        used = for_spacing(params.algorithm, spacing)
        if used is not params.algorithm:
            ctx.log.warning(
                "sparse survey: the points lie %.1f m apart, more than %g cells of %g m; %s runs on cells of %g m "
                "(windows and thresholds unchanged, in metres)",
                spacing,
                SPARSE_SPACINGS,
                grid_cell(params.algorithm),
                used.name,
                grid_cell(used),
            )
            params = params.model_copy(update={"algorithm": used})
        results = classes_by_tile(
            ctx,
            src,
            ctx.outputs["points_classified"],
            buffer=self.tile_buffer(params),
            columns=_classify_columns,
            task=classify_tile,
            extra={"params": params.model_dump(mode="json")},
        )
        counts = {k: sum(r[k] for r in results) for k in ("points", "ground", "non_ground", "last_returns")}
        n, ground, other = counts["points"], counts["ground"], counts["non_ground"]
        if n and ground == 0 and params.last_returns and counts["last_returns"] == 0:
            raise InputDataError(
                f"{glossary.input_names(ctx.config)}: none of its {n:,} points is a last or single return (return number = number of "
                "returns), so none can be ground; if the file's return numbers are wrong, set "
                "stages.classify_ground.last_returns: false."
            )
        ctx.metrics.update(
            algorithm=params.algorithm.model_dump(),
            nominal_spacing_m=round(spacing, 3) if spacing is not None else None,
            grid_cell_m=grid_cell(params.algorithm),
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
    last = cols["return_number"][core] >= cols["number_of_returns"][core]
    return {
        "tile": task["tile"],
        "points": int(core.sum()),
        "last_returns": int(last.sum()),
        "ground": int((kept == glossary.GROUND).sum()),
        "non_ground": int((kept == glossary.UNCLASSIFIED).sum()),
    }
