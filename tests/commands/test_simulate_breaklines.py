"""The simulator's true breaklines: the river's two shores, at the water's height, falling eastwards."""

from __future__ import annotations

import numpy as np
import pyogrio.raw
import pyproj
import shapely

from commands.simulate.forward import Earth
from commands.simulate.scene import RIVER_SLOPE, WATER, make_scene
from commands.simulate.truth import write_truth_breaklines


def test_the_true_breaklines_are_the_shores_at_the_water_level(tmp_path):
    extent = (-80.0, 80.0, -75.0, 75.0)
    world, frame, crs = make_scene(extent), Earth(40.4168, -3.7038, 650.0), pyproj.CRS.from_epsg(32630)
    write_truth_breaklines(tmp_path, world, frame, crs, extent)
    meta, _, geometry, (shore,) = pyogrio.raw.read(tmp_path / "breaklines.gpkg")
    assert meta["geometry_type"] == "LineString Z" and shore.tolist() == ["river south", "river north"]
    to_ecef = pyproj.Transformer.from_crs(crs, "EPSG:4978", always_xy=True)
    centre, half = world.river
    for wkb, n in zip(geometry, (centre - half, centre + half), strict=True):
        xyz = np.asarray(shapely.from_wkb(bytes(wkb)).coords)
        enu = frame.from_ecef(np.column_stack(to_ecef.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])))
        assert np.ptp(enu[:, 0]) > 155 and np.all(np.abs(enu[:, 1] - n) < 1e-3)  # along the shore, end to end
        level = world.sample(world.ground, enu[:, 0], np.full(len(enu), centre))  # the river's water
        seen = np.isfinite(level)  # (the last vertex is the last cell's centre: a round trip may pass it)
        assert seen.sum() >= len(enu) - 1 and np.all(np.abs(enu[seen, 2] - level[seen]) < 1e-3)
        assert abs(np.polyfit(enu[:, 0], enu[:, 2], 1)[0] + RIVER_SLOPE) < 1e-6  # falling 0.3 % eastwards


def test_the_lbs_scene_holds_water_the_lidar_base_specification_flattens(tmp_path):
    extent = (-200.0, 200.0, -200.0, 200.0)
    world = make_scene(extent, water="lbs")
    centre, half = world.river
    assert 2 * half >= 30.48  # the LBS's 100 ft
    ((e0, n0, radius, level),) = world.lakes
    cell = world.cell
    rows, cols = np.indices(world.cls.shape)
    e, n = world.e0 + (cols + 0.5) * cell, world.n0 + (rows + 0.5) * cell
    lake = (world.cls == WATER) & (np.hypot(e - e0, n - n0) < radius + 1)
    assert lake.sum() * cell * cell >= 8094  # the LBS's 2 acres
    assert np.all(world.ground[lake] == level) and n0 - radius > centre + half  # level, north of the river
    across = (world.cls == WATER) & (np.abs(e - 100.25) < 0.1) & (np.abs(n - centre) < 40)  # one column
    assert abs(across.sum() * cell - 2 * half) <= cell  # the river, 31 m wide across
    frame, crs = Earth(40.4168, -3.7038, 650.0), pyproj.CRS.from_epsg(32630)
    write_truth_breaklines(tmp_path, world, frame, crs, extent)
    _, _, geometry, (names,) = pyogrio.raw.read(tmp_path / "breaklines.gpkg")
    assert names.tolist() == ["river south", "river north", "lake 1"]
    ring = shapely.from_wkb(bytes(geometry[2]))
    assert ring.is_closed and abs(shapely.Polygon(ring.coords).area - np.pi * radius**2) < 0.01 * np.pi * radius**2
