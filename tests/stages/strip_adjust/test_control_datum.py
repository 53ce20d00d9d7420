"""Ground control moves the strip datum (SPEC 6: "one strip or ground control fixing the datum").

Three parallel strips over a known smooth terrain (``tests.synthetic.terrain``,
slopes both ways), 50 m of overlap between neighbours, every strip raised by
the same 0.30 m (a GNSS height bias common to the flight).  The strips agree
with each other, so a held reference strip would keep the whole block 0.30 m
high; ground control points on the true terrain must take the datum instead,
and every strip must come down by 0.30 m onto the control.

Before -> after: the slow test_strip_adjust.py control test needs a simulated
flight (about 1 M pulses); this one writes 3 x 20 000 points (about 2 s).
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pyproj

from pipeline.cli import main
from tests.conftest import run_stages
from tests.synthetic import SAMPLE_CRS, SAMPLE_ORIGIN, terrain

BIAS = 0.30  # metres, every strip
NOISE = 0.01  # metres, height noise of the points
STRIPS = {1: 0.0, 2: 70.0, 3: 140.0}  # strip -> west edge (m); 120 m wide: 50 m overlap with each neighbour
WIDTH, LENGTH, DENSITY = 120.0, 250.0, 0.7  # metres, metres, points per m2


def _write_strips(path: Path) -> None:
    rng = np.random.default_rng(33)
    xs, ys, zs, ids = [], [], [], []
    for sid, x0 in STRIPS.items():
        n = int(WIDTH * LENGTH * DENSITY)
        x = x0 + rng.uniform(0, WIDTH, n)
        y = rng.uniform(0, LENGTH, n)
        xs.append(x)
        ys.append(y)
        zs.append(terrain(x, y) + BIAS + rng.normal(0, NOISE, n))
        ids.append(np.full(n, sid))
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001, 0.001, 0.001])
    header.offsets = np.array([SAMPLE_ORIGIN[0], SAMPLE_ORIGIN[1], 0.0])
    header.add_crs(pyproj.CRS.from_user_input(SAMPLE_CRS))
    las = laspy.LasData(header)
    las.x = np.concatenate(xs) + SAMPLE_ORIGIN[0]
    las.y = np.concatenate(ys) + SAMPLE_ORIGIN[1]
    las.z = np.concatenate(zs)
    n = len(las.x)
    las.return_number = np.ones(n, np.uint8)
    las.number_of_returns = np.ones(n, np.uint8)
    las.point_source_id = np.concatenate(ids).astype(np.uint16)
    las.gps_time = np.arange(n, dtype=np.float64) * 1e-4
    las.write(str(path))


def _write_control(path: Path) -> np.ndarray:
    """A 5 x 4 grid of control points on the true terrain, across all three strips."""
    gx, gy = np.meshgrid(np.linspace(20.0, 240.0, 5), np.linspace(30.0, 220.0, 4))
    x, y = gx.ravel(), gy.ravel()
    z = terrain(x, y)
    rows = [
        f"gcp{i},{a + SAMPLE_ORIGIN[0]:.3f},{b + SAMPLE_ORIGIN[1]:.3f},{c:.3f}"
        for i, (a, b, c) in enumerate(zip(x, y, z, strict=True))
    ]
    path.write_text("id,x,y,z\n" + "\n".join(rows) + "\n")
    return np.column_stack((x, y, z))


def test_control_points_move_the_datum_onto_the_control(tmp_path):
    _write_strips(tmp_path / "strips.las")
    _write_control(tmp_path / "gcp.csv")
    config = tmp_path / "adjust.yaml"
    config.write_text(
        f"input: {{format: las, paths: [{tmp_path}/strips.las]}}\noutput: out\ncache: cache\n"
        f"stages: {{strip_adjust: {{control_points: {tmp_path}/gcp.csv}}}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "strip_adjust"]) == 0
    stage = run_stages(tmp_path / "out")["strip_adjust"]
    assert stage["metrics"]["datum"] == "control points"
    report = json.loads((tmp_path / "out" / "strip_corrections.json").read_text())
    assert report["datum"] == "control points" and not report["not_determined"]
    for sid in STRIPS:  # every strip, the one with most overlap included, comes down by the common bias
        tx, ty, tz = report["strips"][str(sid)]["translation_m"]
        assert abs(tz + BIAS) < 0.02, (sid, tz)
        assert abs(tx) < 0.1 and abs(ty) < 0.1, (sid, tx, ty)
    # the adjusted points sit on the true terrain (the control), not 0.30 m above it
    las = laspy.read(stage["outputs"]["points_adjusted"]["file"])
    x, y = np.asarray(las.x) - SAMPLE_ORIGIN[0], np.asarray(las.y) - SAMPLE_ORIGIN[1]
    dz = np.asarray(las.z) - terrain(x, y)
    assert abs(float(np.mean(dz))) < 0.01, float(np.mean(dz))
    assert float(np.sqrt(np.mean(dz**2))) < 0.03
