"""Time going backwards in an LD-MRS acquisition log (issue 18, item 7).

A small simulated flight, damaged as field logs are: the whole log written
twice, one scan stamped 9999-12-31, one scan moved a minute earlier, a run
of scans moved a minute earlier, the files of a survey given out of order.
The unambiguous faults are skipped and counted (QC counters and
``qc/debug.txt``); the others are exit 3 naming the file and line.  Before
the fix every one ended as an internal error from georeferencing
("trajectory times must increase strictly").
"""

from __future__ import annotations

import gzip
import json
import re
from datetime import datetime, timedelta
from pathlib import Path

import numpy as np
import pytest

from lidar.georeferencing import prepare_trajectory
from pipeline.cli import main
from pipeline.errors import InputDataError
from stages.parse.read_ldmrs import Counters, Scan, TimeOrder
from tests.flights import simulate_ldmrs_line


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    root = tmp_path_factory.mktemp("timeorder")
    simulate_ldmrs_line(root / "ld")
    text = gzip.decompress((root / "ld" / "ldmrs" / "acquisition.log.gz").read_bytes()).decode()
    return root, text


def _scans(text: str) -> tuple[list[str], list[str]]:
    """The header lines and the scan blocks ('SCAN ...' to 'END') of a log."""
    head, _, body = text.partition("SCAN ")
    blocks = ["SCAN " + b for b in body.split("SCAN ")]
    return [head], blocks


def _shift(block: str, seconds: float) -> str:
    def move(m: re.Match) -> str:
        t = datetime.fromisoformat(m.group(1).replace("Z", "+00:00")) + timedelta(seconds=seconds)
        return "UTC " + t.strftime("%Y-%m-%dT%H:%M:%S.%fZ")

    return re.sub(r"UTC (\S+)", move, block)


def _run(tmp: Path, logs: list[str], capsys) -> tuple[int, dict, str]:
    paths = []
    for i, text in enumerate(logs):
        path = tmp / f"log{i}.log"
        path.write_text(text)
        paths.append(str(path))
    config = tmp / "c.yaml"
    config.write_text(
        f"input:\n  format: ldmrs_mtig\n  paths: [{', '.join(paths)}]\n  mounting: cb5000\noutput: out\n"
        "stages: {georeference: {strips: {keep_turns: true}}}\n"
    )
    code = main(["run", str(config), "-q", "--until", "georeference"])
    err = capsys.readouterr().err
    assert "Traceback" not in err and "internal error" not in err, err
    metrics = {}
    if code == 0:
        stages = json.loads((tmp / "out" / "run.json").read_text())["stages"]
        metrics = next(s for s in stages if s["name"] == "parse")["metrics"]
        debug = (tmp / "out" / "qc" / "debug.txt").read_text()
        assert f"duplicate_scans {metrics['duplicate_scans']}" in debug
        assert f"out_of_order_scans {metrics['out_of_order_scans']}" in debug
    return code, metrics, err


@pytest.fixture(scope="module")
def clean(flight, tmp_path_factory):
    """The undamaged log's figures."""
    _, text = flight
    tmp = tmp_path_factory.mktemp("clean")

    class NoCapture:
        def readouterr(self):
            class R:
                err = ""

            return R()

    code, m, _ = _run(tmp, [text], NoCapture())
    assert code == 0 and m["duplicate_scans"] == 0 and m["out_of_order_scans"] == 0
    return m


def test_a_log_written_twice_counts_every_repeated_scan(flight, clean, tmp_path, capsys):
    _, text = flight
    code, m, _ = _run(tmp_path, [text + text.split("\n", 2)[2]], capsys)  # the second copy without its header
    assert code == 0
    assert m["scans_accepted"] == clean["scans_accepted"]
    assert m["duplicate_scans"] == clean["scans_accepted"]
    assert m["lost_scans"] == clean["lost_scans"]
    assert m["points_valid"] == clean["points_valid"]
    assert any("repeats a scan already read" in p for p in m["problems"])


def test_the_same_log_given_twice_counts_every_repeated_scan(flight, clean, tmp_path, capsys):
    _, text = flight
    code, m, _ = _run(tmp_path, [text, text], capsys)
    assert code == 0
    assert m["scans_accepted"] == clean["scans_accepted"] and m["duplicate_scans"] == clean["scans_accepted"]


