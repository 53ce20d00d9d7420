"""One glossary of parameter names, shared by every stage.

A parameter that means the same thing in two stages has the same name, unit
and description in both; it is defined here once.  Linear quantities are in
metres whatever the unit of the output CRS: stages convert coordinates to
metres before using them (:mod:`lidar.units`).  docs/CONFIG.md lists them
with their defaults.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from pydantic import Field

#: ASPRS classification codes (LAS 1.4 R15, Table 17) used by the pipeline.
UNCLASSIFIED = 1
GROUND = 2
LOW_NOISE = 7
WATER = 9
BRIDGE_DECK = 17
HIGH_NOISE = 18
IGNORED_GROUND = 20

#: The ground, the DTM's or not (ignored ground lies near a breakline): what ground scores count as ground.
GROUNDS = (GROUND, IGNORED_GROUND)

#: The classes the DTM is made of: the bare earth is the ground and the water surface on it.
BARE_EARTH = (GROUND, WATER)

#: ASPRS class names (LAS 1.4 R15, Table 17; 19-22 added by R15)
CLASS_NAMES = {
    0: "created, never classified",
    1: "unclassified",
    2: "ground",
    3: "low vegetation",
    4: "medium vegetation",
    5: "high vegetation",
    6: "building",
    7: "low noise",
    8: "model key point / reserved",
    9: "water",
    10: "rail",
    11: "road surface",
    12: "overlap / reserved",
    13: "wire guard",
    14: "wire conductor",
    15: "transmission tower",
    16: "wire connector",
    17: "bridge deck",
    18: "high noise",
    19: "overhead structure",
    20: "ignored ground",
    21: "snow",
    22: "temporal exclusion",
}


#: Colours of the ASPRS classes (RGB 0-255), as common viewers show them: the report's class map (others
#: black) and the points' QGIS style.
CLASS_COLOURS = {
    1: (170, 170, 170),
    2: (166, 124, 82),
    3: (186, 228, 179),
    4: (116, 196, 118),
    5: (35, 139, 69),
    6: (227, 26, 28),
    9: (49, 130, 189),
    17: (255, 170, 0),
    20: (204, 204, 102),
}


def class_name(code: int) -> str:
    """The ASPRS name of a classification code ("reserved" 23-63, "user defined" 64-255)."""
    return CLASS_NAMES.get(code, "user defined" if code >= 64 else "reserved")


def cell_size(default: float) -> Any:
    """Side of the square cells of an algorithm's internal grid (m)."""
    return Field(default, gt=0, description="side of the algorithm's internal grid cells, metres")


#: Finest product raster cell (m): below any airborne survey's point spacing.
MIN_RESOLUTION = 0.01


def resolution(default: float) -> Any:
    """Side of the square cells of a product raster (m): finite, at least :data:`MIN_RESOLUTION`."""
    return Field(
        default,
        ge=MIN_RESOLUTION,
        allow_inf_nan=False,
        description=f"side of the product raster's cells, metres (at least {MIN_RESOLUTION:g})",
    )


def slope(default: float) -> Any:
    """Terrain slope as rise over run (dimensionless; 1.0 = 45 degrees)."""
    return Field(default, ge=0, description="terrain slope, rise over run (1.0 = 45 degrees)")


def max_window_size(default: float) -> Any:
    """Largest morphological window (m): larger than the widest building."""
    return Field(default, gt=0, description="largest morphological window, metres (wider than the widest building)")


def nodata_distance(default: float) -> Any:
    """Cells farther than this from every input point are nodata (m)."""
    return Field(default, gt=0, description="cells farther than this from any point are nodata, metres")


def usable(classification, withheld) -> np.ndarray:
    """The points that enter grids and filters: neither noise (7, 18) nor withheld."""
    return ~np.isin(np.asarray(classification), (LOW_NOISE, HIGH_NOISE)) & ~np.asarray(withheld, dtype=bool)


def input_names(config: Any) -> str:
    """The survey's input files as a user named them, for messages of stages that read only intermediates."""
    paths = list(getattr(getattr(config, "input", None), "paths", []) or [])
    if not paths:
        return "the input"
    names = ", ".join(str(p) for p in paths[:3])
    return names + (f" and {len(paths) - 3} more" if len(paths) > 3 else "")


#: GPS - UTC (s) since 2017-01-01: the leap seconds that turn a UTC time into GPS time, unless a run says otherwise.
LEAP_SECONDS = 18.0
