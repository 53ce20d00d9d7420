"""System calibration from strip overlaps (issue 23): ``stages.strip_adjust.model: mounting``.

Simulated RIEGL LMS-Q140i flights (format 3.C) with 3 cm range noise and no navigation noise, so the
only systematic error is the injected mounting error and the truth is known: the boresight error the
simulator flew with (true = error . configured) is what the estimate must find.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from commands.simulate.settings import SimulateConfig
from commands.simulate.simulator import simulate
from pipeline.cli import main
from stages.report.sections import strip_table
from tests.conftest import run_stages
from tests.flights import TRUTH_CELL
from tests.stages.georeference.test_simulate_georef import _match

SIGMA = 0.03  # range noise, metres
BORESIGHT = (0.05, -0.08, 0.15)  # injected roll, pitch, yaw error, degrees
LEVER = (0.03, -0.04, 0.0)  # injected lever-arm error, metres (5 cm)


def _flight(
    root: Path,
    *,
    boresight=(0.0, 0.0, 0.0),
    lever=(0.0, 0.0, 0.0),
    pulse_rate=10_000,
    checkpoints=0,
    terrain="default",
    sigma=SIGMA,
    **flight,
) -> Path:
    plan = {
        "altitude_m": 300,
        "speed_ms": 40,
        "lines": 2,
        "sidelap": 0.5,
        "line_length_m": 300,
        "cross_line": True,
        "bank_deg": 45,
        "lead_in_m": 50,
        "second_altitude_m": 150,
        **flight,
    }
    simulate(
        SimulateConfig(
            output=root / "sim",
            seed=5,
            formats=["lmsq_sbet"],
            checkpoints=checkpoints,
            truth_resolution=TRUTH_CELL,
            scanner={"preset": "q140", "range_noise_m": sigma, "pulse_rate_hz": pulse_rate, "scan_rate_hz": 40},
            scene={"terrain": terrain},
            navigation={"preset": "pos-av-410", "position_noise_m": 0.0, "attitude_noise_deg": 0.0},
            flight=plan,
            faults={"boresight_error_deg": boresight, "lever_arm_error_m": lever},
        )
    )
    return root / "sim"


def _run(root: Path, sim: Path, adjust: str, out: str = "out") -> tuple[dict, dict]:
    """Run to strip_adjust; the stage's run.json entry and strip_corrections.json."""
    config = root / f"{out}.yaml"
    config.write_text(
        f"input: {{format: lmsq_sbet, paths: [{sim}/lmsq/scan.lmsq], sbet: {sim}/lmsq/trajectory.sbet,\n"
        "        boresight_deg: [0.0, 0.0, 0.0], lever_arm_m: [0.10, 0.00, 0.25]}\n"
        f"output: {out}\ncache: cache\n"
        f"stages: {{georeference: {{strips: {{turn_rate_deg_s: 2.0, min_line_s: 3.0}}}}, strip_adjust: {{{adjust}}}}}\n"
    )
    assert main(["run", str(config), "-q", "--until", "strip_adjust"]) == 0
    stages = run_stages(root / out)
    stage = stages["strip_adjust"]
    return stage, json.loads(Path(stage["outputs"]["strip_corrections"]["file"]).read_text())


def _unknowns(corrections: dict) -> dict:
    return {u["name"]: u for u in corrections["unknowns"]}


@pytest.mark.slow  # a calibration flight of about 0.5 M pulses, adjusted twice (about 1 min on 2 cores)
def test_calibration_flight_recovers_the_injected_boresight(tmp_path):
    sim = _flight(
        tmp_path,
        boresight=BORESIGHT,
        lever=LEVER,
        pulse_rate=15_000,
        altitude_m=500,
        second_altitude_m=150,
        lines=3,
        line_length_m=400,
        lead_in_m=0,
    )
    stage, corr = _run(tmp_path, sim, "model: mounting, cell: 8, mounting: {lever_arm: true}")
    u = _unknowns(corr)
    for name, truth in zip(("boresight_roll", "boresight_pitch", "boresight_yaw"), BORESIGHT, strict=True):
        est, sd = u[name]["estimate"], u[name]["sigma"]
        assert u[name]["applied"] and u[name]["correction"] == est
        assert abs(est - truth) <= 0.005, (name, est, truth)
        assert abs(est - truth) <= 3 * sd, (name, est, truth, sd)
    for name, truth in zip(("lever_arm_x", "lever_arm_y"), LEVER[:2], strict=True):
        assert abs(u[name]["correction"] - truth) <= 3 * u[name]["sigma"], (name, u[name], truth)
    # a vertical lever arm lifts every strip alike: no overlap can see it, so it is held and said so
    assert u["lever_arm_z"]["held_because"] and "control" in u["lever_arm_z"]["determined_by"]
    assert u["lever_arm_z"]["correction"] == 0.0
    m = stage["metrics"]
    assert m["overlap_rms_before_m"] > 0.1
    assert m["overlap_rms_after_m"] <= 1.2 * np.sqrt(2) * SIGMA
    # the rigid model on the same flight: the overlaps agree less, and the points sit farther from the truth
    rigid, _ = _run(tmp_path, sim, "model: rigid, cell: 8", out="rigid")
    assert m["overlap_rms_after_m"] < rigid["metrics"]["overlap_rms_after_m"]
    errors = {}
    for label, st in (("mounting", stage), ("rigid", rigid)):
        _, _, _, _, d = _match(sim / "truth" / "points.laz", Path(st["outputs"]["points_adjusted"]["file"]))
        errors[label] = float(np.sqrt(np.mean(np.sum(d**2, axis=1))))
    assert errors["mounting"] <= 1.5 * SIGMA  # range noise (along the beam) and little else
    assert errors["mounting"] < 0.5 * errors["rigid"], errors