@pytest.mark.parametrize("which", ["first", "middle", "last"])
def test_one_scan_stamped_9999_is_skipped_and_counted(flight, clean, tmp_path, capsys, which):
    _, text = flight
    head, blocks = _scans(text)
    i = {"first": 0, "middle": len(blocks) // 2, "last": len(blocks) - 2}[which]
    blocks[i] = re.sub(r"UTC \S+", "UTC 9999-12-31T23:59:59.000000Z", blocks[i])
    code, m, _ = _run(tmp_path, ["".join(head + blocks)], capsys)
    assert code == 0
    assert m["out_of_order_scans"] == 1 and m["scans_accepted"] == clean["scans_accepted"] - 1
    line = 1 + "".join(head + blocks[:i]).count("\n")
    assert any(f"log0.log, line {line}: scan" in p and "later than the scans after it" in p for p in m["problems"])


def test_one_scan_moved_a_minute_earlier_is_skipped_and_counted(flight, clean, tmp_path, capsys):
    _, text = flight
    head, blocks = _scans(text)
    i = len(blocks) // 2
    blocks[i] = _shift(blocks[i], -60.0)
    code, m, _ = _run(tmp_path, ["".join(head + blocks)], capsys)
    assert code == 0
    assert m["out_of_order_scans"] == 1 and m["scans_accepted"] == clean["scans_accepted"] - 1
    line = 1 + "".join(head + blocks[:i]).count("\n")
    assert any(f"line {line}: scan" in p and "earlier than the scans before and after" in p for p in m["problems"])


def test_scans_moved_a_minute_earlier_are_exit_3_naming_the_line(flight, tmp_path, capsys):
    _, text = flight
    head, blocks = _scans(text)
    i = len(blocks) // 2
    for k in range(i, i + 5):
        blocks[k] = _shift(blocks[k], -60.0)
    code, _, err = _run(tmp_path, ["".join(head + blocks)], capsys)
    line = 1 + "".join(head + blocks[:i]).count("\n")
    assert code == 3
    assert f"log0.log, line {line}: the time goes backwards" in err
    assert err.count("\n") == 1


def test_files_given_out_of_order_are_exit_3(flight, tmp_path, capsys):
    _, text = flight
    head, blocks = _scans(text)
    half = len(blocks) // 2
    code, _, err = _run(tmp_path, ["".join(head + blocks[half:]), "".join(head + blocks[:half])], capsys)
    line = 1 + head[0].count("\n")  # the first scan of the second file
    assert code == 3 and f"log1.log, line {line}: the time goes backwards" in err


def test_a_trajectory_going_back_is_input_data_naming_the_epoch():
    t = np.array([0.0, 1.0, 2.0, 1.5, 3.0])
    z = np.zeros(5)
    with pytest.raises(InputDataError, match=r"epoch 3 \(t = 1.500000 s\) is not after epoch 2 \(t = 2.000000 s\)"):
        prepare_trajectory(t, z + 40.0, z - 3.0, z + 600.0, z, z, z, "NED")


def test_the_last_scan_stamped_9999_is_skipped_and_counted(flight, clean, tmp_path, capsys):
    """The last scan has one neighbour: far from it (in the log's scan intervals) is out of line too."""
    _, text = flight
    head, blocks = _scans(text)
    blocks[-1] = re.sub(r"UTC \S+", "UTC 9999-12-31T23:59:59.000000Z", blocks[-1])
    code, m, _ = _run(tmp_path, ["".join(head + blocks)], capsys)
    assert code == 0
    assert m["out_of_order_scans"] == 1 and m["scans_accepted"] == clean["scans_accepted"] - 1
    line = 1 + "".join(head + blocks[:-1]).count("\n")
    assert any(
        f"log0.log, line {line}: scan" in p and "far from the log's 0.080 s scan interval" in p for p in m["problems"]
    )
    times = np.loadtxt(tmp_path / "out" / "qc" / "lla_eul_vel.csv", delimiter=",", skiprows=1, usecols=0, ndmin=1)
    assert times.max() - times.min() < 3600  # no epoch in the year 9999


def test_the_first_scan_a_day_early_is_skipped_and_counted(flight, clean, tmp_path, capsys):
    _, text = flight
    head, blocks = _scans(text)
    blocks[0] = _shift(blocks[0], -86_400.0)
    code, m, _ = _run(tmp_path, ["".join(head + blocks)], capsys)
    assert code == 0
    assert m["out_of_order_scans"] == 1 and m["scans_accepted"] == clean["scans_accepted"] - 1
    assert any("line 4: scan" in p and "between it and its one neighbour" in p for p in m["problems"])


def _scan(number: int, time: float):
    return Scan(number, time, 7, (40.0, -3.0, 700.0), (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), np.zeros((2, 6)), number)


def _order(times: list[float], numbers: list[int] | None = None) -> tuple[list[int], int]:
    counters = Counters(scans_accepted=len(times), points_valid=2 * len(times))
    order = TimeOrder(counters)
    out = []
    for n, t in zip(numbers or range(len(times)), times, strict=True):
        out += order.feed(_scan(n, t))
    out += order.flush()
    return [s.number for s in out], counters.out_of_order_scans


def test_the_ends_are_judged_by_the_scan_numbers_between_them():
    steady = [100.0 + 0.08 * i for i in range(6)]
    assert _order(steady) == ([0, 1, 2, 3, 4, 5], 0)
    assert _order([*steady[:-1], 9e10]) == ([0, 1, 2, 3, 4], 1)  # last far in the future
    assert _order([-5e8, *steady[1:]]) == ([1, 2, 3, 4, 5], 1)  # first far in the past
    # 20 s between the last two scans, but 250 scan numbers lost between them: a gap, not a fault
    assert _order([*steady[:-1], steady[-2] + 20.0], [0, 1, 2, 3, 4, 254]) == ([0, 1, 2, 3, 4, 254], 0)
    assert _order([*steady[:-1], steady[-2] + 20.0]) == ([0, 1, 2, 3, 4], 1)  # 20 s for one scan number
    assert _order([1.0, 9e10]) == ([0, 1], 0)  # two scans: no interval known, nothing judged
    assert _order([1.0, 1.08, 9e10]) == ([0, 1], 1)
