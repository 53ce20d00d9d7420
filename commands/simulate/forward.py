"""The simulator's own geometry: rotations, the local frame, and the map transform.

The simulator builds the truth that georeferencing is checked against, so it
must not build it with the code it checks (issue 19): nothing here comes from
:mod:`lidar.georeferencing`.  Rotations are scipy's ``Rotation``; ECEF,
the local east-north-up frame and the output CRS are PROJ (``EPSG:4979`` <->
``EPSG:4978``, the ``topocentric`` conversion).  Only the local-level axes at
a point are written out, as ``Rz(lon + 90 deg) Rx(90 deg - lat)`` (e.g.
Hofmann-Wellenhof et al. 2008, *GNSS*, doi:10.1007/978-3-211-73017-1); a test
checks them against PROJ.

Conventions (those of the files the simulator writes): body axes
forward-right-down, attitude ``R_ned<-body = Rz(heading) Ry(pitch) Rx(roll)``
(aviation; heading clockwise from north), the mounting ``R_body<-scanner``.
"""

from __future__ import annotations

import numpy as np
import pyproj
from scipy.spatial.transform import Rotation, Slerp

#: NED axes as rows of ENU: v_enu = NED_TO_ENU @ v_ned
NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
#: NED <-> NWU and forward-right-down <-> forward-left-up
D_FLIP = np.diag([1.0, -1.0, -1.0])


def attitude(roll: np.ndarray, pitch: np.ndarray, heading: np.ndarray) -> Rotation:
    """``R_ned<-body`` of aviation Euler angles (radians): Rz(heading) Ry(pitch) Rx(roll).

    >>> bool(np.allclose(attitude(0.0, 0.0, np.pi / 2).apply([1.0, 0.0, 0.0]), [[0.0, 1.0, 0.0]]))
    True
    """
    angles = np.column_stack([np.ravel(a) for a in np.broadcast_arrays(heading, pitch, roll)])
    return Rotation.from_euler("ZYX", angles.astype(np.float64))


def mounting_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """A mounting or boresight rotation (3, 3): Rz(yaw) Ry(pitch) Rx(roll), radians."""
    return Rotation.from_euler("ZYX", [yaw, pitch, roll]).as_matrix()


def enu_axes(lat_deg: np.ndarray, lon_deg: np.ndarray) -> Rotation:
    """``R_ecef<-enu`` at geodetic latitude and longitude (degrees): Rz(lon + 90) Rx(90 - lat)."""
    lat, lon = np.broadcast_arrays(np.asarray(lat_deg, np.float64), np.asarray(lon_deg, np.float64))
    angles = np.column_stack((lon.ravel() + 90.0, 90.0 - lat.ravel()))
    return Rotation.from_euler("ZX", angles, degrees=True)


