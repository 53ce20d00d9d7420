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
    floor_window: float = Field(
        3.0,
        ge=0,
        description="objects flagged by an opening of radius up to this (metres) bound the provisional DEM under "
        "them by that opening (bridge decks; 0: off; docs/GROUND.md)",
    )
    wall_height: float = Field(
        2.0,
        ge=0,
        description="rise (metres) that walls in a plateau: walled plateaus wider than w_max inside the survey "
        "are objects (buildings wider than the window; 0: off; docs/GROUND.md)",
    )


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
    one_grid_cells: int = Field(
        8_000_000,
        ge=0,
        description="SMRF filters the whole survey on one grid, in passes over the points, when the grid has at "
        "most this many cells (8 km2 of 1 m cells; about 55 bytes a cell while it is filtered, more where cells "
        "are empty); larger surveys are cut into tiles with its buffer; 0: always tiles",
    )


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


def candidates_of(
    classification: np.ndarray,
    return_number: np.ndarray,
    number_of_returns: np.ndarray,
    withheld: np.ndarray,
    params: ClassifyGroundParams,
) -> tuple[np.ndarray, np.ndarray]:
    """``(keep, candidates)``: the points whose class stays, and those the algorithm may call ground."""
    kept_classes = (glossary.LOW_NOISE, glossary.HIGH_NOISE) + ((glossary.WATER,) if params.keep_water else ())
    keep = np.isin(classification, kept_classes) | np.asarray(withheld, dtype=bool)
    candidates = ~keep
    if params.last_returns:
        candidates &= np.asarray(return_number) >= np.asarray(number_of_returns)
    return keep, candidates


def new_classes(classification: np.ndarray, keep: np.ndarray, ground: np.ndarray) -> np.ndarray:
    """2 where *ground*, 1 for the other points not kept, the input class where *keep*."""
    cls = np.asarray(classification).copy()
    cls[~keep] = glossary.UNCLASSIFIED
    cls[ground] = glossary.GROUND
    return cls


def classify(
    points: np.ndarray,
    classification: np.ndarray,
    return_number: np.ndarray,
    number_of_returns: np.ndarray,
    withheld: np.ndarray,
    params: ClassifyGroundParams,
) -> np.ndarray:
    """New classes: 2 ground, 1 other; noise (7, 18), withheld and (``keep_water``) water (9) points unchanged."""
    keep, candidates = candidates_of(classification, return_number, number_of_returns, withheld, params)
    ground = np.zeros(len(keep), dtype=bool)
    if candidates.any():
        ground[candidates] = ground_mask(points[candidates], params.algorithm)
    return new_classes(classification, keep, ground)


