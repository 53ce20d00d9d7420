"""No message prints a number's repr (``np.float64(0.5)`` since NumPy 2): numbers are formatted (``:g``, ``:.3f``).

Every f-string of an exception, a log line or a skip note in the product's
packages (``pipeline/``, ``stages/``, ``lidar/``, ``commands/``) is scanned for ``!r`` and ``repr(...)``; the ones left are on
strings (quoted on purpose) or in other areas' files, awaiting their fix.
"""

from __future__ import annotations

import ast
import struct
from pathlib import Path

import pytest

from pipeline.errors import InputDataError
from stages.parse.read_lmsq import LmsqCounters, read_lmsq

ROOT = Path(__file__).resolve().parents[2]
SINKS = {"info", "warning", "error", "debug", "exception", "note", "warn"}

#: (file, expression) shown with !r on purpose: strings, quoted so that blanks and empties show.
STRINGS = {
    ("lidar/checkpoints.py", "key"),
    ("lidar/checkpoints.py", "line.strip()"),
    ("commands/simulate/simulator.py", "start_utc"),
    ("pipeline/config.py", "err['input']"),
    ("pipeline/registry.py", "entry.name"),
}

#: The product's packages.
PACKAGES = ("pipeline", "stages", "lidar", "commands")


def _messages(tree: ast.AST):
    """The f-strings under a raise, a log call or a note."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Raise) and node.exc is not None:
            yield from (n for n in ast.walk(node.exc) if isinstance(n, ast.JoinedStr))
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr in SINKS:
            yield from (n for a in node.args for n in ast.walk(a) if isinstance(n, ast.JoinedStr))


def reprs_in_messages() -> set[tuple[str, str]]:
    found = set()
    for path in sorted(p for package in PACKAGES for p in ROOT.joinpath(package).rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        for message in _messages(ast.parse(path.read_text(encoding="utf-8"))):
            for part in message.values:
                if not isinstance(part, ast.FormattedValue):
                    continue
                if part.conversion == ord("r"):
                    found.add((rel, ast.unparse(part.value)))
                for call in ast.walk(part.value):
                    if isinstance(call, ast.Call) and getattr(call.func, "id", None) == "repr":
                        found.add((rel, ast.unparse(call.args[0])))
    return found


def test_no_message_prints_a_number_by_its_repr():
    found = reprs_in_messages()
    assert {rel for rel, _ in found} & {"lidar/checkpoints.py"}  # the scan reads the packages
    assert found - STRINGS == set()


def test_a_damaged_pps_is_reported_with_its_number_formatted(tmp_path):
    """An .lmsq PPS record whose seconds of week are out of range: the number as text, not a repr."""
    head = ROOT / "data_samples" / "flight_lmsq"
    sample = next(head.rglob("*.lmsq"))
    data = bytearray(sample.read_bytes())
    at = _first_pps(data)
    data[at + 1 : at + 9] = struct.pack("<d", 1e9)
    path = tmp_path / "pps.lmsq"
    path.write_bytes(bytes(data))
    with pytest.raises(InputDataError) as refused:
        for _ in read_lmsq(path, LmsqCounters()):
            pass
    assert "PPS seconds of week 1e+09 out of 0-604800" in str(refused.value)
    assert "np.float64" not in str(refused.value)


def _first_pps(data: bytearray) -> int:
    """The offset of the first PPS record (type 2) of an .lmsq file's bytes."""
    at = 16
    while data[at] != 2:
        at += 18
    return at
