"""Simulator -> parse -> georeference, against the simulator's truth (issues 3 and 4).

Small flights (a few seconds to simulate) in every raw format: zero-noise
flights must georeference to the truth within 1 mm RMS / 5 mm max, every
echo must be accounted for, every counter must equal what was injected, and
noise must come out as it went in.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import laspy
import numpy as np
import pytest

from commands.simulate.faults import FAULT_CODES
from commands.simulate.settings import SimulateConfig
from commands.simulate.simulator import simulate
from lidar.columns import read_columns
from pipeline.cli import main
from stages.parse.read_nmea import with_checksum
from tests.flights import TRUTH_CELL

LDMRS = {
    "formats": ["ldmrs_mtig"],
    "scanner": {"preset": "ldmrs", "angle_step_deg": 2.0},
    "navigation": {"preset": "mtig"},
    "flight": {
        "altitude_m": 50,
        "speed_ms": 8,
        "lines": 2,
        "line_length_m": 80,
        "cross_line": False,
        "lead_in_m": 5,
        "sidelap": 0.3,
    },
}
RIEGL = {
    "formats": ["lmsq_nmea", "lmsq_sbet", "las"],
    "scanner": {"preset": "q140", "pulse_rate_hz": 3000},
    "navigation": {"preset": "pos-av-410", "ins_rate_hz": 200},
    "flight": {
        "altitude_m": 120,
        "speed_ms": 40,
        "lines": 2,
        "line_length_m": 160,
        "cross_line": True,
        "bank_deg": 45,
        "lead_in_m": 20,
    },
}


def _simulate(root: Path, spec: dict, **faults) -> tuple[Path, object]:
    cfg = SimulateConfig(output=root, seed=7, checkpoints=0, truth_resolution=TRUTH_CELL, faults=faults, **spec)
    return root, simulate(cfg)


def _run(tmp: Path, name: str, input_block: str, stages: str = "", until: str = "georeference") -> dict:
    config = tmp / f"{name}.yaml"
    config.write_text(
        f"name: {name}\ninput:\n{input_block}\ncrs: auto-utm\noutput: out-{name}\ncache: cache\n"
        f"stages:\n  georeference: {{strips: {{turn_rate_deg_s: 2.0, min_line_s: 2.0}}{stages}}}\n"
    )
    assert main(["run", str(config), "-q", "--until", until]) == 0
    manifest = json.loads((tmp / f"out-{name}" / "run.json").read_text())
    return {s["name"]: s for s in manifest["stages"]}


def _input(fmt: str, sim: Path) -> str:
    if fmt == "ldmrs_mtig":
        return f"  format: ldmrs_mtig\n  paths: [{sim}/ldmrs/acquisition.log.gz]\n  mounting: cb5000"
    common = f"  paths: [{sim}/lmsq/scan.lmsq]\n  boresight_deg: [0, 0, 0]\n  lever_arm_m: [0.1, 0.0, 0.25]"
    if fmt == "lmsq_nmea":
        return f"  format: lmsq_nmea\n{common}\n  nmea: {sim}/lmsq/nav.nmea\n  ins: {sim}/lmsq/ins.csv"
    return f"  format: lmsq_sbet\n{common}\n  sbet: {sim}/lmsq/trajectory.sbet\n  smrmsg: {sim}/lmsq/trajectory.smrmsg"


def _match(truth_path: Path, points_path: Path):
    """Echoes of the output matched to the truth by GPS time, return number, channel and scan angle."""
    a, b = laspy.read(truth_path), laspy.read(points_path)

    def key(las):
        return np.rec.fromarrays(
            [
                np.round(np.asarray(las.gps_time) * 1e6).astype(np.int64),
                np.asarray(las.return_number),
                np.asarray(las.scanner_channel),
                np.asarray(las.scan_angle),
            ]
        )

    ka, kb = key(a), key(b)
    assert len(np.unique(ka)) == len(ka), "truth keys must be unique"
    common, ia, ib = np.intersect1d(ka, kb, return_indices=True)
    xyz_a = np.column_stack((a.x, a.y, a.z))[ia]
    xyz_b = np.column_stack((b.x, b.y, b.z))[ib]
    return a, b, ia, ib, xyz_b - xyz_a


@pytest.fixture(scope="module")
def zero_noise(tmp_path_factory):
    root = tmp_path_factory.mktemp("zero")
    ld_dir, ld = _simulate(root / "ldmrs", LDMRS, noise=False)
    rg_dir, rg = _simulate(root / "riegl", RIEGL, noise=False, pps_gaps=1)  # a missed PPS: dated by the counter
    runs = {}
    for fmt, sim in (("ldmrs_mtig", ld_dir), ("lmsq_nmea", rg_dir), ("lmsq_sbet", rg_dir)):
        runs[fmt] = (_run(root, fmt, _input(fmt, sim)), sim)
    return root, {"ldmrs": ld, "riegl": rg}, runs


@pytest.mark.parametrize("fmt", ["ldmrs_mtig", "lmsq_nmea", "lmsq_sbet"])
def test_zero_noise_flight_georeferences_to_the_truth(zero_noise, fmt):
    _, _, runs = zero_noise
    stages, sim = runs[fmt]
    geo = stages["georeference"]
    truth, points, ia, ib, d = _match(sim / "truth" / "points.laz", Path(geo["outputs"]["points_georef"]["file"]))
    err = np.linalg.norm(d, axis=1)
    assert len(ib) == len(points), "every output point is a true echo"
    assert np.sqrt(np.mean(err**2)) < 0.001 and err.max() < 0.005
    # every recorded echo is accounted for: written, or dropped in a turn (counted)
    m = geo["metrics"]
    assert m["points"] + m["dropped_in_turns"] + m["rejected_no_trajectory"] == len(truth)
    assert m["rejected_no_trajectory"] == 0
    # and every point keeps its return number and count
    np.testing.assert_array_equal(np.asarray(points.number_of_returns)[ib], np.asarray(truth.number_of_returns)[ia])


@pytest.mark.parametrize("fmt", ["lmsq_nmea", "lmsq_sbet"])
def test_missed_pps_echoes_are_dated_and_georeferenced_exactly(zero_noise, fmt):
    """The second after the missed PPS: every echo comes out, flagged, at its true time and position."""
    _, sims, runs = zero_noise
    stages, sim = runs[fmt]
    injected = sims["riegl"].faults["lmsq"]
    m = stages["parse"]["metrics"]
    assert m["scanner_missed_pps"] == m["scanner_pps_recovered"] == injected["pps_recovered"] > 1000
    assert m["scanner_pps_ambiguous"] == 0
    pulses, _ = read_columns(stages["parse"]["outputs"]["pulses"]["file"])
    flagged = (pulses["flags"] & 0x80) > 0
    truth, points, ia, ib, d = _match(
        sim / "truth" / "points.laz", Path(stages["georeference"]["outputs"]["points_georef"]["file"])
    )
    gap = np.asarray(truth.fault) == FAULT_CODES["pps_gap"]
    gap_times = np.unique(np.round((np.asarray(truth.gps_time)[gap] + 1e9) * 1e6).astype(np.int64))
    np.testing.assert_array_equal(np.unique(np.round(pulses["time"][flagged] * 1e6).astype(np.int64)), gap_times)
    on_gap = gap[ia]
    assert on_gap.sum() > 1000 and np.linalg.norm(d[on_gap], axis=1).max() < 0.005


def test_attitude_from_pashr_when_there_is_no_ins_csv(zero_noise, tmp_path):
    """The INS CSV's attitudes written as $PASHR sentences into the NMEA log (and no input.ins): the same
    points as with the CSV."""
    _, sims, runs = zero_noise
    sim = runs["lmsq_nmea"][1]
    ins = np.loadtxt(sim / "lmsq" / "ins.csv", delimiter=",", skiprows=1)
    week = runs["lmsq_nmea"][0]["parse"]["metrics"]["gps_week"]
    tod = np.mod(week * 604800.0 + ins[:, 0] - 18.0, 86400.0)
    lines = [(sim / "lmsq" / "nav.nmea").read_text().rstrip("\n")]
    for t, (roll, pitch, heading) in zip(tod, ins[:, 1:], strict=True):
        hh, mm, ss = int(t // 3600), int(t % 3600 // 60), t % 60
        body = f"PASHR,{hh:02d}{mm:02d}{ss:09.6f},{heading:.9f},T,{roll:.9f},{pitch:.9f},0.00,0.01,0.01,0.02,1,0"
        lines.append(with_checksum(body) + "\r")
    (tmp_path / "nav.nmea").write_text("\n".join(lines) + "\n")
    block = _input("lmsq_nmea", sim).replace(f"{sim}/lmsq/nav.nmea", str(tmp_path / "nav.nmea"))
    block = "\n".join(line for line in block.splitlines() if "ins:" not in line)
    stages = _run(tmp_path, "pashr", block)
    assert stages["parse"]["metrics"]["nmea_attitude_epochs"] == len(ins)
    a = laspy.read(stages["georeference"]["outputs"]["points_georef"]["file"])
    b = laspy.read(runs["lmsq_nmea"][0]["georeference"]["outputs"]["points_georef"]["file"])
    assert len(a) == len(b)
    np.testing.assert_allclose(np.column_stack((a.x, a.y, a.z)), np.column_stack((b.x, b.y, b.z)), atol=2e-3)


@pytest.mark.parametrize("unwrapped", [False, True])
def test_headings_wrapped_or_unwrapped_give_the_same_points(tmp_path, unwrapped):
    """The SBET written as Applanix does ((-pi, pi]) and unwrapped (a first line at 750 deg: headings past
    4 pi): every pulse is georeferenced to the truth, from the SBET and from the INS CSV alike."""
    spec = {
        **RIEGL,
        "formats": ["lmsq_nmea", "lmsq_sbet"],
        "flight": {**RIEGL["flight"], "heading_deg": 750.0},
        "navigation": {**RIEGL["navigation"], "ins_rate_hz": 50, "unwrapped_heading": unwrapped},
    }
    sim, res = _simulate(tmp_path / "sim", spec, noise=False)
    sbet = np.fromfile(sim / "lmsq" / "trajectory.sbet", "<f8").reshape(-1, 17)
    ins = np.loadtxt(sim / "lmsq" / "ins.csv", delimiter=",", skiprows=1)
    if unwrapped:
        assert sbet[:, 9].min() > 4 * np.pi and ins[:, 3].max() > 720
    else:
        assert np.all(np.abs(sbet[:, 9:11]) <= np.pi) and np.all((ins[:, 3] >= 0) & (ins[:, 3] < 360))
    counts = {}
    for fmt in ("lmsq_nmea", "lmsq_sbet"):
        stages = _run(tmp_path, fmt, _input(fmt, sim))
        geo = stages["georeference"]
        _, points, _, ib, d = _match(sim / "truth" / "points.laz", Path(geo["outputs"]["points_georef"]["file"]))
        assert len(ib) == len(points) and np.linalg.norm(d, axis=1).max() < 0.005
        assert stages["parse"]["metrics"]["navigation_malformed"] == 0
        counts[fmt] = (geo["metrics"]["points"], geo["metrics"]["rejected_no_trajectory"], geo["metrics"]["strips"])
    assert counts["lmsq_nmea"] == counts["lmsq_sbet"] and counts["lmsq_sbet"][1] == 0


def test_zero_noise_3d_las_matches_truth(zero_noise):
    """Format 3.D written by the simulator: the same echoes, georeferenced from the recorded navigation."""
    root, _, _ = zero_noise
    sim = root / "riegl"
    truth, las, ia, ib, d = _match(sim / "truth" / "points.laz", sim / "las" / "points.laz")
    assert len(ib) == len(las) == len(truth)
    assert np.sqrt(np.mean(np.sum(d**2, axis=1))) < 0.001


def test_strips_are_the_flown_lines(zero_noise):
    """Segmentation finds the two lines and the cross line; no strip mixes two simulated lines."""
    _, _, runs = zero_noise
    stages, sim = runs["lmsq_sbet"]
    truth, points, ia, ib, _ = _match(
        sim / "truth" / "points.laz", Path(stages["georeference"]["outputs"]["points_georef"]["file"])
    )
    ours, theirs = np.asarray(points.point_source_id)[ib], np.asarray(truth.point_source_id)[ia]
    assert sorted(set(ours.tolist())) == [1, 2, 3]
    for strip in (1, 2, 3):
        lines = set(theirs[ours == strip].tolist()) - {0}  # 0: the simulator's lead-ins
        assert len(lines) == 1


def test_trajectory_epochs_round_trip(zero_noise):
    """Parse recovers every navigation epoch of every format within the format's quantization."""
    _, sims, runs = zero_noise
    nav, start = sims["riegl"].navigation, sims["riegl"].gps_start
    # 3.C: the SBET at 200 Hz, float64: exact; heading = platform heading - wander
    traj, meta = read_columns(runs["lmsq_sbet"][0]["parse"]["outputs"]["trajectory"]["file"])
    assert meta["convention"] == "NED" and len(traj["time"]) == len(nav.t)
    np.testing.assert_allclose(traj["time"], start + nav.t, atol=1e-6, rtol=0)
    np.testing.assert_allclose(traj["lat"], nav.lat, atol=1e-12, rtol=0)
    np.testing.assert_allclose(np.mod(traj["yaw"] - nav.heading + 180, 360) - 180, 0, atol=1e-9)
    assert "sigma_north_m" in traj
    # 3.B: INS epochs (9 decimals of degrees) with NMEA positions (8 decimals of minutes) splined in
    traj, _ = read_columns(runs["lmsq_nmea"][0]["parse"]["outputs"]["trajectory"]["file"])
    assert len(traj["time"]) == len(nav.t)
    np.testing.assert_allclose(traj["roll"], nav.roll, atol=1e-8, rtol=0)
    np.testing.assert_allclose(np.mod(traj["yaw"] - nav.heading + 180, 360) - 180, 0, atol=1e-8)
    np.testing.assert_allclose(traj["lat"], nav.lat, atol=1e-8, rtol=0)  # 1e-8 deg = 1 mm
    np.testing.assert_allclose(traj["h"], nav.h, atol=2e-3, rtol=0)
    # 3.A: one epoch per scan (LLA 1e-10 deg, Euler 1e-7 deg in the MTi-G's NWU convention)
    nav, start = sims["ldmrs"].navigation, sims["ldmrs"].gps_start
    traj, meta = read_columns(runs["ldmrs_mtig"][0]["parse"]["outputs"]["trajectory"]["file"])
    assert meta["convention"] == "NWU"
    i = np.round((traj["time"] - start) / 0.005).astype(int)
    assert sims["ldmrs"].faults["ldmrs_mtig"]["scans_written"] == len(i)
    np.testing.assert_allclose(traj["lat"], nav.lat[i], atol=1e-10, rtol=0)
    np.testing.assert_allclose(traj["pitch"], -nav.pitch[i], atol=1e-7, rtol=0)
    np.testing.assert_allclose(np.mod(traj["yaw"] + nav.heading[i] + 180, 360) - 180, 0, atol=1e-7)


