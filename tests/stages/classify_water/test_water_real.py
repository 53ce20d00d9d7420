"""Water on real data: lidR's Topography.laz against its provider's 3,897 water points (benchmarks/water_real.py)."""

from __future__ import annotations

import pytest

from benchmarks.water_real import TOPOGRAPHY, topography


@pytest.mark.slow  # the whole run up to classify_water on 73 k real points: about 5 s
def test_topography_water_agrees_with_the_provider(tmp_path):
    """Figures of 2026-12-04 (docs/stages/classify_water.md): kappa 94.7 %, Type I 8.5 %, Type II 0.06 %."""
    assert TOPOGRAPHY.is_file()
    r = topography(tmp_path)
    assert r["reference_water"] == 3897 and r["points"] == 73403
    assert r["kappa"] >= 80.0  # issue 34's target with the default parameters
    assert r["type_1"] <= 15.0 and r["type_2"] <= 0.2
