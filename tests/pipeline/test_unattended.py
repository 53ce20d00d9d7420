"""Unattended runs under hostile conditions (issue 18), on the toy stages.

Damaged cache entries, a full disk while publishing, two configurations
sharing one output folder, inputs and planted links in the output and cache
folders, stale products, oversized tilings.  Each case either works as the
README promises or ends in one sentence with the documented exit code.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import pytest

from pipeline import executor as executor_mod
from pipeline import runner
from pipeline.cache import Cache
from pipeline.cli import main
from pipeline.errors import ConfigError
from pipeline.tiling import MAX_TILES, Layout


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _entry_of(toy, stage: str) -> Path:
    record = next(s for s in toy.manifest()["stages"] if s["name"] == stage)
    return Path(next(iter(record["outputs"].values()))["file"]).parent


def _folder_matches_manifest(out: Path) -> None:
    """Every product run.json lists is in the folder with its checksum."""
    manifest = json.loads((out / "run.json").read_text())
    for name, product in manifest["products"].items():
        assert _sha(out / name) == product["sha256"], name


# --------------------------------------------------------------------------
# Damaged cache entries (items 2 and 11)


def test_a_damaged_entry_is_replaced_not_kept(toy, capsys):
    """Same size, other bytes: the fresh result replaces the entry and is what downstream reads."""
    assert toy.run() == 0
    scaled = _entry_of(toy, "scale") / "scaled.json"
    assert json.loads(scaled.read_text()) == [3.0, 6.0, 9.0, 30.0]
    scaled.write_text(scaled.read_text().replace("30.0", "90.0"))  # same size: only the checksum can tell
    capsys.readouterr()
    assert toy.run("--force", "total") == 0  # total re-reads the scaled values
    assert "fails its SHA-256 checksum" in capsys.readouterr().err
    assert toy.product("total.json") == {"total": 48.0}  # 108 from the damaged entry
    assert json.loads(scaled.read_text()) == [3.0, 6.0, 9.0, 30.0]
    assert toy.run() == 0
    assert toy.statuses()["scale"] == "cached"
    assert "damaged" not in capsys.readouterr().err


@pytest.mark.parametrize("damage", ["file", "dangling link", "link to another entry", "nested brackets"])
def test_an_entry_damaged_in_any_shape_is_recomputed(toy, capsys, tmp_path, damage):
    assert toy.run() == 0
    entry = _entry_of(toy, "scale")
    other = _entry_of(toy, "total")
    before = sorted(p.name for p in other.iterdir())
    shutil.rmtree(entry)
    if damage == "file":
        entry.write_text("not a folder")
    elif damage == "dangling link":
        entry.symlink_to(tmp_path / "nowhere")
    elif damage == "link to another entry":
        entry.symlink_to(other)
    else:
        entry.mkdir()
        (entry / "entry.json").write_text("[" * 200_000 + "]" * 200_000)
    capsys.readouterr()
    assert toy.run() == 0, capsys.readouterr().err
    assert toy.statuses()["scale"] == "ran"
    assert entry.is_dir() and not entry.is_symlink()
    assert json.loads((entry / "scaled.json").read_text()) == [3.0, 6.0, 9.0, 30.0]
    assert sorted(p.name for p in other.iterdir()) == before  # what a link pointed to is untouched
    assert not (tmp_path / "nowhere").exists()
    assert "cache entry scale/" in capsys.readouterr().err
    assert toy.run() == 0 and toy.statuses()["scale"] == "cached"


def test_a_stage_folder_that_stays_unwritable_is_one_sentence_exit_4(toy, capsys, monkeypatch):
    assert toy.run() == 0

    def refused(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied")

    monkeypatch.setattr(tempfile, "mkdtemp", refused)  # as chmod a-w does (tests may run as root)
    assert toy.run("--set", "stages.scale.factor=4") == 4
    err = capsys.readouterr().err.strip().splitlines()
    folder = toy.root / "out" / ".cache" / "scale"
    assert "is damaged (it cannot be written: Permission denied); set aside as" in err[0]  # tried once
    assert err[-1] == (
        f"pipeline: error: stage 'scale': the cache folder {folder} cannot be written (Permission denied); "
        "make it writable or point `cache:` elsewhere, then run again: complete stages are reused."
    )


# --------------------------------------------------------------------------
# Publication (items 3, 5 and stale products)


def test_a_full_disk_while_publishing_keeps_every_old_product(toy, capsys, monkeypatch):
    assert toy.run() == 0
    out = toy.root / "out"
    old = {name: _sha(out / name) for name in ("total.json", "hist.json", "summary.json")}
    old_manifest = toy.manifest()
    (toy.root / "numbers.txt").write_text("5\n6\n7\n")  # every product changes
    # The disk fills up at the second product, whichever way it is copied.
    calls = {"n": 0}
    real_copyfileobj, real_copyfile = shutil.copyfileobj, shutil.copyfile

    def full_after_one(copy):
        def copy_or_fail(src, dst, *args, **kwargs):
            names = [x if isinstance(x, (str, os.PathLike)) else getattr(x, "name", "") for x in (src, dst)]
            if any(str(n).startswith(str(toy.root / "out" / ".cache")) for n in names):
                calls["n"] += 1
                if calls["n"] == 2:
                    raise OSError(errno.ENOSPC, "No space left on device")
            return copy(src, dst, *args, **kwargs)

        return copy_or_fail

    monkeypatch.setattr(shutil, "copyfileobj", full_after_one(real_copyfileobj))
    monkeypatch.setattr(shutil, "copyfile", full_after_one(real_copyfile))
    capsys.readouterr()
    assert toy.run() == 4
    err = capsys.readouterr().err
    assert err.strip() == (
        f"pipeline: error: the output folder {out} is full (No space left on device); "
        "free space or point `output:` elsewhere, then run again: complete stages are reused."
    )
    assert {name: _sha(out / name) for name in old} == old
    manifest = toy.manifest()
    assert manifest["status"] == "failed"
    assert manifest["products"] == old_manifest["products"]
    assert manifest["products_run"] == old_manifest["started"]
    assert not list(out.glob(".*.tmp"))


def test_another_run_publishing_in_between_never_makes_run_json_false(toy, monkeypatch):
    """Two configurations, one output folder: the other run publishes while this one shuts its workers down."""
    other = toy.root / "other.yaml"
    (toy.root / "other.txt").write_text("100\n200\n")
    other.write_text(toy.path.read_text().replace("numbers.txt", "other.txt"))
    real_close = executor_mod.LocalExecutor.close
    state = {"done": False}

    def close_while_another_publishes(self, *args, **kwargs):
        real_close(self, *args, **kwargs)
        if not state["done"]:
            state["done"] = True
            assert main(["run", str(other), "-q"]) == 0

    monkeypatch.setattr(executor_mod.LocalExecutor, "close", close_while_another_publishes)
    assert toy.run() == 0
    _folder_matches_manifest(toy.root / "out")
    assert toy.manifest()["status"] == "ok" and toy.manifest()["config"]["path"] == str(toy.path.resolve())


def test_stale_products_of_a_disabled_stage_are_removed_and_listed(toy):
    assert toy.run() == 0
    assert (toy.root / "out" / "total.json").exists()
    assert toy.run("--set", "stages.total.enabled=false") == 0
    assert not (toy.root / "out" / "total.json").exists()
    manifest = toy.manifest()
    assert manifest["removed_products"] == ["total.json"]
    assert set(manifest["products"]) == {"hist.json", "summary.json"}
    _folder_matches_manifest(toy.root / "out")


def test_a_failed_run_says_which_products_are_in_the_folder(toy):
    assert toy.run() == 0
    first = toy.manifest()
    assert toy.run("--set", "stages.scale.fail=true") == 1
    failed = toy.manifest()
    assert failed["status"] == "failed"
    assert failed["products"] == first["products"] and failed["products_run"] == first["started"]
    _folder_matches_manifest(toy.root / "out")


# --------------------------------------------------------------------------
# Inputs and planted links (items 8 and 9)


def test_an_input_under_a_product_name_is_refused(toy, capsys):
    out = toy.root / "out"
    out.mkdir()
    (out / "total.json").write_text("1\n2\n")
    toy.path.write_text(toy.path.read_text().replace("path: numbers.txt", "path: out/total.json"))
    assert toy.run() == 2
    err = capsys.readouterr().err.strip()
    assert err == (
        f"pipeline: error: the input {out / 'total.json'} is in the output folder under the product name "
        "'total.json', which a run replaces: move the input out of the output folder or choose another output."
    )
    assert (out / "total.json").read_text() == "1\n2\n"


def test_planted_links_are_never_followed(toy, tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    precious = outside / "precious.txt"
    precious.write_text("keep me")
    out = toy.root / "out"
    (out / ".cache" / "scale").mkdir(parents=True)
    (out / f".write-test-{os.getpid()}").symlink_to(precious)  # the probe's name in this process
    (out / ".cache" / f".write-test-{os.getpid()}").symlink_to(precious)
    (out / ".products.lock").symlink_to(outside / "made-by-lock")  # dangling
    assert toy.run() == 0
    # every stage's lock, planted as a dangling link before the next run
    for lock in (out / ".cache").rglob(".*.lock"):
        lock.unlink()
        lock.symlink_to(outside / f"made-by-{lock.parent.name}")
    assert toy.run("--force", "scale") == 0
    assert precious.read_text() == "keep me"
    assert sorted(p.name for p in outside.iterdir()) == ["precious.txt"]
    assert not (out / ".products.lock").is_symlink()


# --------------------------------------------------------------------------
# Values that size memory (item 10, the engine's part)


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ("tiling.size=1e-9", "tiling.size: Input should be greater than or equal to 10"),
        ("tiling.size=1e-3", "tiling.size: Input should be greater than or equal to 10"),
        ("tiling.size=.inf", "tiling.size: Input should be a finite number"),
        ("tiling.buffer=.inf", "tiling.buffer: Input should be a finite number"),
        ("tiling.buffer=1e9", "tiling.buffer: Input should be less than or equal to 10000"),
    ],
)
def test_tiling_values_that_size_memory_are_bounded_in_validation(toy, capsys, override, words):
    assert main(["validate", str(toy.path), "--set", override]) == 2
    err = capsys.readouterr().err
    assert f"--set {override}: {words}" in err and "Traceback" not in err


def test_a_layout_of_too_many_tiles_is_refused_before_cutting():
    # 50 km x 50 km in 100 m tiles: 251,001 tiles
    with pytest.raises(ConfigError) as exc:
        Layout.of((0.0, 0.0, 50_000.0, 50_000.0), 100.0, 10.0)
    assert str(exc.value) == (
        f"tiling.size: tiles of 100 m cut the extent of 50000 m x 50000 m into 251,001 tiles, more than "
        f"{MAX_TILES:,}; use tiles of at least 159 m."
    )
    assert len(Layout.of((0.0, 0.0, 50_000.0, 50_000.0), 159.0, 10.0)) <= MAX_TILES
    with pytest.raises(ConfigError, match="put every point in 225 tiles, more than 100; use tiles of at least 16"):
        Layout.of((0.0, 0.0, 1000.0, 1000.0), 10.0, 70.0)


def test_products_and_run_json_are_published_under_one_lock(toy, monkeypatch):
    """run.json says 'publishing' while products are renamed into place, then 'ok'."""
    seen = []
    real = runner._rename_into_place

    def rename_and_look(tmp, dst):
        seen.append(json.loads((toy.root / "out" / "run.json").read_text())["status"])
        real(tmp, dst)

    monkeypatch.setattr(runner, "_rename_into_place", rename_and_look)
    assert toy.run() == 0
    assert seen and set(seen) == {"publishing"}
    assert toy.manifest()["status"] == "ok"
    assert Cache(toy.root / "out" / ".cache").root.exists()


def test_failed_checks_are_warnings_and_exit_5_only_with_strict(toy, capsys):
    """The toy's histogram checks that no bin holds more than max_count values (4 values, 2 bins: a bin of 3
    fails it).  The run publishes its products either way; each failed check is a WARNING line; exit 5 only
    with --strict, also when the stage comes from the cache."""
    assert toy.run("--set", "stages.histogram.max_count=2") == 0
    err = capsys.readouterr().err
    assert "WARNING [histogram] check failed: bin 0 holds 3 values, more than 2" in err
    assert toy.manifest()["status"] == "ok" and toy.product("hist.json") == [3, 1]
    assert toy.run("--set", "stages.histogram.max_count=2", "--strict") == 5
    assert "1 check(s) failed: exit 5 (--strict)" in capsys.readouterr().err
    assert toy.statuses()["histogram"] == "cached"
    assert toy.run("--set", "stages.histogram.max_count=3", "--strict") == 0  # no bin holds more than 3


def test_a_stages_warnings_are_kept_with_its_metrics_cached_too(toy, capsys):
    """The engine keeps each stage's WARNING lines in its metrics (run.json; a report shows them): a cached
    stage's warnings are those of its run."""
    assert toy.run("--set", "stages.histogram.bins=10") == 0
    assert "WARNING [histogram] more bins (10) than values (4)" in capsys.readouterr().err

    def warned() -> dict:
        return {s["name"]: (s.get("metrics") or {}).get("log_warnings") for s in toy.manifest()["stages"]}

    assert warned()["histogram"] == ["more bins (10) than values (4)"] and warned()["scale"] is None
    assert toy.run("--set", "stages.histogram.bins=10") == 0
    assert toy.statuses()["histogram"] == "cached"
    assert warned()["histogram"] == ["more bins (10) than values (4)"]
    # and the console says them again: what a cached result warned of when it was made still holds
    assert "WARNING [histogram] more bins (10) than values (4) (cached result)" in capsys.readouterr().err


