"""A non-zero boresight, from the configuration to the ground, worked by hand (SPEC 3.B/3.C and 4).

SPEC 4: the boresight R_s^b takes scanner-frame vectors into the body frame,
configured as roll, pitch, yaw (degrees) and composed R_s^b = Rz(yaw) Ry(pitch)
Rx(roll).  The parse stage writes it into the pulses' ``meta.json``; the
georeference stage reads it from there (``prepare_exact``).  With roll 90 and
yaw 90 the nadir pulse (0, 0, r) of the scanner (mirror angle 0) lands by hand:

    Rx(90):  (x, y, z) -> (x, -z, y)    (0, 0, r)  -> (0, -r, 0)
    Rz(90):  (x, y, z) -> (-y, x, z)    (0, -r, 0) -> (r, 0, 0)   body: straight ahead

The inverse (scanner-from-body) rotation would send it to (0, r, 0): starboard.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from lidar.georeferencing import georeference_local, locate, prepare_exact
from stages.parse.intermediates import lmsq_conventions


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _pulses_meta(boresight_deg, lever_arm_m=(0.0, 0.0, 0.0)):
    p = SimpleNamespace(format="lmsq_sbet", boresight_deg=boresight_deg, lever_arm_m=lever_arm_m)
    _, pulses_meta = lmsq_conventions(p, 2300)
    return pulses_meta


def test_configured_boresight_is_body_from_scanner_in_spec_order():
    roll, pitch, yaw = 1.5, -2.0, 30.0  # degrees: three distinct angles, so order and direction both matter
    meta = _pulses_meta((roll, pitch, yaw))
    want = _rz(np.radians(yaw)) @ _ry(np.radians(pitch)) @ _rx(np.radians(roll))
    np.testing.assert_allclose(np.asarray(meta["rotation"]), want, atol=1e-12)
    # a beam along the scanner's x: the body direction is the first column, (cos p cos y, cos p sin y, -sin p)
    cp, sp = np.cos(np.radians(pitch)), np.sin(np.radians(pitch))
    cy, sy = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
    np.testing.assert_allclose(np.asarray(meta["rotation"]) @ [1.0, 0.0, 0.0], [cp * cy, cp * sy, -sp], atol=1e-12)


def test_nadir_pulse_lands_ahead_with_roll_90_yaw_90():
    """Parse metadata -> georeference: level flight due north, a 100 m nadir pulse ends 100 m north."""
    meta = _pulses_meta((90.0, 0.0, 90.0), (0.5, -0.25, 1.0))
    traj_cols = {
        "time": np.array([0.0, 1.0]),
        "lat": np.full(2, 45.0),
        "lon": np.full(2, 10.0),
        "h": np.full(2, 1000.0),
        "roll": np.zeros(2),
        "pitch": np.zeros(2),
        "yaw": np.zeros(2),  # NED heading 0: body x north, y east, z down
    }
    traj, mounting = prepare_exact(traj_cols, "NED", meta)
    i, f, ok = locate(traj, np.array([0.5]), 2.0)
    assert ok.all()
    e, n, u = georeference_local(traj, np.array([0.0]), np.array([0.0]), np.array([100.0]), mounting, i, f)
    # body (100, 0, 0) + lever arm (0.5, -0.25, 1.0) = (100.5 forward, -0.25 right, 1.0 down) -> ENU
    np.testing.assert_allclose([e[0], n[0], u[0]], [-0.25, 100.5, -1.0], atol=1e-6)
