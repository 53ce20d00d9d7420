"""Linear units of the output CRS, and the metric view every algorithm works in.

Products are written in the output CRS as it is, in its own units; every
parameter is stated in metres.  So each stage converts the coordinates it
reads to metres, runs its algorithm there, and converts what it writes back
to the CRS's units.  Heights are in the unit of the CRS's vertical axis when
it has one (:func:`lidar.crs.honour_vertical_keys`), else in the unit of
its horizontal axes.  The rule and why: ``docs/stages/parse.md``.

>>> import pyproj
>>> round(Units.of(pyproj.CRS.from_epsg(2263)).horizontal, 10)  # NAD83 / New York Long Island (ftUS)
0.3048006096
>>> Units.of(pyproj.CRS.from_epsg(25830)) == METRE
True
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import pyproj
from affine import Affine

if TYPE_CHECKING:
    import rasterio.crs


@dataclass(frozen=True)
class Units:
    """Metres per unit of the CRS's horizontal and vertical axes, and their names."""

    horizontal: float = 1.0
    vertical: float = 1.0
    horizontal_name: str = "metre"
    vertical_name: str = "metre"

    @classmethod
    def of(cls, crs: pyproj.CRS | None) -> Units:
        """The units of a pyproj CRS (None: metres).

        Raises
        ------
        ValueError
            When an axis has no linear unit (a geographic CRS).
        """
        if crs is None:
            return METRE
        parts = crs.sub_crs_list if crs.is_compound else [crs]
        horizontal = next((c for c in parts if not c.is_vertical), parts[0])
        vertical = next((c for c in parts if c.is_vertical), None)
        h_axis = horizontal.axis_info[0] if horizontal.axis_info else None
        if h_axis is None or h_axis.unit_name in ("degree", "radian", "grad") or not h_axis.unit_conversion_factor:
            raise ValueError(f"the CRS {crs.name} has no linear horizontal unit")
        v_axis = vertical.axis_info[0] if vertical is not None and vertical.axis_info else h_axis
        return cls(
            float(h_axis.unit_conversion_factor),
            float(v_axis.unit_conversion_factor),
            _name(h_axis.unit_name),
            _name(v_axis.unit_name),
        )

    @property
    def is_metre(self) -> bool:
        return self.horizontal == 1.0 and self.vertical == 1.0

    def to_metres(self, xyz: np.ndarray) -> np.ndarray:
        """(n, 3) coordinates in CRS units -> metres (a copy only when the units are not metres)."""
        if self.is_metre:
            return xyz
        return np.asarray(xyz, dtype=np.float64) * np.array([self.horizontal, self.horizontal, self.vertical])

    def from_metres(self, xyz: np.ndarray) -> np.ndarray:
        """(n, 3) coordinates in metres -> CRS units."""
        if self.is_metre:
            return xyz
        return np.asarray(xyz, dtype=np.float64) / np.array([self.horizontal, self.horizontal, self.vertical])

    def transform_from_metres(self, transform: Affine) -> Affine:
        """A raster's affine transform built in metres -> the same grid in CRS units."""
        if self.horizontal == 1.0:
            return transform
        return Affine.scale(1.0 / self.horizontal) @ transform

    def transform_to_metres(self, transform: Affine) -> Affine:
        """A raster's affine transform in CRS units -> metres."""
        if self.horizontal == 1.0:
            return transform
        return Affine.scale(self.horizontal) @ transform

    def describe(self) -> str:
        """'x, y in US survey foot (0.3048006 m), heights in US survey foot' - for logs and the report."""

        def one(name: str, factor: float) -> str:
            return name if factor == 1.0 else f"{name} ({factor:.7g} m)"

        return (
            f"x, y in {one(self.horizontal_name, self.horizontal)}, heights in {one(self.vertical_name, self.vertical)}"
        )


def _name(unit: str) -> str:
    return "metre" if unit in ("metre", "meter", "m") else unit


METRE = Units()


def raster_units(crs: rasterio.crs.CRS | str | None) -> Units:
    """Units of a rasterio CRS (through pyproj)."""
    if crs is None:
        return METRE

    return Units.of(pyproj.CRS.from_user_input(crs.to_wkt() if hasattr(crs, "to_wkt") else crs))