def test_run_log_keeps_every_info_line_beside_the_products_under_q(toy, capsys):
    """``run.log``: the run's lines of INFO and above, dated, whatever -q keeps off the console; a failed run
    leaves its own, and a run without a log line of INFO does not exist."""
    assert toy.run("--set", "stages.histogram.bins=10") == 0
    err = capsys.readouterr().err
    assert "INFO" not in err  # -q
    log = (toy.root / "out" / "run.log").read_text().splitlines()
    assert any(" INFO    [scale] running (stage " in line for line in log)
    assert any(line.endswith("WARNING [histogram] more bins (10) than values (4)") for line in log)
    assert log[-1].split(" INFO    ")[1].startswith("run ok in ")
    stamp = log[0].split(" INFO")[0]
    assert len(stamp) == len("2026-12-07 18:29:05+0000") and stamp[4] == "-" and stamp[10] == " "
    assert "run.log" not in toy.manifest()["products"]  # not a product: never removed as a stale one
    (toy.root / "numbers.txt").write_text("1\nx\n")
    assert toy.run() != 0
    log = (toy.root / "out" / "run.log").read_text()
    assert "run failed" in log and "more bins" not in log  # the failed run's own log, whole


def test_each_stage_line_says_where_the_run_is(toy, capsys, monkeypatch):
    """Stage k of n on each stage's first line: '[load] running (stage 1 of 5)' ... and on a cache hit."""
    assert main(["run", str(toy.path)]) == 0
    err = capsys.readouterr().err
    names = [s["name"] for s in toy.manifest()["stages"]]
    for k, name in enumerate(names, start=1):
        assert f"[{name}] running (stage {k} of {len(names)})" in err
    assert main(["run", str(toy.path)]) == 0
    assert f"; stage 2 of {len(names)})" in capsys.readouterr().err
