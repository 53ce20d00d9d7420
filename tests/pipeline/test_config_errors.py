"""Configuration errors: exit 2 and one sentence naming file, line and key."""

from __future__ import annotations

import subprocess
import sys

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


# --------------------------------------------------------------------------
# Hostile configurations (issue 18): refused in one sentence, never expanded


def _bomb(levels: int = 9) -> str:
    """The 'billion laughs' file: each level is nine aliases of the one before (9**levels values)."""
    text = "a: &a [" + ",".join(['"lol"'] * 9) + "]\n"
    names = "abcdefghijklmnop"
    for prev, name in zip(names[: levels - 1], names[1:levels], strict=True):
        text += f"{name}: &{name} [" + ",".join([f"*{prev}"] * 9) + "]\n"
    return text


def test_alias_bomb_is_refused_under_a_memory_limit(tmp_path):
    """9**9 values in 342 bytes: refused from the node graph, within 1 GB and 5 s of CPU.

    Before the fix the line recorder followed every alias: MemoryError after
    9 s at this limit.
    """
    path = tmp_path / "bomb.yaml"
    path.write_text(_bomb())
    assert len(path.read_bytes()) == 342
    script = (
        "import resource, sys\n"
        "resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))\n"
        "resource.setrlimit(resource.RLIMIT_CPU, (5, 5))\n"
        "from pipeline.config import load_yaml\n"
        "from pipeline.errors import ConfigError\n"
        "try:\n"
        "    load_yaml(sys.argv[1])\n"
        "except ConfigError as exc:\n"
        "    print(exc)\n"
        "    sys.exit(2)\n"
    )
    done = subprocess.run([sys.executable, "-c", script, str(path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr[-500:]
    assert "bomb.yaml, line 6: the aliases here expand to more than 100,000 values" in done.stdout


def test_aliases_of_a_reasonable_size_still_work(toy, capsys):
    toy.path.write_text(
        "name: toy\nsource: &s {path: numbers.txt}\noutput: out\n"
        "stages:\n  histogram: &h {bins: 3}\n  scale: {factor: 2}\n"
    )
    assert main(["validate", str(toy.path)]) == 0
    toy.path.write_text(toy.path.read_text() + "x: *h\n")  # an alias used where no key is allowed
    code, err = _validate(toy, capsys)
    assert code == 2 and "line 7: x: unknown key" in err


@pytest.mark.parametrize(
    ("text", "line", "words"),
    [
        ("x: " + "[" * 5000 + "]" * 5000 + "\n", 1, "more than 64 levels deep"),
        ("x:\n" + "".join(" " * i + "- \n" for i in range(0, 200, 2)), 65, "more than 64 levels deep"),
        ("x: " + "{a: " * 5000 + "1" + "}" * 5000 + "\n", 1, "more than 64 levels deep"),
        ("name: toy\nx: &x [1, *x]\n", 2, "a recursive alias"),
        ("name: toy\nx: &x {a: 1, b: *x}\n", 2, "a recursive alias"),
    ],
)
def test_deep_nesting_and_recursive_aliases_are_one_sentence(toy, capsys, text, line, words):
    toy.path.write_text(text)
    code, err = _validate(toy, capsys)
    assert code == 2
    assert f"toy.yaml, line {line}:" in err and words in err
    assert "Traceback" not in err and len(err.splitlines()) == 1


def test_an_endless_file_is_not_read_forever(toy, capsys):
    code = main(["validate", "/dev/zero"])  # a device: refused before reading (issue 38)
    err = capsys.readouterr().err
    assert code == 2
    assert "/dev/zero: not a configuration file but a character device" in err
    with open(toy.root / "huge.yaml", "wb") as fh:  # a regular file too large: refused by its size
        fh.truncate(8 << 20)
    code = main(["validate", str(toy.root / "huge.yaml")])
    assert code == 2
    assert "huge.yaml: not a configuration file (more than 1024 KiB)" in capsys.readouterr().err


def test_set_into_an_unknown_block_is_blamed_on_the_override(toy, capsys):
    code, err = _validate(toy, capsys, "--set", "stages.__init__.x=1")
    assert code == 2
    assert err == (
        "pipeline: error: --set stages.__init__.x=1: stages.__init__: unknown key; "
        "allowed here: histogram, scale, summary, total."
    )


def test_validate_lists_every_problem(toy, capsys):
    toy.path.write_text(
        "name: toy\nsource: {path: numbers.txt, comment: 3}\noutput: out\n"
        "stages:\n  scale: {factor: x}\n  histogram: {bins: 0}\nbogus: 1\n"
    )
    code, err = _validate(toy, capsys)
    assert code == 2
    lines = err.splitlines()
    assert lines[0] == "pipeline: error: 4 problems in the configuration:"
    assert [ln.split(": ")[0:2] for ln in lines[1:]] == [
        ["  " + str(toy.path) + ", line 2", "source.comment"],
        ["  " + str(toy.path) + ", line 5", "stages.scale.factor"],
        ["  " + str(toy.path) + ", line 6", "stages.histogram.bins"],
        ["  " + str(toy.path) + ", line 7", "bogus"],
    ]
    assert "more problem" not in err


def test_an_empty_block_says_so(toy, capsys):
    toy.path.write_text(toy.path.read_text().replace("  histogram:\n    bins: 2\n", "  histogram:\n"))
    code, err = _validate(toy, capsys)
    assert code == 2
    assert "toy.yaml, line 7: stages.histogram: an empty block; give it keys" in err and "got None" not in err


def test_a_missing_file_set_on_the_command_line_is_blamed_on_the_override(toy, capsys):
    """The override replaced the file's line, so it is named; its relative path was read from the
    configuration's folder, which the sentence says (from elsewhere, one expects the working folder)."""
    code, err = _validate(toy, capsys, "--set", "source.path=nowhere.txt")
    assert code == 2
    assert err.startswith("pipeline: error: --set source.path=nowhere.txt: source.path: file not found:")
    assert f"read from the configuration's folder, {toy.root.resolve()}" in err
