"""``stages.export_las.files: per_input``: the classified points cut back into the input files.

The inputs are a real survey cut into tiles (:mod:`tests.stages.parse.tiles`);
the known answers are the tiles themselves and the merged ``points.laz`` of
the same run: each per-input file holds that tile's rows of it, in order.
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pyproj

from pipeline.cli import main
from tests.conftest import run_until
from tests.stages.parse.tiles import AUTZEN, cut_tiles


def _config(tmp_path: Path, paths: str = "[tiles]") -> Path:
    config = tmp_path / "run.yaml"
    config.write_text(f"output: out\ninput: {{format: las, paths: {paths}}}\nexecutor: {{kind: local, workers: 1}}\n")
    return config


def test_one_file_per_input_with_its_rows_of_the_merged_cloud(tmp_path, need_data):
    need_data(AUTZEN)
    tiles = cut_tiles(tmp_path / "tiles", count=6, stray_in=4)
    copc = tiles[5].with_name("tile_05.copc.laz")  # a COPC-named input is written as plain LAZ
    tiles[5].rename(copc)
    tiles = sorted([*tiles[:5], copc], key=str)
    config = _config(tmp_path)
    cache = tmp_path / "cache"
    run_until(config, "export_las", tmp_path / "merged", cache=cache)
    stages = run_until(config, "export_las", tmp_path / "split", "stages.export_las.files=per_input", cache=cache)
    assert stages["parse"]["status"] != "ran"  # the same classified cloud, cut
    merged = laspy.read(tmp_path / "merged" / "points.laz")
    folder = tmp_path / "split" / "points"
    names = ["tile_00.laz", "tile_01.las", "tile_02.las", "tile_03.laz", "tile_04.las", "tile_05.laz"]
    assert sorted(p.name for p in folder.iterdir()) == names
    assert not (tmp_path / "split" / "points.laz").exists()
    at = 0
    for tile, name in zip(tiles, names, strict=True):
        src, out = laspy.read(tile), laspy.read(folder / name)
        expected = len(src.points) - (1 if tile.name == "tile_04.las" else 0)  # the stray parse left out
        assert len(out.points) == expected
        assert out.header.are_points_compressed == name.endswith(".laz")
        rows = slice(at, at + expected)
        for dim in ("x", "y", "z", "gps_time", "classification", "intensity"):
            np.testing.assert_array_equal(np.asarray(out[dim]), np.asarray(merged[dim])[rows], err_msg=f"{name} {dim}")
        # the input's own points, in their order (the stray, last in tile_04, left out)
        np.testing.assert_allclose(np.asarray(out.gps_time), np.asarray(src.gps_time)[:expected])
        np.testing.assert_allclose(np.asarray(out.x), np.asarray(src.x)[:expected], atol=1e-4)
        # the product's header rules: LAS 1.4, its format, CRS and GPS time type; the file's own bounds
        assert str(out.header.version) == "1.4" and out.header.point_format.id == merged.header.point_format.id
        assert out.header.parse_crs() == merged.header.parse_crs()
        assert out.header.global_encoding.gps_time_type == merged.header.global_encoding.gps_time_type
        np.testing.assert_allclose(out.header.mins, [float(np.min(out[d])) for d in "xyz"], atol=1e-4)
        assert not any(v.user_id == "copc" for v in out.header.vlrs)
        at += expected
    assert at == len(merged.points)
    _check_vpc(tmp_path / "split" / "points.vpc", [folder / n for n in names])


def _check_vpc(vpc: Path, files: list[Path]) -> None:
    """The virtual point cloud, against PDAL wrench's vpc-spec.md: a STAC API ItemCollection (a GeoJSON
    FeatureCollection of STAC 1.0.0 Items) with the pointcloud and projection extensions, one Item per file;
    bounds in WGS 84 and in the file's CRS (3-D), the file as the data asset, relative to the .vpc."""
    doc = json.loads(vpc.read_text())
    assert doc["type"] == "FeatureCollection" and len(doc["features"]) == len(files)
    for feature, path in zip(doc["features"], files, strict=True):
        las = laspy.read(path)
        assert feature["type"] == "Feature" and feature["stac_version"] == "1.0.0" and feature["links"] == []
        assert any("stac-extensions.github.io/pointcloud/" in e for e in feature["stac_extensions"])
        assert any("stac-extensions.github.io/projection/" in e for e in feature["stac_extensions"])
        asset = feature["assets"]["data"]
        assert asset["roles"] == ["data"] and (vpc.parent / asset["href"]).resolve() == path.resolve()
        props = feature["properties"]
        assert "datetime" in props and props["pc:count"] == len(las.points) and props["pc:type"] == "lidar"
        assert props["pc:encoding"] == ("application/vnd.laszip" if path.suffix == ".laz" else "application/vnd.las")
        assert {s["name"] for s in props["pc:schemas"]} >= {"X", "Y", "Z", "classification", "gps_time"}
        crs = pyproj.CRS.from_wkt(props["proj:wkt2"])
        assert crs == las.header.parse_crs()
        np.testing.assert_allclose(props["proj:bbox"], [*las.header.mins, *las.header.maxs])
        # every point inside the WGS 84 box and polygon (lon, lat; GeoJSON's axis order)
        lon, lat = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True).transform(las.x, las.y)
        w, s, z0, e, n, z1 = feature["bbox"]
        assert w <= lon.min() and lon.max() <= e and s <= lat.min() and lat.max() <= n
        assert z0 <= float(np.min(las.z)) and float(np.max(las.z)) <= z1
        ring = feature["geometry"]["coordinates"][0]
        assert feature["geometry"]["type"] == "Polygon" and ring[0] == ring[-1] and len(ring) == 5
        assert -180 <= w < e <= 180 and -90 <= s < n <= 90


def test_two_inputs_of_one_name_are_refused_exit_2(tmp_path, capsys, need_data):
    need_data(AUTZEN)
    a = cut_tiles(tmp_path / "a", count=2)
    b = cut_tiles(tmp_path / "b", count=2)
    config = _config(tmp_path, "[a, b]")
    assert main(["run", str(config), "-q", "--set", "stages.export_las.files=per_input"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "stages.export_las.files" in err
    assert f"both {a[0]} and {b[0]} as points/{a[0].name}" in err
    assert not (tmp_path / "out").exists()  # refused before any stage ran
    # the same file listed twice is one input (read once), not two of one name
    config = _config(tmp_path, f"[a, {a[0]}]")
    assert main(["run", str(config), "-q", "--until", "parse", "--set", "stages.export_las.files=per_input"]) == 0


def test_per_input_needs_las_inputs_exit_2(tmp_path, capsys):
    log = tmp_path / "flight.log"
    log.write_text("")
    config = tmp_path / "run.yaml"
    config.write_text(
        f"output: out\ninput: {{format: ldmrs_mtig, paths: [{log}], mounting: pilatus}}\n"
        "stages: {export_las: {files: per_input}}\n"
    )
    assert main(["run", str(config), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "stages.export_las.files: per_input" in err and "input.format ldmrs_mtig" in err and "merged" in err
