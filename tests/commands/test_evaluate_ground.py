"""``pipeline evaluate ground`` on a labelled synthetic scene (the ISPRS acceptance: test_evaluate_ground_isprs.py)."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pyproj

from pipeline.cli import main


def labelled_block(path: Path, building: int = 1, n: int = 8000) -> Path:
    """A plane with a 16 m x 12 m flat-roofed block 6 m high, labelled: class 2 ground, *building* the block.

    *n* points over 60 m x 60 m: 8000 is 2.2 points/m², a spacing of 0.67 m.
    """
    rng = np.random.default_rng(5)
    x, y = rng.uniform(0, 60, n), rng.uniform(0, 60, n)
    z = 100 + 0.05 * x + rng.normal(0, 0.03, n)
    box = (np.abs(x - 30) < 8) & (np.abs(y - 30) < 6)
    z[box] += 6.0
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001] * 3)
    header.offsets = np.array([500000.0, 4000000.0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(32630))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x + 500000, y + 4000000, z
    las.classification = np.where(box, building, 2).astype(np.uint8)
    las.write(str(path))
    return path


def test_evaluate_prints_metrics_and_writes_the_cloud(tmp_path, capsys):
    ref = labelled_block(tmp_path / "ref.laz")
    out = tmp_path / "classified.laz"
    assert main(["evaluate", "ground", str(ref), "--compare", "pmf", "--write", str(out)]) == 0
    text = capsys.readouterr().out
    assert "8000 points" in text
    scores, dtm = text.split("\n\n")
    rows = {line.split()[0]: line.split()[1:] for line in scores.splitlines()[2:]}
    assert set(rows) == {"smrf", "pmf"}
    assert float(rows["smrf"][2]) < 1.0  # total error, per cent
    checks = {line.split()[0]: line.split()[1:] for line in dtm.splitlines()[2:]}
    assert set(checks) == {"smrf", "pmf"}
    assert float(checks["smrf"][1]) < 0.05  # the DTM check's RMS: the building is removed
    written = laspy.read(out)
    assert written.header.parse_crs().to_epsg() == 32630
    truth = np.asarray(laspy.read(ref).classification) == 2
    assert ((np.asarray(written.classification) == 2) == truth).mean() > 0.99


def test_evaluate_json_and_params(tmp_path, capsys):
    ref = labelled_block(tmp_path / "ref.laz", n=16000)  # cells that see walls (classify_objects' FACE_CELL)
    args = ["evaluate", "ground", str(ref), "--algorithm", "pmf", "--param", "max_window_size=5", "--json"]
    assert main(args) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["algorithm"] == "pmf" and rows[0]["params"]["max_window_size"] == 5
    # a 5 m window cannot remove a 16 m x 12 m building, but classify_objects takes the roof off the ground ...
    assert rows[0]["type_2"] < 0.01
    # ... and without it the roof stays ground
    config = tmp_path / "run.yaml"
    config.write_text("stages:\n  classify_objects: {enabled: false}\n")
    assert main([*args, "--config", str(config)]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows[0]["type_2"] > 0.5


def test_evaluate_errors_exit_with_one_sentence(tmp_path, capsys):
    ref = labelled_block(tmp_path / "ref.laz")
    assert main(["evaluate", "ground", str(ref), "--param", "slope=steep"]) == 2
    assert "--param slope" in capsys.readouterr().err
    assert main(["evaluate", "ground", str(tmp_path / "none.laz")]) == 2
    bad = tmp_path / "bad.laz"
    bad.write_bytes(b"nope" * 100)
    assert main(["evaluate", "ground", str(bad)]) == 3
    unlabelled = tmp_path / "u.laz"
    las = laspy.read(ref)
    las.classification = np.ones(len(las.points), np.uint8)
    las.write(str(unlabelled))
    assert main(["evaluate", "ground", str(unlabelled)]) == 3
    assert "no point has class 2" in capsys.readouterr().err
