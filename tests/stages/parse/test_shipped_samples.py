"""The shipped raw samples (data_samples/flight_*): what the readers count is what the simulator injected.

Each config runs to the strip adjustment (where every input-related warning
arises: parse, georeference, strip_adjust) on the committed files; its
``qc/debug.txt`` counters must equal ``truth/faults.json`` and the only
warnings are those the injected faults explain.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pyogrio
import pytest

from pipeline.cli import main
from tests.conftest import run_stages

ROOT = Path(__file__).resolve().parents[3]
SAMPLES = {"flight.yaml": "flight_ldmrs", "flight_nmea.yaml": "flight_lmsq", "flight_sbet.yaml": "flight_lmsq"}


def _debug(path: Path) -> dict[str, int]:
    """The ``name value`` counter lines of qc/debug.txt (up to the first blank line)."""
    out = {}
    for line in path.read_text().splitlines():
        if not line.strip():
            break
        name, value = line.split()
        out[name] = int(value)
    return out


def _expected(config: str, faults: dict) -> tuple[dict[str, int], set[str]]:
    """Counters the injected faults determine, and the warnings they explain."""
    if config == "flight.yaml":
        f = faults["ldmrs_mtig"]
        counters = {
            "scans_total": f["scans_written"],
            "scans_accepted": f["scans_written"] - f["invalid_scans"] - f["bad_gps"],
            "lost_scans": f["lost_scans"],
            "invalid_scans": f["invalid_scans"],
            "bad_gps": f["bad_gps"],
            "malformed_scans": 0,
            "empty_scans": f["empty_scans"],
            "rejected_clutter": f["rejected_clutter"],
            "rejected_dirt": f["rejected_dirt"],
            "rejected_zero": 0,
        }
        skipped = f["invalid_scans"] + f["bad_gps"]
        return counters, {f"[parse] {skipped} scans skipped; see qc/debug.txt"} if skipped else set()
    f = faults["lmsq"]
    counters = {
        "scanner_measurements": faults["echoes"],
        "scanner_before_first_pps": 0,
        "scanner_missed_pps": f["missed_pps"],
        "scanner_pps_recovered": f["pps_recovered"],
        "scanner_pps_ambiguous": f["missed_pps"] - f["pps_recovered"],
        "scanner_invalid_quality": f["invalid_quality"],
        "scanner_truncated_bytes": 0,
        "pulses_read": faults["echoes"] - f["invalid_quality"] - (f["missed_pps"] - f["pps_recovered"]),
        "navigation_malformed": 0,
        "navigation_not_increasing": 0,
        "navigation_truncated_bytes": 0,
    }
    if config == "flight_nmea.yaml":
        counters.update(
            nmea_bad_checksum=f["nmea_bad_checksums"],
            nmea_malformed=0,
            nmea_no_fix=0,
            nmea_fixes_2d=0,
            nmea_unknown=0,
            ins_epochs_without_position=0,
        )
    skipped = f["invalid_quality"] + f["missed_pps"] - f["pps_recovered"]
    return counters, {
        f"[parse] {skipped} measurements skipped, 0 bytes cut off; see qc/debug.txt"
    } if skipped else set()


@pytest.mark.parametrize("config", sorted(SAMPLES))
def test_sample_counts_what_was_injected_and_warns_of_nothing_else(tmp_path, capsys, config):
    faults = json.loads((ROOT / "data_samples" / SAMPLES[config] / "truth" / "faults.json").read_text())
    out = tmp_path / "out"
    args = ["run", str(ROOT / "configs" / config), "-q", "--until", "strip_adjust"]
    assert main([*args, "--set", f"output={out}", "--set", f"cache={tmp_path / 'cache'}"]) == 0
    warnings = {re.sub(r"^\S+ WARNING ", "", line) for line in capsys.readouterr().err.splitlines() if line.strip()}
    counters, explained = _expected(config, faults)
    assert warnings == explained
    debug = _debug(out / "qc" / "debug.txt")
    assert {k: debug.get(k) for k in counters} == counters
    # qc/trajectory.gpkg: one LineString per flight line
    lines = pyogrio.read_info(str(out / "qc" / "trajectory.gpkg"))
    assert lines["features"] == len(faults["line_biases_m"]) and lines["geometry_type"] == "LineString"
    run = run_stages(out)
    geo, adjust = run["georeference"]["metrics"], run["strip_adjust"]["metrics"]
    assert geo["rejected_no_trajectory"] == 0
    # every flown line is a strip, and the adjustment corrects every strip but the datum
    assert len(geo["strips"]) == len(faults["line_biases_m"]) == adjust["strips"]
    assert adjust["strips_not_determined"] == [] and adjust["strips_estimated"] == adjust["strips"] - 1
    if config == "flight.yaml":  # the main job's biased lines: the overlaps agree better after
        assert adjust["overlap_rms_before_m"] > 2 * adjust["overlap_rms_after_m"]


def test_both_lmsq_trajectories_georeference_the_same_pulses(tmp_path):
    """3.B (NMEA + INS CSV) and 3.C (SBET) of the same flight: the same pulses in the same strips."""
    strips = {}
    for config in ("flight_nmea.yaml", "flight_sbet.yaml"):
        out = tmp_path / config
        args = ["run", str(ROOT / "configs" / config), "-q", "--until", "georeference", "--set", f"output={out}"]
        assert main([*args, "--set", f"cache={tmp_path / 'cache'}"]) == 0
        geo = next(s for s in json.loads((out / "run.json").read_text())["stages"] if s["name"] == "georeference")
        strips[config] = (geo["metrics"]["pulses"], geo["metrics"]["strips"])
    assert strips["flight_nmea.yaml"] == strips["flight_sbet.yaml"]
    assert len(strips["flight_sbet.yaml"][1]) == 3
