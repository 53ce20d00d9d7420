"""Faults of the machine and of a hostile user, on the toy stages (issue 38).

An input that changes while it is read, an input that is not a regular
file.  Each case ends in a true result or in one sentence with the
documented exit code.
"""

from __future__ import annotations

import errno
import os
from pathlib import Path

import pytest

from pipeline import runner
from pipeline.config import load_config
from pipeline.errors import ConfigError
from pipeline.stage import config_model
from tests.pipeline import toy as toymod


def _entries(toy, stage: str) -> list[Path]:
    return list((toy.root / "out" / ".cache" / stage).glob("*/entry.json"))


# --------------------------------------------------------------------------
# An input that changes while the run reads it (item 1)


def _replace(path: Path, text: str, how: str) -> None:
    if how == "rewritten":
        path.write_text(text)
    else:  # renamed over: another inode under the same name
        new = path.with_name("incoming.tmp")
        new.write_text(text)
        os.replace(new, path)


@pytest.mark.parametrize("how", ["rewritten", "renamed over"])
@pytest.mark.parametrize("when", ["before the stage reads it", "after the stage read it"])
def test_an_input_changed_during_the_run_is_refused_and_never_cached(toy, capsys, monkeypatch, how, when):
    source = toy.root / "numbers.txt"
    real_run = toymod.Load.run

    def run_while_it_changes(self, ctx):
        if when.startswith("before"):
            _replace(source, "100\n200\n", how)
        real_run(self, ctx)
        if when.startswith("after"):
            _replace(source, "100\n200\n", how)

    monkeypatch.setattr(toymod.Load, "run", run_while_it_changes)
    assert toy.run() == 3
    err = capsys.readouterr().err.strip()
    assert err == (
        f"pipeline: error: stage 'load': the input {source} changed while the run read it; nothing was cached: "
        "run again once it is no longer being written."
    )
    assert not _entries(toy, "load")
    assert not list((toy.root / "out" / ".cache" / "load").glob(".tmp-*"))
    monkeypatch.setattr(toymod.Load, "run", real_run)
    assert toy.run() == 0  # the file no longer changes: computed from the bytes it now holds
    assert toy.statuses()["load"] == "ran"
    assert toy.product("total.json") == {"total": 900.0}


def test_an_input_touched_but_not_changed_is_accepted(toy, monkeypatch):
    source = toy.root / "numbers.txt"
    real_run = toymod.Load.run

    def run_and_touch(self, ctx):
        real_run(self, ctx)
        _replace(source, source.read_text(), "renamed over")  # same bytes, another inode and mtime

    monkeypatch.setattr(toymod.Load, "run", run_and_touch)
    assert toy.run() == 0
    assert toy.product("total.json") == {"total": 48.0}
    monkeypatch.setattr(toymod.Load, "run", real_run)
    assert toy.run() == 0 and toy.statuses()["load"] == "cached"


def _config_then(toy, damage) -> tuple:
    """The validated toy configuration, its input then damaged (as between validation and the run)."""
    config = load_config(toy.path, config_model(toymod.plugin), [])
    source = toy.root / "numbers.txt"
    source.unlink()
    damage(source)
    return config, source


@pytest.mark.parametrize(
    ("kind", "damage"),
    [
        ("a FIFO (named pipe)", os.mkfifo),
        ("a folder", os.mkdir),
        ("a character device", lambda p: p.symlink_to("/dev/zero")),
    ],
)
def test_an_input_that_is_not_a_regular_file_is_refused_without_opening_it(toy, kind, damage):
    config, source = _config_then(toy, damage)
    with pytest.raises(ConfigError) as exc:
        runner.run(config, toymod.plugin, config_path=toy.path)
    assert str(exc.value) == (
        f"stage 'load': the input {source} is {kind}, not a regular file; name the file itself in the configuration."
    )


def test_an_input_that_cannot_be_read_is_exit_3_naming_it(toy, capsys, monkeypatch):
    source = toy.root / "numbers.txt"
    real_open = os.open

    def refused(path, *args, **kwargs):
        if Path(path) == source:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", refused)  # as chmod 000 does (tests may run as root)
    assert toy.run() == 3
    assert capsys.readouterr().err.strip() == (
        f"pipeline: error: stage 'load': the input {source} cannot be read (Permission denied); "
        "make it readable and run again."
    )
