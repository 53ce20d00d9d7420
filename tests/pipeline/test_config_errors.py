"""Configuration errors: exit 2 and one sentence naming file, line and key."""

from __future__ import annotations

import pytest

from pipeline.cli import main


def _validate(toy, capsys, *extra: str) -> tuple[int, str]:
    code = main(["validate", str(toy.path), *extra])
    return code, capsys.readouterr().err.strip()


def test_valid_config_passes(toy, capsys):
    code = main(["validate", str(toy.path)])
    assert code == 0
    assert "load -> scale -> total -> histogram -> summary" in capsys.readouterr().out


def test_typo_in_key_names_line_and_suggestion(toy, capsys):
    toy.path.write_text(toy.path.read_text().replace("bins: 2", "binz: 2"))
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "toy.yaml, line 8: stages.histogram.binz: unknown key (did you mean 'bins'?)" in err
    assert "Traceback" not in err


def test_wrong_type_names_line(toy, capsys):
    toy.path.write_text(toy.path.read_text().replace("bins: 2", "bins: two"))
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "toy.yaml, line 8: stages.histogram.bins:" in err
    assert "'two'" in err


def test_missing_input_file_names_line(toy, capsys):
    toy.path.write_text(toy.path.read_text().replace("numbers.txt", "nowhere.txt"))
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "toy.yaml, line 3: source.path: file not found:" in err
    assert "nowhere.txt" in err


def test_missing_required_key_names_parent_line(toy, capsys):
    toy.path.write_text(toy.path.read_text().replace("  path: numbers.txt\n", "  comment: ';'\n"))
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "toy.yaml, line 2: source.path: required key is missing" in err


def test_unknown_stage_block(toy, capsys):
    toy.path.write_text(toy.path.read_text() + "  scael: {factor: 2}\n")
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "line 9: stages.scael: unknown key (did you mean 'scale'?)" in err


def test_duplicate_key_is_an_error(toy, capsys):
    toy.path.write_text(toy.path.read_text() + "output: elsewhere\n")
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "line 9: key 'output' is given twice" in err


def test_invalid_yaml_names_line(toy, capsys):
    toy.path.write_text("name: toy\nsource: [unclosed\n")
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "toy.yaml, line" in err and "not valid YAML" in err


def test_missing_config_file(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PIPELINE_PLUGIN", "tests.pipeline.toy:plugin")
    assert main(["validate", str(tmp_path / "none.yaml")]) == 2
    assert "configuration file not found" in capsys.readouterr().err


def test_set_override_changes_value_and_is_named_in_errors(toy, capsys):
    code, err = _validate(toy, capsys, "--set", "stages.histogram.bins=0")
    assert code == 2
    assert err.startswith("pipeline: error: --set stages.histogram.bins=0: stages.histogram.bins:")
    code, err = _validate(toy, capsys, "--set", "stages.scale.factor=oops")
    assert code == 2 and "--set stages.scale.factor=oops" in err
    assert main(["validate", str(toy.path), "--set", "stages.histogram.bins=7"]) == 0


def test_set_into_a_scalar_is_an_error(toy, capsys):
    code, err = _validate(toy, capsys, "--set", "name.first=x")
    assert code == 2
    assert "'name' is not a mapping" in err


@pytest.mark.parametrize("bad", ["noequals", "=3", "a..b=1"])
def test_malformed_set(toy, capsys, bad):
    code, err = _validate(toy, capsys, "--set", bad)
    assert code == 2 and err


def test_paths_are_relative_to_the_config_file(toy, tmp_path, monkeypatch):
    other = tmp_path / "elsewhere"
    other.mkdir()
    monkeypatch.chdir(other)  # the current directory must not matter
    assert toy.run() == 0
    assert (toy.root / "out" / "total.json").exists()
    assert not (other / "out").exists()