class Earth:
    """WGS 84 around the survey: the local ENU frame at an origin, geodetic coordinates, the output CRS."""

    def __init__(self, lat0: float, lon0: float, h0: float):
        self.lat0, self.lon0, self.h0 = float(lat0), float(lon0), float(h0)
        self._topo = pyproj.Transformer.from_pipeline(
            f"+proj=topocentric +ellps=WGS84 +lat_0={float(self.lat0)!r} +lon_0={float(self.lon0)!r} +h_0={float(self.h0)!r}"
        )
        self._to_geodetic = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
        #: R_enu(origin)<-ecef
        self.enu_from_ecef = enu_axes(self.lat0, self.lon0)[0].inv()

    def to_ecef(self, enu: np.ndarray) -> np.ndarray:
        """ECEF (n, 3) of local ENU points (n, 3)."""
        enu = np.atleast_2d(np.asarray(enu, np.float64))
        x, y, z = self._topo.transform(enu[:, 0], enu[:, 1], enu[:, 2], direction="INVERSE")
        return np.column_stack((x, y, z))

    def from_ecef(self, xyz: np.ndarray) -> np.ndarray:
        """Local ENU (n, 3) of ECEF points (n, 3)."""
        xyz = np.atleast_2d(np.asarray(xyz, np.float64))
        e, n, u = self._topo.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])
        return np.column_stack((e, n, u))

    def geodetic(self, enu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Latitude, longitude (degrees) and ellipsoidal height of local ENU points."""
        ecef = self.to_ecef(enu)
        lon, lat, h = self._to_geodetic.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
        return np.asarray(lat), np.asarray(lon), np.asarray(h)

    def from_geodetic(self, lat_deg, lon_deg, h) -> np.ndarray:
        """Local ENU (n, 3) of geodetic points (degrees, metres)."""
        x, y, z = self._to_geodetic.transform(
            np.asarray(lon_deg, float), np.asarray(lat_deg, float), np.asarray(h, float), direction="INVERSE"
        )
        return self.from_ecef(np.column_stack((x, y, z)))

    def local_from_body(self, lat_deg, lon_deg, roll, pitch, heading) -> Rotation:
        """``R_enu(origin)<-body`` at points of latitude/longitude (degrees), aviation angles in radians."""
        ned = Rotation.from_matrix(NED_TO_ENU)  # R_enu<-ned, the same at every point
        return self.enu_from_ecef * enu_axes(lat_deg, lon_deg) * ned * attitude(roll, pitch, heading)

    def to_crs(self, crs) -> MapProjection:
        """The exact local ENU -> *crs* transform, point by point through PROJ."""
        return MapProjection(self, crs)


class MapProjection:
    """Local ENU (n, 3) -> output CRS (n, 3): PROJ for every point, heights in the CRS's units.

    A CRS without a vertical axis gets the ellipsoidal height in its horizontal unit (the LAS
    practice the pipeline follows, see :mod:`lidar.units`).
    """

    def __init__(self, earth: Earth, crs):
        self.earth, self.crs = earth, crs
        self._to_crs = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True)
        axes = crs.axis_info
        self._height_unit = 1.0 if len(axes) >= 3 else float(axes[0].unit_conversion_factor or 1.0)

    def __call__(self, enu: np.ndarray) -> np.ndarray:
        ecef = self.earth.to_ecef(enu)
        x, y, z = self._to_crs.transform(ecef[:, 0], ecef[:, 1], ecef[:, 2])
        return np.column_stack((x, y, np.asarray(z) / self._height_unit))


class RecordedPose:
    """Pose at any time from recorded navigation epochs: position linear, attitude SLERP.

    What a vendor's georeferencing does with an SBET: positions interpolated
    linearly between epochs, the rotation ``R_enu<-body`` by spherical linear
    interpolation (Shoemake 1985, doi:10.1145/325165.325242).
    """

    def __init__(self, earth: Earth, t, lat, lon, h, roll_deg, pitch_deg, heading_deg):
        self.t = np.asarray(t, np.float64)
        self.pos = earth.from_geodetic(lat, lon, h)
        rot = earth.local_from_body(lat, lon, np.radians(roll_deg), np.radians(pitch_deg), np.radians(heading_deg))
        self._slerp = Slerp(self.t, rot)

    def points(self, t: np.ndarray, v_s: np.ndarray, rotation: np.ndarray, lever_arm: np.ndarray) -> np.ndarray:
        """Local ENU (n, 3) of scanner vectors *v_s* (n, 3) measured at times *t* inside the epochs."""
        t = np.asarray(t, np.float64)
        if len(t) and (t.min() < self.t[0] or t.max() > self.t[-1]):
            raise ValueError("pulse times outside the recorded navigation")
        pos = np.column_stack([np.interp(t, self.t, self.pos[:, k]) for k in range(3)])
        body = np.asarray(v_s, np.float64) @ np.asarray(rotation).T + np.asarray(lever_arm)
        return pos + self._slerp(t).apply(body)
