"""A project re-run after one of its files changed: only the tiles that file reaches run again.

Four files cut from the shipped LAS sample (x strips of 100 m of a
400 m x 100 m piece, 100 m tiles) run through noise, SMRF on tiles, and the
TIN DTM.  The last file's heights then move by 0.3 m and the project runs
again with the same cache.  Which tiles must run again is worked out from
the stages' inputs themselves (not from the code under test): a tile runs
again exactly when a point that differs between the two runs lies in its
core plus buffer; the others are reused.  The products equal those of a
run on an empty cache, byte for byte.
"""

from __future__ import annotations

import contextlib
import io
import json
import re
from pathlib import Path

import laspy
import numpy as np
import pytest

from pipeline.cli import main

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data_samples" / "las" / "sample.laz"
X0, Y0 = 440000.0, 4474000.0
TILE = 100.0


def _cut(folder: Path) -> list[Path]:
    las = laspy.read(SAMPLE)
    x, y = np.asarray(las.x) - X0, np.asarray(las.y) - Y0
    paths = []
    for k in range(4):
        keep = (x >= k * TILE) & (x < (k + 1) * TILE) & (y < TILE)
        part = laspy.LasData(las.header)
        part.points = las.points[keep]
        paths.append(folder / f"part{k}.laz")
        part.write(paths[-1])
    return paths


def _run(tmp: Path, paths: list[Path], out: str, cache: str, dry_run: bool = False) -> dict | str:
    config = tmp / "project.yaml"
    config.write_text(
        "input: {format: las, paths: [" + ", ".join(str(p) for p in paths) + "]}\n"
        f"output: {tmp / out}\ncache: {tmp / cache}\n"
        "executor: {kind: local, workers: 2}\n"
        f"tiling: {{size: {TILE:g}}}\n"
        "stages:\n"
        "  classify_ground: {one_grid_cells: 0}\n  classify_objects: {one_grid_cells: 0}\n"
        "  classify_water: {one_grid_cells: 0}\n"
        "  hillshade: {enabled: false}\n  contours: {enabled: false}\n  report: {enabled: false}\n"
    )
    if dry_run:
        printed = io.StringIO()
        with contextlib.redirect_stdout(printed):
            assert main(["run", str(config), "-q", "--dry-run"]) == 0
        return printed.getvalue()
    assert main(["run", str(config), "-q"]) == 0
    return json.loads((tmp / out / "run.json").read_text())


def _stage(manifest: dict, name: str) -> dict:
    return next(s for s in manifest["stages"] if s["name"] == name)


def _input_file(manifest: dict, stage: str) -> str:
    """The cached file a stage read: the output of an earlier stage with the SHA-256 of its input."""
    digest = next(v for k, v in _stage(manifest, stage)["inputs"].items() if k.startswith("points_"))  # not water.gpkg
    files = {o["sha256"]: o["file"] for s in manifest["stages"] for o in s.get("outputs", {}).values()}
    return files[digest]


def _changed_x(before: dict, after: dict, stage: str) -> np.ndarray:
    """x of the points whose input to *stage* differs between two runs (same points, same order)."""
    a, b = (laspy.read(_input_file(m, stage)) for m in (before, after))
    differ = (a.X != b.X) | (a.Y != b.Y) | (a.Z != b.Z) | (np.asarray(a.classification) != b.classification)
    return np.asarray(b.x)[differ] - X0


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("incremental")
    paths = _cut(tmp)
    first = _run(tmp, paths, "first", "cache")
    last = laspy.read(paths[3])
    last.z = np.asarray(last.z) + 0.3
    last.write(paths[3])
    plan = _run(tmp, paths, "first", "cache", dry_run=True)
    again = _run(tmp, paths, "again", "cache")
    fresh = _run(tmp, paths, "fresh", "fresh-cache")
    return first, again, fresh, plan


def test_products_equal_a_run_on_an_empty_cache(runs):
    _, again, fresh, _ = runs
    assert {n: p["sha256"] for n, p in again["products"].items()} == {
        n: p["sha256"] for n, p in fresh["products"].items()
    }


@pytest.mark.parametrize("stage", ["denoise", "classify_ground", "rasterize"])
def test_only_tiles_reaching_a_changed_point_run_again(runs, stage):
    first, again, _, _ = runs
    buffer = _stage(again, stage)["tile_buffer"]
    x = _changed_x(first, again, stage)
    assert len(x) > 0
    # tile k (one row of four) holds x in [k TILE - buffer, (k + 1) TILE + buffer)
    expected = sum(1 for k in range(4) if ((x >= k * TILE - buffer) & (x < (k + 1) * TILE + buffer)).any())
    tiling = _stage(again, stage)["metrics"]["tiling"]
    assert (tiling["ran"], tiling["reused"]) == (expected, 4 - expected)
    assert expected < 4, "the claim needs a tile that is reused"
    assert _stage(first, stage)["metrics"]["tiling"]["ran"] == 4


def test_the_dry_run_says_how_many_tiles_will_run(runs):
    """Before the re-run, from the changed file's header: exact for the first tiled stage, a bound after it."""
    _, again, _, plan = runs
    said = {
        m["stage"]: int(m["n"])
        for m in re.finditer(
            r"^(?P<stage>\w+)\s+run \(upstream\)\s+at most (?P<n>\d+) of 4 tiles \(1 file changed\)$", plan, re.M
        )
    }
    assert set(said) == {"denoise", "classify_ground", "classify_water", "classify_objects", "rasterize"}, plan
    ran = {name: _stage(again, name)["metrics"]["tiling"]["ran"] for name in said}
    assert said["denoise"] == ran["denoise"], "nothing upstream spreads the change: the header's bounds tell exactly"
    assert all(said[name] >= ran[name] for name in said)