def test_noise_comes_out_as_it_went_in(tmp_path):
    """Range noise only (5 cm): the georeferencing error is that noise, along the ray."""
    spec = {
        **RIEGL,
        "scanner": {**RIEGL["scanner"], "range_noise_m": 0.05},
        "formats": ["lmsq_sbet"],
        "navigation": {"preset": "pos-av-410", "position_noise_m": 0.0, "attitude_noise_deg": 0.0},
    }
    sim, _ = _simulate(tmp_path / "sim", spec, noise=True)
    stages = _run(tmp_path, "noisy", _input("lmsq_sbet", sim))
    _, _, _, _, d = _match(
        sim / "truth" / "points.laz", Path(stages["georeference"]["outputs"]["points_georef"]["file"])
    )
    rms = np.sqrt(np.mean(np.sum(d**2, axis=1)))
    assert 0.045 < rms < 0.055
    assert abs(np.mean(d[:, 2])) < 0.002  # unbiased


def test_counters_equal_injected_faults(tmp_path):
    """Every fault the simulator injects is counted by the reader, exactly."""
    ld, res_ld = _simulate(
        tmp_path / "ld",
        LDMRS,
        noise=True,
        invalid_utc_scans=3,
        bad_gps_scans=2,
        lost_scans=3,
        empty_scans=2,
        clutter_points=40,
        dirt_points=9,
    )
    rg, res_rg = _simulate(
        tmp_path / "rg",
        {**RIEGL, "formats": ["lmsq_nmea"]},
        noise=True,
        pps_gaps=1,
        invalid_quality=50,
        dust_echoes=30,
        nmea_bad_checksums=7,
    )
    injected = json.loads((ld / "truth" / "faults.json").read_text())["ldmrs_mtig"]
    assert injected == res_ld.faults["ldmrs_mtig"]
    parse = _run(tmp_path, "ld", _input("ldmrs_mtig", ld), until="parse")["parse"]["metrics"]
    for key in ("invalid_scans", "bad_gps", "lost_scans", "empty_scans", "rejected_clutter", "rejected_dirt"):
        assert parse[key] == injected[key] > 0, key
    assert parse["malformed_scans"] == 0
    debug = (tmp_path / "out-ld" / "qc" / "debug.txt").read_text()
    assert f"invalid_scans {injected['invalid_scans']}" in debug
    injected = res_rg.faults["lmsq"]
    parse = _run(tmp_path, "rg", _input("lmsq_nmea", rg), until="parse")["parse"]["metrics"]
    assert parse["scanner_missed_pps"] == injected["missed_pps"] > 0
    assert parse["scanner_pps_recovered"] == injected["pps_recovered"] == injected["missed_pps"]
    assert parse["scanner_invalid_quality"] == injected["invalid_quality"] > 0
    assert parse["nmea_bad_checksum"] == injected["nmea_bad_checksums"] == 7
    # and the georeferenced output holds exactly the echoes without a fault the reader drops
    truth = laspy.read(rg / "truth" / "points.laz")
    kept = [FAULT_CODES["none"], FAULT_CODES["dust"], FAULT_CODES["pps_gap"]]  # pps_gap: dated by the counter
    invalid_in_gap = injected["invalid_quality"] - int(
        np.sum(np.asarray(truth.fault) == FAULT_CODES["invalid_quality"])
    )
    usable = np.isin(np.asarray(truth.fault), kept).sum() - invalid_in_gap
    assert parse["pulses_read"] == usable


def test_simulation_is_reproducible(tmp_path):
    digests = []
    for k in range(2):
        # one short line: every random draw of the simulator (noise, dust, navigation) is on it
        short = {**RIEGL["flight"], "lines": 1, "cross_line": False, "line_length_m": 80}
        spec = {**RIEGL, "formats": ["lmsq_nmea"], "flight": short}
        sim, _ = _simulate(tmp_path / f"s{k}", spec, noise=True, dust_echoes=5)
        digests.append(
            [hashlib.sha256((sim / f).read_bytes()).hexdigest() for f in ("lmsq/scan.lmsq", "lmsq/nav.nmea")]
        )
    assert digests[0] == digests[1]


def test_raw_input_cannot_skip_georeferencing(capsys):
    config = Path(__file__).resolve().parents[3] / "configs" / "flight.yaml"
    assert main(["validate", str(config), "--set", "stages.georeference.enabled=false"]) == 2
    err = capsys.readouterr().err
    assert "stages.georeference.enabled" in err and "raw format" in err and err.count("\n") == 1
