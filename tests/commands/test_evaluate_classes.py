"""``pipeline evaluate classes`` on hand-made labelled clouds whose scores are known."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import laspy
import numpy as np
import pytest

from commands.evaluate.scores import class_scores
from pipeline.cli import main
from tests.commands.test_evaluate_ground import labelled_block


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


@pytest.fixture(scope="module")
def scored(tmp_path_factory) -> tuple[Path, dict]:
    ref = labelled_block(tmp_path_factory.mktemp("classes") / "ref.laz", building=6)
    return ref, json.loads(_run(ref, "--json"))


def _run(ref: Path, *args: str) -> str:
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
    assert rows[6]["recall"] > 0.95 and rows[6]["precision"] > 0.95  # the block is a building
    assert result["ground"]["type_1"] < 0.01 and result["ground"]["type_2"] < 0.01  # the roof is not ground
    assert result["scores"]["kappa"] > 0.9


def test_the_table_and_its_errors(scored, tmp_path, capsys):
    text = _run(scored[0])
    assert "8000 points" in text and "building" in text and "kappa" in text and "type II" in text
    assert main(["evaluate", "classes", str(tmp_path / "none.laz")]) == 2
    assert "file not found" in capsys.readouterr().err
    bad = tmp_path / "bad.laz"
    bad.write_bytes(b"nope" * 100)
    assert main(["evaluate", "classes", str(bad)]) == 3
