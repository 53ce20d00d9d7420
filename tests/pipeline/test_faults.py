"""Faults of the machine and of a hostile user, on the toy stages (issue 38).

An input that changes while it is read, an input that is not a regular
file, a full or read-only disk on the cache or the output side, a cache
whose folders were replaced by links, files or folders, a product replaced
by a link.  Each case ends in a true result or in one sentence with the
documented exit code, and nothing outside the cache and output folders is
touched.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from pipeline import runner
from pipeline.config import load_config
from pipeline.errors import ConfigError, EnvironmentFailure
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


# --------------------------------------------------------------------------
# A full or read-only disk: which folder, which side (item 4)


def _sentence(side: str, folder: Path, state: str, why: str) -> str:
    fix = "free space" if state == "is full" else "make it writable"
    return (
        f"the {side} folder {folder} {state} ({why}); {fix} or point `{side}:` elsewhere, "
        "then run again: complete stages are reused."
    )


@pytest.mark.parametrize(
    ("code", "state"),
    [(errno.ENOSPC, "is full"), (errno.EDQUOT, "is full"), (errno.EROFS, "cannot be written")],
)
def test_a_stage_that_fills_or_meets_a_read_only_cache_is_exit_4_naming_it(toy, capsys, monkeypatch, code, state):
    def fail(self, ctx):
        (ctx.workdir / "part").write_text("half")
        name = None if code != errno.EROFS else str(ctx.workdir / "part")  # write() names no file; open() does
        raise OSError(code, os.strerror(code), name)

    monkeypatch.setattr(toymod.Scale, "run", fail)
    assert toy.run() == 4
    cache = toy.root / "out" / ".cache"
    err = capsys.readouterr().err.strip()
    assert err == f"pipeline: error: stage 'scale': {_sentence('cache', cache, state, os.strerror(code))}"
    assert not _entries(toy, "scale") and not list((cache / "scale").glob(".tmp-*"))
    assert "please report it" not in err


def test_a_full_disk_outside_the_cache_is_named_as_it_is(toy, capsys, monkeypatch, tmp_path):
    scratch = tmp_path / "scratch"
    scratch.mkdir()

    def fail(self, ctx):
        raise OSError(errno.ENOSPC, "No space left on device", str(scratch / "sort.tmp"))

    monkeypatch.setattr(toymod.Scale, "run", fail)
    assert toy.run() == 4
    assert capsys.readouterr().err.strip() == (
        f"pipeline: error: stage 'scale': the disk holding {scratch} is full (No space left on device); "
        "free space, then run again: complete stages are reused."
    )


def test_an_environment_failure_in_a_stage_is_told_with_the_stage_name(toy, capsys, monkeypatch):
    def worker_died(self, ctx):
        raise EnvironmentFailure("a worker process died (killed by signal 9, SIGKILL); run again to resume.")

    monkeypatch.setattr(toymod.Histogram, "run", worker_died)
    assert toy.run() == 4
    assert capsys.readouterr().err.strip() == (
        "pipeline: error: stage 'histogram': a worker process died (killed by signal 9, SIGKILL); run again to resume."
    )


def test_a_read_only_output_folder_while_publishing_is_exit_4_naming_it(toy, capsys, monkeypatch):
    assert toy.run() == 0
    (toy.root / "numbers.txt").write_text("5\n6\n")
    real = runner._stage_copy

    def read_only(src, dst):
        if dst.name == "hist.json":
            raise OSError(errno.EROFS, "Read-only file system", str(dst.parent / f".{dst.name}.1234.tmp"))
        return real(src, dst)

    monkeypatch.setattr(runner, "_stage_copy", read_only)
    capsys.readouterr()
    assert toy.run() == 4
    out = toy.root / "out"
    assert capsys.readouterr().err.strip() == (
        f"pipeline: error: {_sentence('output', out, 'cannot be written', 'Read-only file system')}"
    )
    assert toy.product("total.json") == {"total": 48.0}  # the old products stay


def test_a_cache_root_that_cannot_be_written_is_exit_4_naming_it(toy, capsys, monkeypatch):
    cache = toy.root / "out" / ".cache"
    real_open = os.open

    def read_only(path, *args, **kwargs):
        if Path(path).parent == cache and Path(path).name.startswith(".write-test-"):
            raise OSError(errno.EROFS, "Read-only file system", str(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    assert toy.run() == 4
    assert capsys.readouterr().err.strip() == (
        f"pipeline: error: {_sentence('cache', cache, 'cannot be written', 'Read-only file system')}"
    )


# --------------------------------------------------------------------------
# The cache is the cache: damaged stage folders (item 5)


def _damage_stage_folder(toy, how: str, outside: Path, monkeypatch) -> None:
    stage = toy.root / "out" / ".cache" / "scale"
    record = next(s for s in toy.manifest()["stages"] if s["name"] == "scale")
    if how == "lock is a folder":
        lock = stage / f".{record['key']}.lock"
        lock.unlink()
        lock.mkdir()
        (lock / "inside").write_text("x")
        return
    if how == "read-only":  # chmod a-w or a read-only mount (tests may run as root): the first workspace fails
        shutil.rmtree(stage / record["key"])
        real = tempfile.mkdtemp
        calls = []

        def refused_once(*args, **kwargs):
            if Path(kwargs.get("dir", "")) == stage and not calls:
                calls.append(1)
                raise OSError(errno.EROFS, "Read-only file system", str(stage))
            return real(*args, **kwargs)

        monkeypatch.setattr(tempfile, "mkdtemp", refused_once)
        return
    shutil.rmtree(stage)
    if how == "a link":
        stage.symlink_to(outside, target_is_directory=True)
    else:
        stage.write_text("not a folder")


@pytest.mark.parametrize("how", ["a link", "a file", "lock is a folder", "read-only"])
def test_a_damaged_stage_folder_is_set_aside_and_recomputed(toy, capsys, monkeypatch, tmp_path, how):
    outside = tmp_path / "outside"
    (outside / ".tmp-x").mkdir(parents=True)
    (outside / "keep.txt").write_text("keep me")
    assert toy.run() == 0
    _damage_stage_folder(toy, how, outside, monkeypatch)
    capsys.readouterr()
    assert toy.run() == 0
    err = capsys.readouterr().err
    assert err.count("is damaged") == 1 and "scale" in err, err
    assert sorted(p.name for p in outside.iterdir()) == [".tmp-x", "keep.txt"]  # nothing made or removed outside
    assert (outside / "keep.txt").read_text() == "keep me"
    cache = toy.root / "out" / ".cache"
    assert (cache / "scale").is_dir() and not (cache / "scale").is_symlink()
    assert toy.product("total.json") == {"total": 48.0}
    assert toy.run() == 0
    assert toy.statuses()["scale"] == "cached"
    assert "damaged" not in capsys.readouterr().err


def test_a_dry_run_never_reads_through_a_stage_folder_that_is_a_link(toy, capsys, tmp_path):
    assert toy.run() == 0
    stage = toy.root / "out" / ".cache" / "scale"
    outside = tmp_path / "outside"
    shutil.copytree(stage, outside)
    shutil.rmtree(stage)
    stage.symlink_to(outside, target_is_directory=True)
    capsys.readouterr()
    assert toy.run("--dry-run") == 0
    assert [line.split()[1] for line in capsys.readouterr().out.splitlines() if line.startswith("scale")] == ["run"]


# --------------------------------------------------------------------------
# A product replaced by a link (item 7)


def test_a_product_replaced_by_a_link_is_replaced_never_its_target(toy, capsys, tmp_path):
    assert toy.run() == 0
    out = toy.root / "out"
    target = tmp_path / "elsewhere.json"
    target.write_text("precious")
    (out / "total.json").unlink()
    (out / "total.json").symlink_to(target)
    capsys.readouterr()
    assert toy.run() == 0
    err = capsys.readouterr().err
    assert (
        f"the product 'total.json' in the output folder {out} is a symbolic link to {target}; "
        "publishing replaces the link, never its target"
    ) in err
    assert not (out / "total.json").is_symlink() and toy.product("total.json") == {"total": 48.0}
    assert target.read_text() == "precious"
    assert json.loads((out / "run.json").read_text())["status"] == "ok"


@pytest.mark.parametrize("to", ["the input", "its folder"])
def test_a_product_that_is_a_link_to_an_input_is_refused_saying_so(toy, capsys, to):
    assert toy.run() == 0
    out = toy.root / "out"
    source = toy.root / "numbers.txt"
    (out / "total.json").unlink()
    (out / "total.json").symlink_to(source if to == "the input" else toy.root)
    capsys.readouterr()
    assert toy.run() == 2
    what = f"the input {source}" if to == "the input" else f"{toy.root}, which holds the input {toy.path}"
    assert capsys.readouterr().err.strip() == (
        f"pipeline: error: the product 'total.json' in the output folder {out} is a symbolic link to {what}: "
        "remove the link (not its target) or choose another output."
    )
    assert source.read_text() == "1\n2\n3 # three\n10\n"
