"""Projects of many files: folders and globs in ``input.paths``, the header index, ``qc/input_files.csv``.

The tiles are a real survey cut into twelve files (:mod:`tests.stages.parse.tiles`);
the known answers are the files themselves (their names, headers and points, read with laspy).
"""

from __future__ import annotations

import csv
import hashlib
import json
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from pydantic import TypeAdapter

from pipeline.cli import main
from stages.parse.params import LasInput
from stages.parse.read_las import convert_las_files
from tests.conftest import run_until
from tests.stages.parse.tiles import AUTZEN, cut_tiles, tile_name


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _paths(entries: list[str], base: Path) -> list[Path]:
    """``input.paths`` as validated against a configuration in *base*."""
    model = TypeAdapter(LasInput).validate_python({"format": "las", "paths": entries}, context={"base_dir": base})
    return model.paths


def test_folders_and_patterns_expand_to_the_sorted_files(tmp_path, need_data):
    need_data(AUTZEN)
    tiles = cut_tiles(tmp_path / "tiles", count=5)
    (tmp_path / "tiles" / "notes.txt").write_text("not a LAS file")
    (tmp_path / "tiles" / "deeper").mkdir()
    deep = cut_tiles(tmp_path / "tiles" / "deeper", count=2)
    assert _paths(["tiles"], tmp_path) == tiles  # the folder: its LAS/LAZ files, not the text, not deeper/
    assert _paths(["tiles/*.la?"], tmp_path) == tiles
    assert _paths(["tiles/*.laz"], tmp_path) == [p for p in tiles if p.suffix == ".laz"]
    assert _paths(["tiles/**/*.las"], tmp_path) == sorted([p for p in tiles + deep if p.suffix == ".las"], key=str)
    # entries keep their order; each one's files are sorted
    assert _paths([str(tiles[4]), "tiles/deeper"], tmp_path) == [tiles[4], *deep]


def test_a_folder_and_a_glob_give_the_products_of_the_sorted_list(tmp_path, need_data):
    """One cache: the folder's and the glob's runs have the list's keys (same files, same order), so the same dtm.tif."""
    need_data(AUTZEN)
    tiles = cut_tiles(tmp_path / "tiles", count=6)
    config = tmp_path / "run.yaml"
    config.write_text("input: {format: las, paths: [tiles]}\nexecutor: {kind: local, workers: 1}\n")
    listed = "[" + ", ".join(str(p) for p in tiles) + "]"
    runs = {}
    for name, paths in (("list", listed), ("folder", "[tiles]"), ("glob", "['tiles/tile_*.la[sz]']")):
        out = tmp_path / name
        stages = run_until(config, "rasterize", out, f"input.paths={paths}", cache=tmp_path / "cache")
        manifest = json.loads((out / "run.json").read_text())
        runs[name] = (_sha(out / "dtm.tif"), stages["parse"]["key"], list(manifest["inputs"]))
    assert runs["folder"] == runs["list"] and runs["glob"] == runs["list"]
    assert runs["list"][2] == [str(p) for p in tiles]  # run.json lists the files found, each with its SHA-256
    # the order is the points' order: the list reversed is another parse (another key, the index reversed)
    out = tmp_path / "reversed"
    stages = run_until(config, "parse", out, "input.paths=[" + ", ".join(str(p) for p in tiles[::-1]) + "]")
    assert stages["parse"]["key"] != runs["list"][1]
    rows = list(csv.DictReader((out / "qc" / "input_files.csv").open()))
    assert [r["path"] for r in rows] == [str(p) for p in tiles[::-1]]


def test_the_index_is_published_and_strays_are_counted_per_file(tmp_path, need_data):
    need_data(AUTZEN)
    tiles = cut_tiles(tmp_path / "tiles", count=6, stray_in=4)
    config = tmp_path / "run.yaml"
    config.write_text("input: {format: las, paths: [tiles]}\nexecutor: {kind: local, workers: 1}\n")
    stages = run_until(config, "parse", tmp_path / "out")
    rows = list(csv.DictReader((tmp_path / "out" / "qc" / "input_files.csv").open()))
    assert [r["path"] for r in rows] == [str(p) for p in tiles]
    for row, path in zip(rows, tiles, strict=True):
        las = laspy.read(path)
        assert int(row["bytes"]) == path.stat().st_size
        assert int(row["points"]) == len(las.points)
        stray = 1 if path.name == tile_name(4) else 0
        assert int(row["points_kept"]) == len(las.points) - stray
        mins, maxs = las.header.mins, las.header.maxs
        bounds = [float(row[k]) for k in ("xmin", "ymin", "zmin", "xmax", "ymax", "zmax")]
        np.testing.assert_allclose(bounds, [*mins, *maxs], rtol=0, atol=1e-9)
        assert int(row["point_format"]) == 3 and row["gps_time_type"] == "week"
        assert row["crs"] == "NAD_1983_HARN_Lambert_Conformal_Conic"
    metrics = stages["parse"]["metrics"]
    assert metrics["outside_header_bounds"] == {str(tiles[4]): 1}
    assert sum(metrics["points_kept_per_file"].values()) == sum(int(r["points"]) for r in rows) - 1


def test_each_input_is_opened_twice_header_then_points(tmp_path, need_data, monkeypatch):
    """The header index opens each file once, the reading once more (was 3 to 4 opens a file)."""
    need_data(AUTZEN)
    tiles = cut_tiles(tmp_path / "tiles", count=4)
    opened: dict[str, int] = {}
    real_open = laspy.open

    def counting_open(source, *args, **kwargs):
        opened[str(source)] = opened.get(str(source), 0) + 1
        return real_open(source, *args, **kwargs)

    monkeypatch.setattr(laspy, "open", counting_open)
    convert_las_files(
        tiles, tmp_path / "points.las", crs_setting="auto-utm", assign_crs=pyproj.CRS("EPSG:2992"), chunk_size=1000
    )
    assert {p: opened.get(str(p)) for p in tiles} == {p: 2 for p in tiles}


@pytest.mark.parametrize(
    ("entry", "said"),
    [
        ("tiles/*.copc.laz", "the pattern tiles/*.copc.laz"),
        ("empty", "holds no .las or .laz file directly inside it"),
        ("tiles/missing.las", "file not found"),
    ],
)
def test_nothing_matched_is_one_sentence_exit_2(tmp_path, capsys, need_data, entry, said):
    need_data(AUTZEN)
    cut_tiles(tmp_path / "tiles", count=2)
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "readme.txt").write_text("no LAS here")
    config = tmp_path / "run.yaml"
    config.write_text(f"output: out\ninput:\n  format: las\n  paths:\n    - tiles\n    - {entry}\n")
    assert main(["run", str(config), "-q"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert f"{config}, line 6: input.paths.1: " in err and said in err
    if entry == "empty":
        assert "empty/**/*.laz" in err  # the way to search subfolders
    if entry.startswith("tiles/*"):
        assert "correct the pattern or list the files" in err and str(tmp_path) in err