@pytest.fixture(scope="module")
def error_free(tmp_path_factory):
    root = tmp_path_factory.mktemp("mount_free")
    # the boresight needs lines both ways and a cross line, not the second altitude (that is for the lever arm)
    sim = _flight(root, pulse_rate=4_000, second_altitude_m=None)
    return _run(root, sim, "model: mounting, cell: 6")


def test_error_free_flight_estimates_zero_and_moves_no_point(error_free):
    stage, corr = error_free
    u = _unknowns(corr)
    for name in ("boresight_roll", "boresight_pitch", "boresight_yaw"):
        assert u[name]["estimated"], u[name]
        assert abs(u[name]["estimate"]) <= 3 * u[name]["sigma"], u[name]
        # not significant, so not applied: the configured (true) mounting stays
        assert not u[name]["applied"] and u[name]["correction"] == 0.0
    assert stage["metrics"]["largest_point_move_m"] <= 0.005
    assert stage["metrics"]["not_determined"] == []
    # the sigmas and the correlations are published with the estimate
    names = corr["correlation"]["names"]
    matrix = np.array(corr["correlation"]["matrix"])
    assert names == ["boresight_roll", "boresight_pitch", "boresight_yaw"] and matrix.shape == (3, 3)
    assert np.allclose(np.diag(matrix), 1.0) and np.allclose(matrix, matrix.T)


def test_lines_flown_one_way_cannot_determine_pitch(tmp_path, capfd):
    sim = _flight(
        tmp_path, boresight=BORESIGHT, pulse_rate=4_500, one_way=True, cross_line=False, second_altitude_m=None
    )
    stage, corr = _run(tmp_path, sim, "model: mounting, cell: 6")
    u = _unknowns(corr)
    pitch = u["boresight_pitch"]
    assert not pitch["estimated"] and pitch["correction"] == 0.0  # held at the configured value
    assert "opposite directions" in pitch["determined_by"]
    assert stage["metrics"]["not_determined"] == ["boresight_pitch"]
    assert "boresight_pitch cannot be determined by this flight" in capfd.readouterr().err
    # what the lines do determine is found: roll and yaw
    assert abs(u["boresight_roll"]["correction"] - BORESIGHT[0]) <= 0.005
    assert abs(u["boresight_yaw"]["correction"] - BORESIGHT[2]) <= 0.01
    # the report's strip-adjustment section is the calibration: each unknown with its estimate and fate
    page = strip_table(corr, np.array([]))
    assert "strip_adjust.model: mounting" in page
    row = page.split("<td>boresight_pitch</td>")[1].split("</tr>")[0]
    assert "not determined" in row and "opposite directions" in row
    row = page.split("<td>boresight_roll</td>")[1].split("</tr>")[0]
    assert f"{u['boresight_roll']['estimate']:+.5f}" in row and "applied" in row


def test_mounting_model_with_las_input_is_a_usage_error(tmp_path, capsys):
    sample = Path(__file__).resolve().parents[3] / "data_samples" / "las" / "sample.laz"
    config = tmp_path / "las.yaml"
    config.write_text(
        f"input: {{format: las, paths: [{sample}]}}\noutput: out\nstages: {{strip_adjust: {{model: mounting}}}}\n"
    )
    assert main(["validate", str(config)]) == 2
    err = capsys.readouterr().err
    assert "stages.strip_adjust.model: mounting needs a raw flight" in err and "model: rigid" in err
    assert "Traceback" not in err


def test_ground_control_determines_the_vertical_lever_arm(tmp_path):
    # a 5 cm vertical lever-arm error lifts every strip alike: only ground control sees it.  The control
    # points are the simulator's check points in the open (true terrain, the output CRS, ellipsoidal)
    sim = _flight(tmp_path, lever=(0.0, 0.0, 0.05), pulse_rate=3_000, checkpoints=40)
    lines = (sim / "checkpoints.csv").read_text().splitlines()
    control = tmp_path / "control.csv"
    control.write_text("\n".join(lines[:2] + [row for row in lines[2:] if row.endswith(",open")]) + "\n")
    _, corr = _run(tmp_path, sim, f"model: mounting, cell: 6, control_points: {control}, mounting: {{lever_arm: true}}")
    z = _unknowns(corr)["lever_arm_z"]
    assert z["applied"] and abs(z["estimate"] - 0.05) <= 3 * z["sigma"] and z["sigma"] < 0.01, z
