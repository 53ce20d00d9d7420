"""Strip adjustment on simulated flights (issue 6): five lines at 50 % sidelap and a cross line, 2 cm range noise.

Line 1 is flown without systematic error and is the datum, so after the
adjustment every strip must sit on the truth.  The flights without injected
error are in test_strip_adjust_no_error.py (a file per worker: the two share
the workers).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import rasterio

from lidar.rasters import read_raster
from pipeline.cli import main
from tests.conftest import run_stages
from tests.flights import PERFECT_NAVIGATION, lines, simulate_flight
from tests.stages.georeference.test_simulate_georef import _match
from tests.synthetic import make_scene, write_scene_las

SIGMA = 0.02
pytestmark = pytest.mark.slow  # simulates a flight (five lines and a cross line at 30 kHz)


def _flight(root: Path, bias: float, rotation: float, noise: bool = True) -> Path:
    simulate_flight(
        root / "sim",
        seed=11,
        formats=["las"],
        checkpoints=40,
        scanner={"preset": "q140", "range_noise_m": SIGMA, "pulse_rate_hz": 30000},
        navigation=PERFECT_NAVIGATION,
        flight=lines(150, 40, 5, 400, sidelap=0.5, cross_line=True, bank_deg=45),
        faults={"noise": noise, "strip_bias_m": bias, "strip_rotation_deg": rotation, "error_free_lines": [1]},
    )
    return root / "sim"


def _adjust(root: Path, sim: Path, extra: str = "reference_strip: 1") -> dict:
    config = root / "adjust.yaml"
    config.write_text(
        f"input: {{format: las, paths: [{sim}/las/points.laz]}}\noutput: out\nstages: {{strip_adjust: {{{extra}}}}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "strip_adjust"]) == 0
    stages = run_stages(root / "out")
    return stages["strip_adjust"]


@pytest.fixture(scope="module")
def injected(tmp_path_factory):
    root = tmp_path_factory.mktemp("adjust_injected")
    sim = _flight(root, bias=0.5, rotation=0.05)
    return root, sim, _adjust(root, sim)


def test_overlaps_agree_after_adjustment(injected):
    root, _, stage = injected
    m = stage["metrics"]
    assert m["overlap_rms_before_m"] > 0.2  # decimetres apart before
    assert m["overlap_rms_after_m"] <= 1.2 * SIGMA * np.sqrt(2)
    report = json.loads((root / "out" / "strip_corrections.json").read_text())
    assert report["datum"] == "strip 1" and len(report["strips"]) == 6
    assert all(p["rms_after_m"] <= 1.2 * SIGMA * np.sqrt(2) for p in report["pairs"])
    assert report["strips"]["1"]["translation_m"] == [0.0, 0.0, 0.0]
    for name in ("strip_difference_before.tif", "strip_difference_after.tif", "strip_difference.png"):
        assert (root / "out" / name).stat().st_size > 0


def test_adjusted_points_sit_on_the_truth(injected):
    root, sim, stage = injected
    _, _, _, _, before = _match(sim / "truth" / "points.laz", sim / "las" / "points.laz")
    _, _, _, _, after = _match(sim / "truth" / "points.laz", Path(stage["outputs"]["points_adjusted"]["file"]))
    rms = lambda d: float(np.sqrt(np.mean(np.sum(d**2, axis=1))))  # noqa: E731
    assert rms(before) > 0.3
    assert rms(after) <= 0.03  # 3D, range noise (2 cm) included


def test_control_points_fix_the_datum(injected, tmp_path):
    """No reference strip: surveyed points on open ground hold the block; heights land on the truth."""
    _, sim, _ = injected
    lines = (sim / "checkpoints.csv").read_text().splitlines()
    gcp = tmp_path / "gcp.csv"
    gcp.write_text("\n".join(line for line in lines if not line.endswith(",vegetated")) + "\n")
    stage = _adjust(tmp_path, sim, f"control_points: {gcp}")
    assert stage["metrics"]["datum"] == "control points"
    _, _, _, _, after = _match(sim / "truth" / "points.laz", Path(stage["outputs"]["points_adjusted"]["file"]))
    assert float(np.sqrt(np.mean(after[:, 2] ** 2))) <= 0.03  # vertical: what ground control fixes


def test_difference_map_shows_the_improvement(injected):
    root, _, _ = injected
    before, *_ = read_raster(root / "out" / "strip_difference_before.tif")
    after, *_ = read_raster(root / "out" / "strip_difference_after.tif")
    assert np.nanpercentile(np.abs(before), 50) > 0.1 and np.nanpercentile(np.abs(after), 95) < 0.03
    for name in ("strip_difference_before.tif", "strip_difference_after.tif"):  # the elevation rasters' nodata
        with rasterio.open(root / "out" / name) as src:
            assert src.nodata == -999999.0  # the default specification is a USGS LBS quality level


def test_single_strip_passes_through(tmp_path):
    """One strip: nothing to adjust, points unchanged, a note instead of figures."""
    scene = make_scene(seed=3)
    scene.point_source_id[:] = 1
    (tmp_path / "las").mkdir()
    write_scene_las(scene, tmp_path / "las" / "points.laz")
    stage = _adjust(tmp_path, tmp_path, "enabled: true")
    assert "nothing to adjust" in stage["metrics"]["note"]
    assert stage["metrics"]["strips_adjusted"] == 0


def test_undetermined_corrections_are_not_applied(injected, tmp_path):
    """A correction less certain than the limit is not applied: the strip stays as flown, and is listed."""
    _, sim, _ = injected
    stage = _adjust(tmp_path, sim, "reference_strip: 1, max_sigma_translation_m: 0.0001")
    m = stage["metrics"]
    assert m["strips_not_determined"] == [2, 3, 4, 5, 6] and m["strips_estimated"] == 0
    assert m["largest_translation_m"] == 0.0
    report = json.loads((tmp_path / "out" / "strip_corrections.json").read_text())
    assert set(report["not_determined"]) == {"2", "3", "4", "5", "6"}


def test_a_lattice_of_cells_is_enough_for_a_large_survey(injected, tmp_path):
    """Above max_points, the estimation sees every k-th cell only: memory bounded, corrections nearly as good.

    Here a quarter of the cells (1,891 correspondences instead of 8,284): the strips still agree to
    the noise, and sit on the truth to 4.3 cm (3D, 2 cm range noise included) instead of under 3 cm.
    """
    root, sim, full = injected
    stage = _adjust(tmp_path, sim, "reference_strip: 1, max_points: 300000")
    m = stage["metrics"]
    assert m["lattice_step"] == 2 and m["estimation_points"] <= 300_000 < full["metrics"]["estimation_points"]
    assert m["overlap_rms_after_m"] <= 1.2 * SIGMA * np.sqrt(2)
    _, _, _, _, after = _match(sim / "truth" / "points.laz", Path(stage["outputs"]["points_adjusted"]["file"]))
    assert float(np.sqrt(np.mean(np.sum(after**2, axis=1)))) <= 0.05