class ClassifyGround(Stage):
    name = "classify_ground"
    version = "8"  # 8: SMRF walled plateaus (wide buildings); 7: SMRF floor of narrow objects (bridge decks); 6: SMRF low outliers as in the paper (canopy), second pass for pits, edge line under the cells; 5: SMRF edge padding from the cells near each edge; sparse surveys; 4: anchored grids; tiles
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
        whole = None
        if params.algorithm.name == "smrf" and params.one_grid_cells > 0:
            with ctx.progress(2 * cloud_info(src).count, "filtering", unit="pt") as bar:
                whole = smrf_one_grid(
                    src,
                    ctx.outputs["points_classified"],
                    params,
                    threads=ctx.workers,
                    progress=bar,
                    executor=ctx.executor,
                    workdir=ctx.workdir,
                )
        if whole is not None:  # SMRF on one grid of the whole survey: no tile, no buffer (see smrf_one_grid)
            ctx.metrics["tiling"] = {
                "tiles": 1,
                "size": None,
                "buffer": 0.0,
                "executor": "one grid, this process",
                "grid": list(whole["grid"]),
            }
            ctx.log.info("SMRF on one grid of %d x %d cells of %g m", *whole["grid"], grid_cell(params.algorithm))
            results = [whole]
        else:
            results = classes_by_tile(
                ctx,
                src,
                ctx.outputs["points_classified"],
                buffer=self.tile_buffer(params),
                columns=_classify_columns,
                task=classify_tile,
                extra={"params": params.model_dump(mode="json")},
                on_workers=True,
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


def _chunks(path: Path, work, *, chunk_size: int = 1_000_000):
    """``work(chunk, xyz, columns)`` of each chunk of a LAS file, in file order.

    ``xyz`` are the chunk's coordinates in metres and ``columns`` what
    :func:`classify` needs, as :func:`stages.tiles.split_cloud` reads them.
    (Two threads sharing the chunks were slower, 24 s against 16 s on 37.5 M
    points with the other core busy, and held 1.6 times the memory.)
    """
    import laspy

    from stages.io import chunk_xyz_metres, cloud_crs
    from stages.units import Units

    with laspy.open(str(path)) as reader:
        units = Units.of(cloud_crs(reader))
        for chunk in reader.chunk_iterator(chunk_size):
            yield work(chunk, chunk_xyz_metres(chunk, units), _classify_columns(chunk))


def _anchored(lo, hi, cell: float) -> tuple[float, float, int, int]:
    """``(x0, y0, rows, cols)`` of the grid of cells of *cell* over a box, anchored as :func:`stages.ground.surface.index_points`."""
    from stages.ground.surface import grid_corner

    x0, y0 = grid_corner(lo, cell)
    return x0, y0, int(np.floor((hi[1] - y0) / cell)) + 1, int(np.floor((hi[0] - x0) / cell)) + 1


def _candidate_bounds(src: Path, params: ClassifyGroundParams, chunk_size: int = 1_000_000):
    """Lowest and highest x, y of the points the algorithm may call ground; None when there is none."""

    def bounds(_, xyz, cols):
        _, cand = candidates_of(**cols, params=params)
        if not cand.any():
            return np.full(2, np.inf), np.full(2, -np.inf)
        return xyz[cand, :2].min(axis=0), xyz[cand, :2].max(axis=0)

    lo, hi = np.full(2, np.inf), np.full(2, -np.inf)
    for low, high in _chunks(src, bounds, chunk_size=chunk_size):
        lo, hi = np.minimum(lo, low), np.maximum(hi, high)
    return (lo, hi) if np.isfinite(lo).all() else None


def _lowest(src: Path, params: ClassifyGroundParams, anchor, progress=None, chunk_size: int = 1_000_000):
    """The lowest candidate per cell of the grid *anchor*, and the rows and columns the candidates occupy.

    Returns ``(zmin, (r0, r1, c0, c1))`` (NaN where a cell holds no
    candidate; ``r1``, ``c1`` inclusive; None without candidates), or None
    when a candidate lies off the grid (a header whose bounds miss points).
    """
    x0, y0, rows, cols = anchor
    cell = params.algorithm.cell_size

    def cells(_, xyz, columns):
        _, cand = candidates_of(**columns, params=params)
        col = np.floor((xyz[cand, 0] - x0) / cell).astype(np.int64)
        row = np.floor((xyz[cand, 1] - y0) / cell).astype(np.int64)
        if not len(col):
            return len(xyz), None, None, None
        box = (row.min(), row.max(), col.min(), col.max())
        return len(xyz), box, row * cols + col, xyz[cand, 2]

    zmin = np.full(rows * cols, np.inf)
    box = [rows, -1, cols, -1]
    for n, part, flat, z in _chunks(src, cells, chunk_size=chunk_size):
        if part is not None:
            r0, r1, c0, c1 = part
            if r0 < 0 or c0 < 0 or r1 >= rows or c1 >= cols:
                return None
            box = [min(box[0], r0), max(box[1], r1), min(box[2], c0), max(box[3], c1)]
            np.minimum.at(zmin, flat, z)
        if progress is not None:
            progress.update(n)
    zmin[~np.isfinite(zmin)] = np.nan
    return zmin.reshape(rows, cols), (tuple(int(b) for b in box) if box[1] >= 0 else None)


def smrf_one_grid(
    src: Path,
    dst: Path,
    params: ClassifyGroundParams,
    *,
    threads: int = 1,
    chunk_size: int = 1_000_000,
    progress=None,
    executor=None,
    workdir: Path | None = None,
) -> dict | None:
    """SMRF on one grid of the whole survey: *src* copied to *dst* with the new classes; None when too big.

    SMRF's grid steps (:func:`stages.ground.smrf.provisional_dem`) need no
    point, and a survey's grid is small next to its points (8 bytes a cell
    against 30 or more a point), so the survey is filtered whole, in
    passes over the points a chunk at a time:

    1. the lowest candidate per cell, on the grid of the file header's
       bounds (when a candidate lies off it, or that grid has more than
       ``one_grid_cells`` cells, the candidates' bounds are read first);
    2. the grid cut to the cells the candidates occupy: the grid
       :func:`classify` makes of all the points at once, so the classes
       are those of an untiled run, with no buffer read twice and memory
       that follows the grid and the chunk, not the points;
    3. each chunk's point test and classes, written as it is read.

    *threads* filter bands of the grid's rows at once
    (:func:`stages.ground.smrf.progressive_filter`).  With an *executor* of
    more than one worker (and a *workdir* for the grids), step 3 runs on
    the workers, a range of records each (:func:`_classes_on_workers`):
    the same file, byte for byte.  Returns the counts, or None (nothing
    written) when the grid of the candidates has more than
    ``one_grid_cells`` cells: the caller tiles.
    """
    import laspy

    from stages.ground.smrf import provisional_dem
    from stages.ground.surface import CellIndex
    from stages.io import open_las_writer
    from stages.tiles import cloud_info

    algo = params.algorithm
    cell, cap = algo.cell_size, params.one_grid_cells
    info = cloud_info(src)
    extent = info.extent
    records = None  # where the records lie, for the workers to write them in place
    if executor is not None and executor.workers > 1 and workdir is not None and info.count >= 2 * chunk_size:
        records = _record_layout(src)
    if records is not None:
        executor.prepare(classes_range)  # the workers start while this process finds the grid
    anchor = _anchored(extent[:2], extent[2:], cell)
    got = _lowest(src, params, anchor, progress, chunk_size) if anchor[2] * anchor[3] <= cap else None
    if got is None:  # the header's grid is too big (stray points) or misses points: the candidates' own
        bounds = _candidate_bounds(src, params, chunk_size)
        anchor = _anchored(*bounds, cell) if bounds is not None else (0.0, 0.0, 1, 1)
        if anchor[2] * anchor[3] > cap:
            return None
        got = _lowest(src, params, anchor, chunk_size=chunk_size)
    zmin, box = got
    test = {"elevation_threshold": algo.elevation_threshold, "elevation_scalar": algo.elevation_scalar}
    surfaces, grid = None, None
    if box is not None:
        r0, r1, c0, c1 = box
        x0, y0 = anchor[0] + c0 * cell, anchor[1] + r0 * cell
        grid = CellIndex(x0, y0, cell, r1 - r0 + 1, c1 - c0 + 1, np.zeros(0, np.int64), np.zeros(0, np.int64))
        zmin = zmin[r0 : r1 + 1, c0 : c1 + 1]
        surfaces = provisional_dem(
            zmin,
            cell_size=cell,
            slope=algo.slope,
            max_window_size=algo.max_window_size,
            floor_window=algo.floor_window,
            wall_height=algo.wall_height,
            threads=threads,
            **test,
        )
    del zmin

    def classes(chunk, xyz, cols):
        chunk.classification, numbers = _chunk_classes(xyz, cols, params, grid, surfaces)
        return chunk, numbers

    counts = dict.fromkeys(COUNTS, 0)
    if records is not None and surfaces is not None:
        numbers = _classes_on_workers(src, dst, records, params, grid, surfaces, executor, workdir, chunk_size)
        for key, value in zip(counts, numbers, strict=True):
            counts[key] += value
        if progress is not None:
            progress.update(info.count)
    else:
        with laspy.open(str(src)) as reader, open_las_writer(dst, reader.header) as writer:
            for chunk, numbers in _chunks(src, classes, chunk_size=chunk_size):
                writer.write_points(chunk)
                for key, value in zip(counts, numbers, strict=True):
                    counts[key] += value
                if progress is not None:
                    progress.update(numbers[0])
    counts["grid"] = (grid.rows, grid.cols) if grid is not None else (0, 0)
    return counts


#: What step 3 counts, in this order: points, ground, non-ground, last (or single) returns.
COUNTS = ("points", "ground", "non_ground", "last_returns")


def _chunk_classes(xyz, cols, params, grid, surfaces) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Step 3 of :func:`smrf_one_grid` on one chunk: its new classes and :data:`COUNTS`."""
    from stages.ground.smrf import point_test

    algo = params.algorithm
    keep, cand = candidates_of(**cols, params=params)
    ground = np.zeros(len(keep), dtype=bool)
    if surfaces is not None and cand.any():
        ground[cand] = point_test(
            xyz[cand],
            grid,
            *surfaces,
            elevation_threshold=algo.elevation_threshold,
            elevation_scalar=algo.elevation_scalar,
        )
    cls = new_classes(cols["classification"], keep, ground)
    last = int((cols["return_number"] >= cols["number_of_returns"]).sum())
    return cls, (len(cls), int((cls == glossary.GROUND).sum()), int((cls == glossary.UNCLASSIFIED).sum()), last)


def _record_layout(path: Path) -> tuple[int, int, int] | None:
    """``(offset to the first record, record length, record count)`` of a LAS file the workers may rewrite in place.

    None when the classification is not a byte of its own (point formats
    0-5 keep it in five bits of a byte shared with three flags), the file
    is compressed, or anything follows the records (EVLRs, which laspy's
    writer does not copy): such a file is written by laspy's writer.
    """
    import laspy

    with laspy.open(str(path)) as reader:
        header = reader.header
        if header.are_points_compressed:
            return None
        fields = header.point_format.dtype().fields
        if "classification" not in fields or fields["classification"][0] != np.uint8:
            return None
        offset, size, count = int(header.offset_to_point_data), int(header.point_format.size), int(header.point_count)
        if Path(path).stat().st_size != offset + count * size:
            return None
        return offset, size, count


def _classes_on_workers(src, dst, records, params, grid, surfaces, executor, workdir, chunk_size) -> list[int]:
    """Step 3 of :func:`smrf_one_grid` on the workers: *dst* is *src* with the new classes.

    This process writes *src*'s header and VLRs to *dst* and sizes it for
    the records; the workers each classify a range of records
    (:func:`classes_range`, the grids read from ``.npy`` files in
    *workdir*) and write the range's records, their classification byte
    replaced, at their place in *dst*.  Only the classification changes, so
    *src*'s header (bounds, returns, counts) is the one laspy's writer gives
    the same points (a test compares the bytes); *src* has nothing after
    its records (*records*: :func:`_record_layout`).  Returns :data:`COUNTS`.
    """
    import shutil

    offset, size, count = records
    folder = Path(workdir) / ".smrf-one-grid"
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    try:
        np.save(folder / "dem.npy", surfaces[0])
        np.save(folder / "slope.npy", surfaces[1])
        with open(src, "rb") as head, open(dst, "wb") as out:
            out.write(head.read(offset))  # header and VLRs
            out.truncate(offset + count * size)
        pieces = 2 * executor.workers
        bounds = [count * k // pieces for k in range(pieces + 1)]
        tasks = [
            {
                "path": str(src),
                "start": bounds[k],
                "stop": bounds[k + 1],
                "params": params.model_dump(mode="json"),
                "grid": [grid.x0, grid.y0, grid.cell_size, grid.rows, grid.cols],
                "surfaces": [str(folder / "dem.npy"), str(folder / "slope.npy")],
                "dst": str(dst),
                "offset": offset + bounds[k] * size,
                "chunk_size": max(chunk_size // executor.workers, 1),  # the workers' chunks together: one process's
            }
            for k in range(pieces)
        ]
        results = executor.map(classes_range, tasks, what="point test")
        return [sum(r[k] for r in results) for k in range(len(COUNTS))]
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def classes_range(task: dict) -> list[int]:
    """Step 3 of :func:`smrf_one_grid` on records ``start:stop`` (runs in a worker; see :func:`_classes_on_workers`)."""
    import laspy

    from stages.ground.surface import CellIndex
    from stages.io import chunk_xyz_metres, cloud_crs
    from stages.tiles import record_chunks
    from stages.units import Units

    params = ClassifyGroundParams.model_validate(task["params"])
    x0, y0, cell, rows, cols = task["grid"]
    empty = np.zeros(0, np.int64)
    grid = CellIndex(x0, y0, cell, int(rows), int(cols), empty, empty)
    surfaces = tuple(np.load(p, mmap_mode="r") for p in task["surfaces"])
    start, stop = task["start"], task["stop"]
    totals = [0] * len(COUNTS)
    # the file exists at its full size: each range writes its own bytes (r+: no truncation)
    with laspy.open(task["path"]) as reader, open(task["dst"], "r+b") as out:
        out.seek(task["offset"])
        units = Units.of(cloud_crs(reader))
        for chunk in record_chunks(reader, start, stop, task["chunk_size"]):
            xyz = chunk_xyz_metres(chunk, units)
            cls, numbers = _chunk_classes(xyz, _classify_columns(chunk), params, grid, surfaces)
            chunk.array["classification"] = cls
            out.write(chunk.array)  # contiguous records: written as they are, no copy
            totals = [a + b for a, b in zip(totals, numbers, strict=True)]
    if totals[0] != stop - start:  # pragma: no cover - fewer records than the header says; parse checks that first
        raise InputDataError(f"{task['path']}: of records {start:,} to {stop:,}, {totals[0]:,} could be read.")
    return totals
