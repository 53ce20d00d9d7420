"""The strip-adjustment datum ``most_overlap`` with injected strip errors (issue 19).

Three parallel lines at 50 % sidelap: the middle one overlaps both others,
each outer one only the middle one, so "the strip with most overlap" is line
2 by geometry.  Lines 1 and 3 carry injected errors (decimetres, and a tilt),
line 2 none: held fixed, it brings the whole block onto the truth; an outer
strip as datum would carry its error into every strip.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pipeline.cli import main
from tests.conftest import run_stages
from tests.flights import PERFECT_NAVIGATION, lines, simulate_flight
from tests.stages.georeference.test_simulate_georef import _match


def test_most_overlap_holds_the_middle_strip_and_lands_on_the_truth(tmp_path):
    simulate_flight(
        tmp_path / "sim",
        seed=5,
        formats=["las"],
        scanner={"preset": "q140", "range_noise_m": 0.01, "pulse_rate_hz": 4000},
        navigation=PERFECT_NAVIGATION,
        flight=lines(100, 40, 3, 400, sidelap=0.5, bank_deg=45),
        faults={"noise": True, "strip_bias_m": 0.4, "strip_rotation_deg": 0.04, "error_free_lines": [2]},
    )
    sim = tmp_path / "sim"
    config = tmp_path / "adjust.yaml"
    config.write_text(
        f"input: {{format: las, paths: [{sim}/las/points.laz]}}\noutput: out\ncache: cache\n"
        "stages: {strip_adjust: {reference_strip: most_overlap}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "strip_adjust"]) == 0
    stages = run_stages(tmp_path / "out")
    stage = stages["strip_adjust"]
    assert stage["metrics"]["datum"] == "strip 2"
    report = json.loads((tmp_path / "out" / "strip_corrections.json").read_text())
    assert report["strips"]["2"]["translation_m"] == [0.0, 0.0, 0.0]
    _, _, _, _, before = _match(sim / "truth" / "points.laz", sim / "las" / "points.laz")
    _, _, _, _, after = _match(sim / "truth" / "points.laz", Path(stage["outputs"]["points_adjusted"]["file"]))
    rms = lambda d: float(np.sqrt(np.mean(np.sum(d**2, axis=1))))  # noqa: E731
    assert rms(before) > 0.2
    assert rms(after) < 0.03, rms(after)  # 3D, 1 cm range noise included
