"""``pipeline evaluate classes`` on hand-made labelled clouds whose scores are known."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from dtm.commands.evaluate.scores import class_scores
from pipeline.cli import main


def test_class_scores_by_hand():
    # reference 2 2 2 2 6 6 6 5 ; predicted 2 2 2 6 6 6 1 5
    ref = np.array([2, 2, 2, 2, 6, 6, 6, 5])
    pred = np.array([2, 2, 2, 6, 6, 6, 1, 5])
    s = class_scores(ref, pred)
    rows = {r.code: r for r in s.classes}
    assert list(rows) == [1, 2, 5, 6]
    assert (rows[1].reference, rows[1].predicted, rows[1].recall, rows[1].precision) == (0, 1, None, 0.0)
    assert (rows[2].recall, rows[2].precision) == (0.75, 1.0)
    assert (rows[6].recall, rows[6].precision) == (pytest.approx(2 / 3), pytest.approx(2 / 3))
    assert s.accuracy == 6 / 8
    # expected agreement: sum of reference x predicted marginals / n^2 = (0*1 + 4*3 + 1*1 + 3*3) / 64
    pe = 22 / 64
    assert s.kappa == pytest.approx((6 / 8 - pe) / (1 - pe))


def _labelled(path: Path) -> Path:
    """A plane (class 2) with a flat-roofed block 6 m high (class 6): 8,000 points, 16 m x 12 m of roof."""
    rng = np.random.default_rng(5)
    n = 8000
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
    las.classification = np.where(box, 6, 2).astype(np.uint8)
    las.write(str(path))
    return path


@pytest.fixture(scope="module")
def scored(tmp_path_factory) -> tuple[Path, dict]:
    ref = _labelled(tmp_path_factory.mktemp("classes") / "ref.laz")
    return ref, json.loads(_run(ref, "--json"))


def _run(ref: Path, *args: str) -> str:
    import contextlib
    import io

    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        assert main(["evaluate", "classes", str(ref), *args]) == 0
    return out.getvalue()


def test_every_class_of_either_labelling_has_a_row(scored):
    _, result = scored
    rows = {r["code"]: r for r in result["scores"]["classes"]}
    truth = laspy.read(scored[0]).classification
    assert rows[2]["reference"] == int((truth == 2).sum())
    assert rows[6]["reference"] == int((truth == 6).sum())
    assert sum(r["predicted"] for r in rows.values()) == result["n"] == 8000
    assert rows[2]["recall"] > 0.99  # the plane is ground
    assert result["ground"]["type_1"] < 0.01 and result["ground"]["type_2"] < 0.01  # the roof is not ground


def test_the_table_and_its_errors(scored, tmp_path, capsys):
    text = _run(scored[0])
    assert "8000 points" in text and "building" in text and "kappa" in text and "type II" in text
    assert main(["evaluate", "classes", str(tmp_path / "none.laz")]) == 2
    assert "file not found" in capsys.readouterr().err
    bad = tmp_path / "bad.laz"
    bad.write_bytes(b"nope" * 100)
    assert main(["evaluate", "classes", str(bad)]) == 3
