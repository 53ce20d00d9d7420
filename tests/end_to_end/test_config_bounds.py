"""Values that size memory are bounded in validation (issue 18, item 10): exit 2, one sentence, before running."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.cli import main

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize(
    ("value", "words"),
    [
        ("1e-9", "Input should be greater than or equal to 0.01"),
        ("1e-3", "Input should be greater than or equal to 0.01"),
        (".inf", "Input should be a finite number"),
        (".nan", "Input should be a finite number"),
    ],
)
def test_rasterize_resolution_is_finite_and_at_least_a_centimetre(capsys, value, words):
    override = f"stages.rasterize.resolution={value}"
    assert main(["validate", str(ROOT / "configs" / "las.yaml"), "--set", override]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"pipeline: error: --set {override}: stages.rasterize.resolution: {words}")
    assert "\n" not in err


def test_a_centimetre_resolution_is_accepted(capsys):
    assert main(["validate", str(ROOT / "configs" / "las.yaml"), "--set", "stages.rasterize.resolution=0.01"]) == 0
