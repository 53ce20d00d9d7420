"""The DTM's interpolation methods, each declared once: name, parameter block, reach and function.

``rasterize``'s ``method`` names one of :data:`INTERPOLATORS`; the method's
parameters are the block ``stages.rasterize.<method>``
(:class:`~stages.rasterize.params.RasterizeParams` gets one per method that
has parameters), the tiles' buffer grows by its reach, and docs/CONFIG.md
lists them.  A method's function makes the DTM of ground points on a grid:
``function(ground, grid, params, progress)`` with the stage's parameters.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from lidar.grid import Grid
from pipeline.registry import Algorithm, Registry
from stages.rasterize.interpolate import IdwParams, TinParams, idw, nearest, tin

if TYPE_CHECKING:
    from pipeline.log import Progress


@dataclass(frozen=True)
class Interpolator(Algorithm):
    """An interpolation method: an :class:`~pipeline.registry.Algorithm` whose *reach* takes the stage's parameters.

    *min_points*: the fewest ground points that make a surface; *mask*:
    whether it marks the cells far from every point on a grid grown by
    ``nodata_distance`` (memory: :func:`stages.rasterize.tile_rasters.tile_memory`);
    *hands_over*: whether it frees the points it is given once it has what
    it needs (given as a one-item list).
    """

    min_points: int = 1
    mask: bool = False
    hands_over: bool = False


#: The registered interpolation methods.
INTERPOLATORS: Registry[Interpolator] = Registry("interpolation method")


def _tin(ground: Any, grid: Grid, params: Any, progress: Progress | None = None) -> np.ndarray:
    return tin(
        ground,
        grid,
        nodata_distance=params.nodata_distance,
        thin=params.tin.thin,
        progress=progress,
        max_hull_edge=params.outline_edge,
    )


def _idw(ground: np.ndarray, grid: Grid, params: Any, progress: Progress | None = None) -> np.ndarray:
    return idw(
        ground,
        grid,
        nodata_distance=params.nodata_distance,
        neighbors=params.idw.neighbors,
        power=params.idw.power,
        progress=progress,
    )


def _nearest(ground: np.ndarray, grid: Grid, params: Any, progress: Progress | None = None) -> np.ndarray:
    return nearest(ground, grid, nodata_distance=params.nodata_distance, progress=progress)


INTERPOLATORS.register(
    Interpolator(
        name="tin",
        params=TinParams,
        # a triangle covering a cell may reach across a gap up to nodata_distance from both sides
        reach=lambda p: 2.0 * p.nodata_distance,
        function=_tin,
        summary="linear interpolation on the Delaunay triangulation of the ground points",
        min_points=3,
        mask=True,
        hands_over=True,
    )
)
INTERPOLATORS.register(
    Interpolator(
        name="idw",
        params=IdwParams,
        reach=lambda p: p.nodata_distance,  # the points within nodata_distance of a cell centre
        function=_idw,
        summary="inverse-distance-weighted mean of the nearest ground points (Shepard 1968)",
    )
)
INTERPOLATORS.register(
    Interpolator(
        name="nearest",
        params=None,
        reach=lambda p: p.nodata_distance,
        function=_nearest,
        summary="the value of the nearest ground point",
    )
)
