"""Geodesy for georeferencing: WGS 84 geodetic -> ECEF, local-level frames, map projection.

Every transform between datums and projections is pyproj's (PROJ).  What is
ours is how it is applied to millions of points fast *without* giving up
exactness (:class:`MapTransform`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pyproj

from lidar.units import Units


def _transformer(src, dst):
    return pyproj.Transformer.from_crs(src, dst, always_xy=True)


def geodetic_to_ecef(lat_deg: np.ndarray, lon_deg: np.ndarray, h: np.ndarray) -> np.ndarray:
    """WGS 84 latitude, longitude (degrees), ellipsoidal height -> ECEF (n, 3) metres (pyproj)."""
    x, y, z = _transformer("EPSG:4979", "EPSG:4978").transform(
        np.asarray(lon_deg, float), np.asarray(lat_deg, float), np.asarray(h, float)
    )
    return np.column_stack((x, y, z))


def local_level_to_ecef(lat_deg: np.ndarray, lon_deg: np.ndarray, frame: str = "NED") -> np.ndarray:
    """R_n^e: matrices (n, 3, 3) whose columns are the local-level axes in ECEF.

    ``NED``: north, east, down (aviation, INS, SBET).  ``NWU``: north, west,
    up (the Xsens MTi-G).  ``ENU``: east, north, up.

    >>> m = local_level_to_ecef(np.array([0.0]), np.array([0.0]), "NED")[0]
    >>> (m @ [0, 0, 1]).round(12) + 0.0  # down at (0 N, 0 E) is -X
    array([-1.,  0.,  0.])
    """
    lat = np.radians(np.asarray(lat_deg, dtype=np.float64))
    lon = np.radians(np.asarray(lon_deg, dtype=np.float64))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    north = np.stack((-sl * co, -sl * so, cl), -1)
    east = np.stack((-so, co, np.zeros_like(lat)), -1)
    up = np.stack((cl * co, cl * so, sl), -1)
    axes = {"NED": (north, east, -up), "NWU": (north, -east, up), "ENU": (east, north, up)}[frame]
    return np.stack(axes, -1)


WGS84_A = 6_378_137.0  # semi-major axis, metres
WGS84_E2 = 6.69437999014e-3  # first eccentricity squared


def radii_of_curvature(lat_deg: float) -> tuple[float, float]:
    """WGS 84 radii of curvature at a latitude (degrees): meridian M and prime vertical N, metres.

    >>> [round(float(r)) for r in radii_of_curvature(0.0)]
    [6335439, 6378137]
    """
    w = 1.0 - WGS84_E2 * np.sin(np.radians(lat_deg)) ** 2
    return WGS84_A * (1 - WGS84_E2) / w**1.5, WGS84_A / np.sqrt(w)


def ltp_predicted_departure(
    platform: np.ndarray, lat0: float, h0: float, radius: float
) -> tuple[np.ndarray, np.ndarray]:
    """What geometry predicts for the seed-0 ltp plane's error at platform positions (local ENU, n x 3).

    The platform is placed with the sphere's *radius* instead of the radii of
    curvature at its height, M + h and N + h, and the tangent plane rises over
    the ellipsoid by d^2 / 2R.  Returns the horizontal and vertical figures,
    metres.  The pulse offsets are added in the plane, which tilts by d/R
    against the true local level: a term left out.
    """
    radius_m, radius_n = radii_of_curvature(lat0)
    h_p = h0 + platform[:, 2]
    horizontal = np.hypot(
        (radius / (radius_n + h_p) - 1) * platform[:, 0], (radius / (radius_m + h_p) - 1) * platform[:, 1]
    )
    vertical = (platform[:, 0] ** 2 + platform[:, 1] ** 2) / (2 * np.sqrt(radius_m * radius_n))
    return horizontal, vertical


@dataclass
class LocalFrame:
    """A Cartesian east-north-up frame tangent to WGS 84 at an origin: a rigid transform of ECEF.

    Georeferencing works in it (small numbers, exact: no approximation is
    involved); :class:`MapTransform` takes points from it to the output CRS.
    """

    lat0: float
    lon0: float
    h0: float

    def __post_init__(self) -> None:
        self.origin = geodetic_to_ecef([self.lat0], [self.lon0], [self.h0])[0]
        self.r_enu_to_ecef = local_level_to_ecef(np.array([self.lat0]), np.array([self.lon0]), "ENU")[0]

    def from_ecef(self, xyz: np.ndarray) -> np.ndarray:
        return (np.asarray(xyz) - self.origin) @ self.r_enu_to_ecef

    def to_ecef(self, enu: np.ndarray) -> np.ndarray:
        return np.asarray(enu) @ self.r_enu_to_ecef.T + self.origin

    def from_geodetic(self, lat_deg: np.ndarray, lon_deg: np.ndarray, h: np.ndarray) -> np.ndarray:
        return self.from_ecef(geodetic_to_ecef(lat_deg, lon_deg, h))


def _monomials(p: np.ndarray) -> np.ndarray:
    """The 20 monomials of degree <= 3 of the rows of (n, 3) *p*, as an (n, 20) matrix."""
    e, n, u = p[:, 0], p[:, 1], p[:, 2]
    out = np.empty((len(p), 20))
    out[:, 0] = 1.0
    out[:, 1], out[:, 2], out[:, 3] = e, n, u
    out[:, 4], out[:, 5], out[:, 6] = e * e, e * n, n * n
    out[:, 7], out[:, 8], out[:, 9] = e * u, n * u, u * u
    out[:, 10], out[:, 11] = out[:, 4] * e, out[:, 4] * n
    out[:, 12], out[:, 13] = out[:, 6] * e, out[:, 6] * n
    out[:, 14], out[:, 15], out[:, 16] = out[:, 4] * u, out[:, 5] * u, out[:, 6] * u
    out[:, 17], out[:, 18], out[:, 19] = out[:, 9] * e, out[:, 9] * n, out[:, 9] * u
    return out


class MapTransform:
    """Local ENU -> output CRS (easting, northing, height), exact to ``tolerance`` (m).

    The exact transform is pyproj's (ECEF -> CRS, with the geoid grid when
    one is given).  Over the box *lo*..*hi* it is replaced by a cubic
    polynomial in local (e, n, u) fitted to PROJ on a lattice and checked
    against PROJ at random points: ``max_error_m`` records the check, and
    ``method`` is ``polynomial`` when it is within *tolerance*, else
    ``proj`` (every point through PROJ).  Why this is exact and fast:
    docs/stages/georeference.md.
    """

    def __init__(
        self,
        frame: LocalFrame,
        crs: pyproj.CRS,
        lo: np.ndarray,
        hi: np.ndarray,
        *,
        tolerance: float = 1e-4,
        geoid: Path | None = None,
    ):
        self.frame = frame
        self.crs = crs
        self.geoid = geoid
        self._exact = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True)
        # PROJ leaves the ellipsoidal height in metres when the CRS has no vertical axis; heights are
        # written in the CRS's units (lidar.units: its horizontal unit then), so scale them here
        self._height_unit = 1.0 if len(crs.axis_info) >= 3 else Units.of(crs).vertical
        if geoid is not None:
            pipeline = (
                "+proj=pipeline +step +proj=cart +inv +ellps=WGS84 "
                f"+step +proj=vgridshift +grids={geoid} +multiplier=-1 "
                "+step +inv +proj=longlat +ellps=WGS84 +step +proj=cart +ellps=WGS84"
            )
            self._geoid = pyproj.Transformer.from_pipeline(pipeline)
        self.lo = np.asarray(lo, dtype=np.float64) - 1.0
        self.hi = np.asarray(hi, dtype=np.float64) + 1.0
        self.centre = (self.lo + self.hi) / 2
        self.half = np.maximum((self.hi - self.lo) / 2, 1.0)
        grid = [np.linspace(-1, 1, 9)] * 3
        lattice = np.stack(np.meshgrid(*grid, indexing="ij"), -1).reshape(-1, 3)
        local = self.centre + lattice * self.half
        self.coef, *_ = np.linalg.lstsq(_monomials(lattice), self.exact(local), rcond=None)
        rng = np.random.default_rng(0)
        check = self.centre + rng.uniform(-1, 1, (4000, 3)) * self.half
        self.max_error_m = float(np.max(np.abs(self._poly(check) - self.exact(check))))
        self.method = "polynomial" if self.max_error_m <= tolerance else "proj"

    def exact(self, local: np.ndarray) -> np.ndarray:
        """PROJ, point by point."""
        ecef = self.frame.to_ecef(local)
        if self.geoid is not None:
            # vgridshift on geodetic heights: ECEF of the point lowered by the geoid height
            ecef = np.column_stack(self._geoid.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2]))
        x, y, z = self._exact.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
        return np.column_stack((x, y, np.asarray(z) / self._height_unit))

    def _poly(self, local: np.ndarray) -> np.ndarray:
        return np.column_stack(self.poly_columns(local[:, 0], local[:, 1], local[:, 2]))

    def poly_columns(self, e: np.ndarray, n: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
        """The polynomial on contiguous 1-D columns, in nested (Horner) form: no (n, 20) matrix."""
        e = (e - self.centre[0]) * (1.0 / self.half[0])
        n = (n - self.centre[1]) * (1.0 / self.half[1])
        u = (u - self.centre[2]) * (1.0 / self.half[2])
        out = []
        for k in range(3):
            c = self.coef[:, k]
            a = c[1] + e * (c[4] + c[10] * e + c[11] * n + c[14] * u) + n * (c[5] + c[12] * n + c[15] * u) + c[7] * u
            b = c[2] + n * (c[6] + c[13] * n + c[16] * u) + c[8] * u
            d = c[3] + u * (c[9] + c[17] * e + c[18] * n + c[19] * u)
            out.append(c[0] + e * a + n * b + u * d)
        return tuple(out)

    def columns(self, e: np.ndarray, n: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, ...]:
        """Output-CRS columns of local ENU columns."""
        if self.method == "polynomial":
            return self.poly_columns(e, n, u)
        xyz = self.exact(np.column_stack((e, n, u)))
        return xyz[:, 0], xyz[:, 1], xyz[:, 2]

    def __call__(self, local: np.ndarray) -> np.ndarray:
        """Output-CRS coordinates of (n, 3) local ENU points."""
        if self.method == "polynomial":
            return self._poly(local)
        return self.exact(local)
