"""Project rules checked on the source tree."""

from __future__ import annotations

import ast
import re
from pathlib import Path

from commands.configdoc import render, render_simulator
from pipeline.config import field_models
from pipeline.stage import config_model
from stages.plugin import plugin
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


def _setting_defaults() -> dict[str, set[str]]:
    """Every setting of the configuration (stage parameters, nested blocks, registered algorithms) by name:
    the reprs of the literal defaults it has."""

    found: dict[str, set[str]] = {}

    def visit(model) -> None:
        for name, field in model.model_fields.items():
            if isinstance(field.default, bool | int | float | str) and field.default is not None:
                found.setdefault(name, set()).add(repr(field.default))
            for sub in field_models(field):
                visit(sub)

    visit(config_model(plugin))
    return found


#: Function parameters that share a setting's name and value but are not that setting: how much work a process
#: holds at once (the runs' settings of that name are other settings), and the simulator, which keeps values of
#: its own so that it checks the code instead of sharing its mistakes.
NOT_SETTINGS = {"chunk_size"}
INDEPENDENT = ("commands/simulate/",)


def test_one_default_per_setting():
    """No function keeps a literal copy of a setting's default: it takes the model's, or a constant both read."""
    settings = _setting_defaults()
    copies = []
    for folder in ("stages", "lidar", "commands"):
        for path in _sources(folder):
            rel = path.relative_to(ROOT).as_posix()
            if rel.startswith(INDEPENDENT):
                continue
            for node in ast.walk(ast.parse(path.read_text())):
                if not isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                    continue
                a = node.args
                pos = a.posonlyargs + a.args
                pairs = list(zip(pos[len(pos) - len(a.defaults) :], a.defaults, strict=True))
                pairs += [(k, d) for k, d in zip(a.kwonlyargs, a.kw_defaults, strict=True) if d is not None]
                for arg, default in pairs:
                    if arg.arg in NOT_SETTINGS or not isinstance(default, ast.Constant):
                        continue
                    if repr(default.value) in settings.get(arg.arg, ()):
                        copies.append(f"{rel}:{node.lineno} {node.name}({arg.arg}={default.value!r})")
    assert len(settings) > 100  # the configuration was read
    assert not copies, copies
