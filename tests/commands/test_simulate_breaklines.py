"""The simulator's true breaklines: the river's two shores, at the water's height, falling eastwards."""

from __future__ import annotations

import numpy as np
import pyproj

from dtm.commands.simulate.forward import Earth
from dtm.commands.simulate.scene import RIVER_SLOPE, make_scene, river_band
from dtm.commands.simulate.truth import write_truth_breaklines


def test_the_true_breaklines_are_the_shores_at_the_water_level(tmp_path):
    import pyogrio.raw
    import shapely

    extent = (-80.0, 80.0, -75.0, 75.0)
    world, frame, crs = make_scene(extent), Earth(40.4168, -3.7038, 650.0), pyproj.CRS.from_epsg(32630)
    write_truth_breaklines(tmp_path, world, frame, crs, extent)
    meta, _, geometry, (shore,) = pyogrio.raw.read(tmp_path / "breaklines.gpkg")
    assert meta["geometry_type"] == "LineString Z" and shore.tolist() == ["south", "north"]
    to_ecef = pyproj.Transformer.from_crs(crs, "EPSG:4978", always_xy=True)
    centre, half = river_band(extent[2], extent[3] - extent[2])
    for wkb, n in zip(geometry, (centre - half, centre + half), strict=True):
        xyz = np.asarray(shapely.from_wkb(bytes(wkb)).coords)
        enu = frame.from_ecef(np.column_stack(to_ecef.transform(xyz[:, 0], xyz[:, 1], xyz[:, 2])))
        assert np.ptp(enu[:, 0]) > 155 and np.all(np.abs(enu[:, 1] - n) < 1e-3)  # along the shore, end to end
        level = world.sample(world.ground, enu[:, 0], np.full(len(enu), centre))  # the river's water
        seen = np.isfinite(level)  # (the last vertex is the last cell's centre: a round trip may pass it)
        assert seen.sum() >= len(enu) - 1 and np.all(np.abs(enu[seen, 2] - level[seen]) < 1e-3)
        assert abs(np.polyfit(enu[:, 0], enu[:, 2], 1)[0] + RIVER_SLOPE) < 1e-6  # falling 0.3 % eastwards
