"""The ground filters, each declared once: name, parameter model, reach, function, grid cell and grid form.

``classify_ground``'s configuration (``algorithm: {name: ...}``), its tile
buffer, ``pipeline evaluate ground`` and docs/CONFIG.md read
:data:`GROUND_FILTERS`.  A filter's function takes (n, 3) coordinates in
metres and its parameters (without ``name``) and returns a ground mask;
adding a filter is its module, one :meth:`~pipeline.registry.Registry.register`
call and its tests.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import BaseModel

from pipeline.registry import Algorithm, Registry
from stages.classify_ground import csf, pmf, smrf
from stages.classify_ground.surface import CellIndex


@dataclass(frozen=True)
class GridForm:
    """A filter that needs no point once its grid of lowest points is made (SMRF): the survey filtered on one grid.

    ``surfaces(zmin, params, threads)``: the grids the point test reads
    (None when the filter leaves no cell); ``test(xyz, index, surfaces,
    params)``: the ground mask of points on that grid.
    """

    surfaces: Callable[[np.ndarray, BaseModel, int], tuple[np.ndarray, ...] | None]
    test: Callable[[np.ndarray, CellIndex, tuple[np.ndarray, ...], BaseModel], np.ndarray]


@dataclass(frozen=True)
class GroundFilter(Algorithm):
    """A ground filter: an :class:`~pipeline.registry.Algorithm` with its grid cell.

    *cell*: the field of its parameters that holds its grid's cell (m);
    *sparse*: whether that cell grows to a sparse survey's point spacing
    (:func:`stages.classify_ground.ground_classes.for_spacing`); *grid*: its
    one-grid form, None for a filter that needs its points.
    """

    cell: str = "cell_size"
    sparse: bool = True
    grid: GridForm | None = None


#: The registered ground filters.
GROUND_FILTERS: Registry[GroundFilter] = Registry("ground algorithm")


def _without_name(params: BaseModel) -> dict[str, Any]:
    return params.model_dump(exclude={"name"})


def _smrf_surfaces(zmin: np.ndarray, params: smrf.SmrfParams, threads: int) -> tuple[np.ndarray, ...] | None:
    return smrf.provisional_dem(zmin, **_without_name(params), threads=threads)


def _smrf_test(xyz: np.ndarray, index: CellIndex, surfaces: tuple[np.ndarray, ...], params: smrf.SmrfParams):
    return smrf.point_test(
        xyz,
        index,
        *surfaces,
        elevation_threshold=params.elevation_threshold,
        elevation_scalar=params.elevation_scalar,
    )


GROUND_FILTERS.register(
    GroundFilter(
        name="smrf",
        params=smrf.SmrfParams,
        reach=smrf.reach,
        function=smrf.smrf,
        summary="simple morphological filter (Pingel et al. 2013)",
        grid=GridForm(_smrf_surfaces, _smrf_test),
    )
)
GROUND_FILTERS.register(
    GroundFilter(
        name="pmf",
        params=pmf.PmfParams,
        reach=pmf.reach,
        function=pmf.pmf,
        summary="progressive morphological filter (Zhang et al. 2003)",
    )
)
GROUND_FILTERS.register(
    GroundFilter(
        name="csf",
        params=csf.CsfParams,
        reach=csf.reach,
        function=csf.csf,
        summary="cloth simulation filter (Zhang W. et al. 2016)",
        cell="cloth_resolution",
        sparse=False,  # a cloth particle needs no point in its cell
    )
)


def grid_cell(algorithm: BaseModel) -> float:
    """The cell (m) of the algorithm's grid: the parameter its declaration names."""
    return float(getattr(algorithm, GROUND_FILTERS[algorithm.name].cell))


def reach(algorithm: BaseModel) -> float:
    """How far (m) the algorithm looks from a point: the buffer a tile needs."""
    return float(GROUND_FILTERS[algorithm.name].reach(algorithm))


def ground_mask(points: np.ndarray, algorithm: BaseModel) -> np.ndarray:
    """Run the configured algorithm on (n, 3) coordinates; True = ground."""
    return GROUND_FILTERS[algorithm.name].function(points, **_without_name(algorithm))
