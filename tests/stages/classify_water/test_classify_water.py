"""The ``classify_water`` stage in runs: classes, the DTM over water, tiles, polygons and their CRS (issue 34)."""

from __future__ import annotations

import json
import sqlite3
import struct
from pathlib import Path

import laspy
import numpy as np
import pyogrio
import pyogrio.raw
import pyproj
import pytest
import shapely

from lidar.rasters import read_raster
from pipeline.cli import main
from tests.conftest import run_until
from tests.stages.denoise.test_noise_classes import X0, Y0, write_las

LEVEL = 100.6


def _lakes(size: float, lakes: list[tuple[float, float, float]], seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A square survey of side *size* (local metres, 2 points/m2): valleys at least 4 % steep around round lakes
    (x, y, radius) whose water lies 0.4 m under their shore.  Returns the points and which are on a lake."""
    rng = np.random.default_rng(seed)
    n = int(size * size * 2)
    x, y = rng.uniform(0, size, n), rng.uniform(0, size, n)
    z = np.full(n, np.inf)
    lake = np.zeros(n, bool)
    for cx, cy, r in lakes:
        z = np.minimum(z, LEVEL + 0.4 + 0.04 * np.maximum(np.abs(x - cx) + np.abs(y - cy) - r, 0.0))
        lake |= np.hypot(x - cx, y - cy) < r
    z = np.where(lake, LEVEL, z) + rng.normal(0, 0.02, n)
    return np.column_stack((x, y, z)), lake


def _config(root: Path, las: Path, stages: str = "") -> Path:
    config = root / "water.yaml"
    config.write_text(
        f"name: water\ninput: {{format: las, paths: [{las}]}}\noutput: out\ncache: cache\n"
        "executor: {kind: local, workers: 1}\nstages:\n  rasterize: {resolution: 1.0}\n" + stages
    )
    return config


def _classes(stage: dict) -> np.ndarray:
    return np.asarray(laspy.read(stage["outputs"]["points_water"]["file"]).classification)


@pytest.fixture(scope="module")
def one_lake(tmp_path_factory):
    root = tmp_path_factory.mktemp("lake")
    xyz, lake = _lakes(120.0, [(60.0, 60.0, 25.0)])
    las = write_las(root / "lake.las", xyz)
    stages = run_until(_config(root, las), "rasterize", root / "out")
    return root, stages, lake


def test_the_lake_is_water_and_the_valley_ground(one_lake):
    _, stages, lake = one_lake
    cls = _classes(stages["classify_water"])
    assert np.all(cls[lake] == 9)
    assert np.mean(np.isin(cls[~lake], (2, 20))) > 0.99  # ground, or ignored ground at the shore
    m = stages["classify_water"]["metrics"]
    assert m["water"] == m["from_points"] == m["ground_to_water"] == lake.sum() and m["from_polygons"] == 0


def _centre_cells(root: Path, product: str = "dtm.tif") -> np.ndarray:
    dtm, transform, *_ = read_raster(root / product)
    col = int((X0 + 60.0 - transform.c) / transform.a)
    row = int((Y0 + 60.0 - transform.f) / transform.e)
    return dtm[row - 15 : row + 15, col - 15 : col + 15]  # 15 m around the centre: all lake


def test_the_dtm_is_flat_at_the_water_level_over_the_lake(one_lake):
    root, stages, _ = one_lake
    centre = _centre_cells(root / "out")
    assert len(np.unique(centre)) == 1 and abs(float(centre[0, 0]) - LEVEL) < 0.01
    bodies = stages["classify_water"]["metrics"]["bodies"]
    assert bodies["polygons"] == bodies["flattened"] == 1
    assert float(centre[0, 0]) == np.float32(bodies["levels_m"][0])


def test_water_gpkg_is_one_polygon_z_at_the_level_in_a_geopackage_1_2(one_lake):
    path = one_lake[0] / "out" / "water.gpkg"
    info = pyogrio.read_info(path)
    assert info["geometry_type"] == "Polygon Z" and info["features"] == 1 and info["crs"] == "EPSG:25830"
    with sqlite3.connect(path) as db:
        assert db.execute("pragma user_version").fetchone()[0] == 10200  # GeoPackage 1.2
    meta, _, geometry, values = pyogrio.raw.read(path, columns=["level", "flattened", "area_m2"])
    fields = dict(zip(meta["fields"], values, strict=True))
    wkb = bytes(geometry[0])
    n = int(np.frombuffer(wkb, "<u4", 1, 9)[0])
    xyz = np.frombuffer(wkb, "<f8", 3 * n, 13).reshape(n, 3)
    assert np.all(xyz[:, 2] == fields["level"][0]) and fields["flattened"][0] == 1
    assert abs(fields["area_m2"][0] - np.pi * 25**2) < 2 * np.pi * 25  # within a metre of the shore
    r = np.hypot(xyz[:, 0] - X0 - 60, xyz[:, 1] - Y0 - 60)
    assert np.all((r > 22) & (r < 27))


def test_breaklines_gpkg_is_the_shore_at_the_level_in_3d(one_lake):
    out = one_lake[0] / "out"
    info = pyogrio.read_info(out / "breaklines.gpkg")
    assert info["geometry_type"] == "MultiLineString Z" and info["features"] == 1 and info["crs"] == "EPSG:25830"
    with sqlite3.connect(out / "breaklines.gpkg") as db:
        assert db.execute("pragma user_version").fetchone()[0] == 10200  # GeoPackage 1.2
    meta, _, geometry, values = pyogrio.raw.read(out / "breaklines.gpkg")
    fields = dict(zip(meta["fields"], values, strict=True))
    assert fields["water_body"][0] == 1 and fields["kind"][0] == "lake"
    (line,) = shapely.from_wkb(bytes(geometry[0])).geoms  # the whole shore: the lake lies inside the survey
    xyz = np.asarray(line.coords)
    assert np.all(xyz[:, 2] == fields["level"][0]) and np.array_equal(xyz[0], xyz[-1])
    polygon = shapely.from_wkb(bytes(pyogrio.raw.read(out / "water.gpkg")[2][0]))
    assert shapely.distance(polygon.boundary, shapely.points(xyz[:, :2])).max() < 1e-9  # on its outline


def test_ground_at_the_shore_is_ignored_ground_and_the_rest_stays(one_lake):
    """Class 20 within 0.7 m (``ignored_ground``) of the lake's outline in water.gpkg, the hydro breakline."""
    root, stages, lake = one_lake
    cls = _classes(stages["classify_water"])
    geometry = pyogrio.raw.read(root / "out" / "water.gpkg")[2]
    shore = shapely.from_wkb(bytes(geometry[0])).boundary
    las = laspy.read(str(root / "lake.las"))
    d = shapely.distance(shore, shapely.points(np.asarray(las.x), np.asarray(las.y)))
    ground = np.isin(cls, (2, 20))  # not water
    assert np.all(cls[ground & (d < 0.69)] == 20)
    assert not np.any(cls[d > 0.71] == 20)
    assert stages["classify_water"]["metrics"]["ignored_ground"] == int((cls == 20).sum()) > 100


def test_without_hydro_flattening_the_dtm_follows_the_water_points(one_lake):
    root, _, _ = one_lake
    run_until(root / "water.yaml", "rasterize", root / "rough", "stages.rasterize.hydro_flatten=false")
    centre = _centre_cells(root / "rough")
    assert len(np.unique(centre)) > 100 and np.all(np.abs(centre - LEVEL) < 0.1)


def test_disabled_the_stage_passes_the_ground_classes_on(one_lake):
    root, _, _ = one_lake
    stages = run_until(root / "water.yaml", "rasterize", root / "off", "stages.classify_water.enabled=false")
    ground = stages["classify_ground"]["outputs"]["points_classified"]["sha256"]
    assert stages["classify_objects"]["inputs"]["points_water"] == ground  # the next stage reads the ground's
    assert stages["classify_water"]["status"] == "disabled"


#: The run modes of the water grid (300 x 300 cells of 1 m) cut in 100 m tiles: tiles of points, the grid in the
#: tiles' windows (a cap under the grid, within 4 times it), the grid whole.
MODES = {
    "points": ("stages.classify_water.one_grid_cells=0",),
    "windows": ("stages.classify_water.one_grid_cells=40000",),
    "grid": (),
}


@pytest.fixture(scope="module")
def lakes(tmp_path_factory):
    """Lakes cut by the tile edges x, y = 100, 200 m, and their classes untiled.  The one centred at (150, 118),
    20 m wide, reaches 2 m into the tile below y = 100: its shore there is water because the lake's level cells
    beyond the edge make a body of 70 m2 or more.  A tile or window that sees 5 m across the edge sees under
    70 m2 of them and leaves the shore ground."""
    tmp = tmp_path_factory.mktemp("lakes")
    xyz, lake = _lakes(300.0, [(100.0, 150.0, 30.0), (200.0, 200.0, 12.0), (150.0, 118.0, 20.0), (260.0, 60.0, 40.0)])
    config = _config(tmp, write_las(tmp / "lakes.las", xyz))
    untiled = run_until(config, "rasterize", tmp / "untiled", "tiling.enabled=false", *MODES["points"])
    a = _classes(untiled["classify_water"])
    assert (a[lake] == 9).mean() > 0.99 and (a[~lake] == 9).mean() < 0.001
    shore = lake & (xyz[:, 1] < 100)
    assert np.all(a[shore] == 9)
    return tmp, config, a, shore


def _mode_equals_untiled(lakes, mode: str) -> dict:
    """The mode's run in 100 m tiles: its classes and DTM those of the untiled run; a buffer of 5 m shows."""
    tmp, config, a, shore = lakes
    tiled = run_until(config, "rasterize", tmp / mode, "tiling.size=100", *MODES[mode])
    np.testing.assert_array_equal(_classes(tiled["classify_water"]), a, err_msg=mode)
    np.testing.assert_array_equal(read_raster(tmp / mode / "dtm.tif")[0], read_raster(tmp / "untiled" / "dtm.tif")[0])
    if mode != "grid":  # a buffer short of the stage's reach shows where the work is cut
        sets = ("tiling.size=100", "tiling.buffer=5", *MODES[mode])
        narrow = run_until(config, "classify_water", tmp / f"narrow-{mode}", *sets)
        assert np.any(_classes(narrow["classify_water"])[shore] != 9), mode
    return tiled["classify_water"]["metrics"]["tiling"]


def test_the_grid_whole_and_in_windows_equals_untiled(lakes):
    assert _mode_equals_untiled(lakes, "grid")["executor"] == "one grid, this process"
    windows = _mode_equals_untiled(lakes, "windows")
    assert windows["tiles"] == 9 and windows["executor"].startswith("one grid in windows")


@pytest.mark.slow  # three more runs of the lakes (about 8 s)
def test_tiles_of_points_equal_untiled(lakes):
    tiling = _mode_equals_untiled(lakes, "points")
    assert tiling["tiles"] == 9 and "extent" in tiling


def _polygon_layer(path: Path, rings: list[np.ndarray], epsg: int) -> Path:
    """A GeoPackage of one PolygonZ (z = 0) with *rings* in local metres."""
    parts = [struct.pack("<BII", 1, 1003, len(rings))]
    for ring in rings:
        xyz = np.column_stack((ring[:, 0] + X0, ring[:, 1] + Y0, np.zeros(len(ring))))
        parts.append(struct.pack("<I", len(ring)) + xyz.astype("<f8").tobytes())
    geometry = np.empty(1, dtype=object)
    geometry[0] = b"".join(parts)
    pyogrio.raw.write(
        str(path),
        geometry=geometry,
        field_data=[np.array([1])],
        fields=["id"],
        layer="water",
        driver="GPKG",
        geometry_type="Polygon Z",
        crs=pyproj.CRS.from_epsg(epsg).to_wkt(),
    )
    return path


def _circle(cx: float, cy: float, r: float) -> np.ndarray:
    t = np.linspace(0, 2 * np.pi, 73)
    return np.column_stack((cx + r * np.cos(t), cy + r * np.sin(t)))


def test_polygons_make_water_without_detection(tmp_path):
    """A polygon 5 m wider than the lake, with an island (a hole): the lake's points are water, its shore (0.4 m
    above) and the island's points (at the water level, but outside the polygon) are not."""
    xyz, lake = _lakes(120.0, [(60.0, 60.0, 25.0)])
    island = np.hypot(xyz[:, 0] - 60, xyz[:, 1] - 60) < 4
    layer = _polygon_layer(tmp_path / "water.gpkg", [_circle(60, 60, 30), _circle(60, 60, 4.5)[::-1]], 25830)
    las = write_las(tmp_path / "lake.las", xyz)
    stages = f"  classify_water: {{polygons: {layer}, detect: {{enabled: false}}, polygon_height: 0.3}}\n"
    got = run_until(_config(tmp_path, las, stages), "classify_water", tmp_path / "out")
    cls = _classes(got["classify_water"])
    within = lake & ~(np.hypot(xyz[:, 0] - 60, xyz[:, 1] - 60) < 4.5)
    assert np.all(cls[within] == 9)
    assert not np.any(cls[~lake] == 9) and not np.any(cls[island] == 9)
    assert got["classify_water"]["metrics"]["from_polygons"] == within.sum()


def test_polygons_in_another_crs_are_one_sentence_exit_3(tmp_path, capsys):
    xyz, _ = _lakes(60.0, [(30.0, 30.0, 10.0)])
    layer = _polygon_layer(tmp_path / "water.gpkg", [_circle(30, 30, 12)], 25831)
    las = write_las(tmp_path / "lake.las", xyz)
    config = _config(tmp_path, las, f"  classify_water: {{polygons: {layer}}}\n")
    assert main(["run", str(config), "-q", "--until", "classify_water"]) == 3
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    assert "water.gpkg" in err and "ETRS89 / UTM zone 31N" in err and "reproject" in err
    assert json.loads((tmp_path / "out" / "run.json").read_text())["status"] == "failed"


def _car_park() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A level 40 m x 40 m paved square draining away at 2 % on every side, beside a lake: the points, the
    lake's and the square's, and each point's Chebyshev distance (m) from the square's centre."""
    rng = np.random.default_rng(4)
    xyz, lake = _lakes(160.0, [(120.0, 80.0, 25.0)])
    x, y = xyz[:, 0], xyz[:, 1]
    d = np.maximum(np.abs(x - 40), np.abs(y - 80))
    park = (d < 20) & ~lake
    near = (d < 60) & (x < 90)
    xyz[near, 2] = np.where(park[near], 103.0, 103.0 - 0.02 * (d[near] - 20)) + rng.normal(0, 0.02, near.sum())
    return xyz, lake, park, d


def test_a_level_car_park_is_given_its_ground_class_back(tmp_path):
    """A level 40 m x 40 m paved square draining away at 2 % on every side: level enough to be found, but its
    banks do not rise above it, so its points are ground again; the lake beside it stays water."""
    xyz, lake, park, _ = _car_park()
    las = write_las(tmp_path / "park.las", xyz)
    got = run_until(_config(tmp_path, las), "classify_water", tmp_path / "out")
    cls = _classes(got["classify_water"])
    assert not np.any(cls[park] == 9) and np.mean(cls[park] == 2) > 0.99
    assert np.all(cls[lake] == 9)
    m = got["classify_water"]["metrics"]
    assert m["given_back"] >= park.sum() * 0.9 and m["water"] == int((cls == 9).sum())
    assert m["bodies"]["refused_cells"] > 1000
    # without the banks' test the square is found: level, 1,600 m2
    loose = run_until(
        _config(tmp_path, las), "classify_water", tmp_path / "loose", "stages.classify_water.detect.min_bank=-100"
    )
    assert np.mean(_classes(loose["classify_water"])[park] == 9) > 0.95


def test_the_inputs_own_water_is_kept_and_counted(tmp_path):
    """The car park above, with a 10 m square of it labelled water (9) in the input: the square stays water
    when the park is given back, and the counts are of the stage's own water (an input's own water counted
    as given back made them negative)."""
    xyz, lake, park, d = _car_park()
    own = d < 5
    las = write_las(tmp_path / "park.las", xyz, cls=np.where(own, 9, 0).astype(np.uint8))
    got = run_until(_config(tmp_path, las), "classify_water", tmp_path / "out")
    cls = _classes(got["classify_water"])
    assert np.all(cls[own] == 9) and np.mean(cls[park & ~own] == 2) > 0.99
    m = got["classify_water"]["metrics"]
    assert m["water"] == int((cls == 9).sum()) - own.sum() == lake.sum()  # the points the stage made water
    assert m["given_back"] >= (park & ~own).sum() * 0.9
    assert all(v >= 0 for v in m.values() if isinstance(v, int))
