"""Project rules checked on the source tree."""

from __future__ import annotations

import re
from pathlib import Path

from commands.configdoc import render, render_simulator
from tests.conftest import LONGEST_FIRST

ROOT = Path(__file__).resolve().parents[1]


def _sources(folder: str):
    found = sorted((ROOT / folder).rglob("*.py"))
    assert found, f"{folder}/ holds no Python: a check over it would pass by reading nothing"
    return found


def test_engine_knows_no_domain_words():
    words = re.compile(r"\b(las|laz|lidar|ground|point ?cloud)\b", re.IGNORECASE)
    hits = [
        f"{p.relative_to(ROOT)}:{i}"
        for p in _sources("pipeline")
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if words.search(line)
    ]
    assert not hits, hits


def test_no_unsafe_deserialisation_or_eval():
    bad = re.compile(
        r"^\s*(import|from)\s+(pickle|marshal|dill|cloudpickle|shelve)\b|\beval\(|\bexec\(|yaml\.load\(|yaml\.unsafe_load|yaml\.Loader\b|yaml\.FullLoader"
    )
    hits = [
        f"{p.relative_to(ROOT)}:{i}"
        for folder in ("pipeline", "stages", "lidar", "commands")
        for p in _sources(folder)
        for i, line in enumerate(p.read_text().splitlines(), 1)
        if bad.search(line)
    ]
    assert not hits, hits


def test_config_reference_is_current():
    committed = (ROOT / "docs" / "CONFIG.md").read_text()
    assert committed == render(), "docs/CONFIG.md is stale: python -m commands.configdoc > docs/CONFIG.md"

    committed = (ROOT / "docs" / "SIMULATOR.md").read_text()
    assert committed == render_simulator(), "stale: python -m commands.configdoc --simulator > docs/SIMULATOR.md"


def test_the_longest_files_named_for_scheduling_exist():
    """tests/conftest.py's LONGEST_FIRST orders the run; a name that no longer exists would order nothing."""
    assert [name for name in LONGEST_FIRST if not (ROOT / name).is_file()] == []
