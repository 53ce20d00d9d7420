"""Every input file of every format, empty or blank, through the command line:
one sentence naming the file, exit 3 (bad input data), no traceback, no
products.  (An all-blank file is valid syntax with nothing in it.)"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from pipeline.cli import main

ROOT = Path(__file__).resolve().parents[3]
LMSQ = ROOT / "data_samples" / "flight_lmsq" / "lmsq"
CASES = [
    ("flight.yaml", "../data_samples/flight_ldmrs/ldmrs/acquisition.log.gz", "acquisition.log"),
    ("flight_nmea.yaml", "../data_samples/flight_lmsq/lmsq/scan.lmsq", "scan.lmsq"),
    ("flight_nmea.yaml", "../data_samples/flight_lmsq/lmsq/nav.nmea", "nav.nmea"),
    ("flight_nmea.yaml", "../data_samples/flight_lmsq/lmsq/ins.csv", "ins.csv"),
    ("flight_sbet.yaml", "../data_samples/flight_lmsq/lmsq/trajectory.sbet", "trajectory.sbet"),
    ("flight_sbet.yaml", "../data_samples/flight_lmsq/lmsq/trajectory.smrmsg", "trajectory.smrmsg"),
    ("las.yaml", "../data_samples/las/sample.laz", "sample.laz"),
]


@pytest.mark.parametrize("content", [b"", b"\n\n  \n"], ids=["empty", "blank"])
@pytest.mark.parametrize(("config", "original", "name"), CASES, ids=[c[2] for c in CASES])
def test_empty_or_blank_input_is_one_sentence_exit_3(tmp_path, capsys, config, original, name, content):
    text = (ROOT / "configs" / config).read_text()
    assert original in text
    for other in LMSQ.iterdir():  # the other files of the flight, intact
        shutil.copy(other, tmp_path / other.name)
    (tmp_path / name).write_bytes(content)
    text = text.replace(original, name).replace("../data_samples/flight_lmsq/lmsq/", "")
    text = text.replace("../data_samples/", str(ROOT / "data_samples") + "/")
    (tmp_path / "job.yaml").write_text(text)
    code = main(["run", str(tmp_path / "job.yaml"), "-q", "--set", "output=out", "--set", "cache=cache"])
    err = capsys.readouterr().err
    assert code == 3, err
    assert "Traceback" not in err and len(err.strip().splitlines()) == 1, err
    assert name in err, err
    assert not list((tmp_path / "out").glob("*.tif")), "no products from an empty input"
