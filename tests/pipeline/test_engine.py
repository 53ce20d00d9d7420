"""The engine with toy stages: planning, caching, re-runs, manifest, atomicity."""

from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import logging
import os
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from pipeline.cache import Cache, hash_value
from pipeline.cli import main
from pipeline.config import load_config
from pipeline.errors import PlanError
from pipeline.runner import build_plan
from pipeline.stage import StageContext, config_model
from tests.pipeline import toy as toymod


def test_first_run_computes_products(toy):
    assert toy.run() == 0
    assert toy.product("total.json") == {"total": 48.0}  # 3 * (1 + 2 + 3 + 10)
    assert toy.product("hist.json") == [3, 1]
    assert set(toy.statuses().values()) == {"ran"}


def test_second_run_is_all_cache_hits(toy):
    assert toy.run() == 0
    first = toy.manifest()
    assert toy.run() == 0
    second = toy.manifest()
    assert set(toy.statuses().values()) == {"cached"}
    assert first["products"] == second["products"]
    # Metrics are kept with the cache entry.
    load = next(s for s in second["stages"] if s["name"] == "load")
    assert load["metrics"] == {"count": 4}


def test_changing_one_parameter_reruns_only_that_stage_and_dependants(toy):
    assert toy.run() == 0
    assert toy.run("--set", "stages.histogram.bins=3") == 0
    assert toy.statuses() == {
        "load": "cached",
        "scale": "cached",
        "total": "cached",
        "histogram": "ran",
        "summary": "ran",
    }
    assert toy.product("hist.json") == [3, 0, 1]
    assert toy.run("--set", "stages.scale.factor=1") == 0
    # the histogram of [1, 2, 3, 10] has the same counts at any scale: summary stays cached
    assert toy.statuses() == {"load": "cached", "scale": "ran", "total": "ran", "histogram": "ran", "summary": "cached"}
    assert toy.product("total.json") == {"total": 16.0}


def test_identical_upstream_output_keeps_downstream_cached(toy):
    assert toy.run() == 0
    # Same numbers, different bytes: load re-runs, its output is identical.
    (toy.root / "numbers.txt").write_text("1\n2\n3\n10 # ten\n")
    assert toy.run() == 0
    assert toy.statuses() == {
        "load": "ran",
        "scale": "cached",
        "total": "cached",
        "histogram": "cached",
        "summary": "cached",
    }


def test_input_file_content_is_part_of_the_key(toy):
    assert toy.run() == 0
    (toy.root / "numbers.txt").write_text("5\n")
    assert toy.run() == 0
    assert toy.product("total.json") == {"total": 15.0}


def test_disabled_stage_passes_its_input_on(toy):
    assert toy.run("--set", "stages.scale.enabled=false") == 0
    assert toy.product("total.json") == {"total": 16.0}
    assert toy.statuses()["scale"] == "disabled"


def test_disabling_a_needed_producer_is_a_plan_error(toy, capsys):
    config = load_config(toy.path, config_model(toymod.plugin), ["stages.total.enabled=false"])
    assert [s.name for s in build_plan(config, toymod.plugin).steps] == ["load", "scale", "histogram", "summary"]

    class NoPass(toymod.Scale):
        passthrough = {}

    plugin = toymod.Plugin("toy", [toymod.Load, NoPass, toymod.Total, toymod.Histogram], toymod.plugin.global_fields)
    config = load_config(toy.path, config_model(plugin), ["stages.scale.enabled=false"])
    with pytest.raises(PlanError, match="stage 'total' needs 'scaled', which no enabled stage produces"):
        build_plan(config, plugin)


def test_until_runs_only_the_stage_and_what_it_needs(toy):
    assert toy.run("--until", "scale") == 0
    assert toy.statuses() == {
        "load": "ran",
        "scale": "ran",
        "total": "after --until scale",
        "histogram": "after --until scale",
        "summary": "after --until scale",
    }
    assert not (toy.root / "out" / "total.json").exists()


def test_force_reruns_a_cached_stage(toy):
    assert toy.run() == 0
    assert toy.run("--force", "total") == 0
    assert toy.statuses() == {
        "load": "cached",
        "scale": "cached",
        "total": "ran",
        "histogram": "cached",
        "summary": "cached",
    }


def test_force_replaces_the_cached_entry(toy):
    """--force computes the stage again and keeps the new entry (not the old one as from a concurrent run)."""
    assert toy.run() == 0
    record = next(s for s in toy.manifest()["stages"] if s["name"] == "total")
    entry = Path(next(iter(record["outputs"].values()))["file"]).parent / "entry.json"
    before = json.loads(entry.read_text())
    time.sleep(1.1)  # entry.json's creation time has whole seconds
    assert toy.run("--force", "total") == 0
    after = json.loads(entry.read_text())
    assert after["created"] != before["created"]


def test_unknown_stage_names_exit_2(toy, capsys):
    assert toy.run("--until", "nope") == 2
    assert "unknown stage 'nope'" in capsys.readouterr().err
    assert toy.run("--force", "nope") == 2


def test_dry_run_reports_hits_and_runs_nothing(toy, capsys):
    assert main(["run", str(toy.path), "--dry-run", "-q"]) == 0
    out = capsys.readouterr().out
    assert "load" in out and "run (upstream)" in out
    assert not (toy.root / "out" / "run.json").exists()
    assert toy.run() == 0
    capsys.readouterr()
    assert main(["run", str(toy.path), "--dry-run", "-q", "--set", "stages.histogram.bins=5"]) == 0
    lines = {line.split()[0]: line.split()[1] for line in capsys.readouterr().out.splitlines()[1:]}
    assert lines == {
        "load": "cached",
        "scale": "cached",
        "total": "cached",
        "histogram": "run",
        "summary": "run",
    }
    capsys.readouterr()
    assert main(["run", str(toy.path), "--dry-run", "-q"]) == 0
    assert "run" not in capsys.readouterr().out.split("key", 1)[1].split()  # all cached, summary included


def test_failing_stage_leaves_no_cache_entry_and_a_failed_manifest(toy, capsys):
    assert toy.run("--set", "stages.scale.fail=true") == 1
    err = capsys.readouterr().err
    assert "internal error: RuntimeError: boom" in err and "Traceback" not in err
    manifest = toy.manifest()
    assert manifest["status"] == "failed"
    cache = toy.root / "out" / ".cache" / "scale"
    # no entry, no leftover workspace (only the entry's lock file, kept on purpose)
    assert not [p for p in cache.iterdir() if p.suffix != ".lock"]
    assert not (toy.root / "out" / "total.json").exists()


def test_bad_input_data_exits_3(toy, capsys):
    (toy.root / "numbers.txt").write_text("1\nseven\n")
    assert toy.run() == 3
    assert "numbers.txt, line 2: 'seven' is not a number." in capsys.readouterr().err


def test_manifest_records_versions_hashes_and_timings(toy):
    assert toy.run() == 0
    m = toy.manifest()
    assert m["status"] == "ok" and m["version"]
    assert len(m["config"]["sha256"]) == 64
    assert str(toy.root / "numbers.txt") in m["inputs"]
    for stage in m["stages"]:
        assert stage["seconds"] >= 0 and len(stage["key"]) == 64

    data = (toy.root / "out" / "total.json").read_bytes()
    assert m["products"]["total.json"]["sha256"] == hashlib.sha256(data).hexdigest()


def test_cache_key_covers_defaults_and_version(toy):
    """An explicit default gives the same key; a new stage version does not."""
    assert toy.run() == 0
    key = {s["name"]: s["key"] for s in toy.manifest()["stages"]}
    assert toy.run("--set", "stages.scale.factor=3.0", "--set", "stages.total.enabled=true") == 0
    assert {s["name"]: s["key"] for s in toy.manifest()["stages"]} == key
    old = toymod.Total.version
    try:
        toymod.Total.version = "2"
        assert toy.run() == 0
        assert toy.statuses()["total"] == "ran"
    finally:
        toymod.Total.version = old


def test_incomplete_cache_entry_is_not_trusted(toy):
    assert toy.run() == 0
    m = toy.manifest()
    total = next(s for s in m["stages"] if s["name"] == "total")
    path = total["outputs"]["total"]["file"]
    with open(path, "a") as fh:
        fh.write("   ")  # size no longer matches entry.json
    assert toy.run() == 0
    assert toy.statuses()["total"] == "ran"
    assert toy.product("total.json") == {"total": 48.0}


def test_cache_commit_is_atomic_and_keeps_existing_entries(tmp_path):
    cache = Cache(tmp_path)
    ws = cache.new_workspace("s")
    (ws / "a.txt").write_text("x")
    entry = cache.commit("s", "k", ws, {"outputs": {"a": "a.txt"}})
    assert json.loads((entry.folder / "entry.json").read_text())["outputs"]["a"]["bytes"] == 1
    ws2 = cache.new_workspace("s")
    (ws2 / "a.txt").write_text("x")
    again = cache.commit("s", "k", ws2, {"outputs": {"a": "a.txt"}})
    assert again.folder == entry.folder and not ws2.exists()
    assert hash_value({"b": 1, "a": [1, 2]}) == hash_value({"a": [1, 2], "b": 1})


def test_an_output_that_is_its_input_takes_the_input_checksum_and_a_copy_is_read(tmp_path):
    """An output hard-linked to an input file is that file: its known SHA-256 is taken, not read again (the
    digest given here is not the file's, so a read would show); an output with the same bytes in a file of
    its own is read."""
    cache = Cache(tmp_path / "cache")
    given = tmp_path / "given.bin"
    given.write_bytes(b"points")
    told = "0" * 64
    ws = cache.new_workspace("s")
    os.link(given, ws / "linked.bin")
    (ws / "copied.bin").write_bytes(b"points")
    entry = cache.commit("s", "k", ws, {"outputs": {"a": "linked.bin", "b": "copied.bin"}}, known={given: told})
    outputs = json.loads((entry.folder / "entry.json").read_text())["outputs"]
    assert outputs["a"]["sha256"] == told
    assert outputs["b"]["sha256"] == hashlib.sha256(b"points").hexdigest()


def test_json_log_lines(toy, capsys):
    assert main(["run", str(toy.path), "--log-format", "json"]) == 0
    lines = [json.loads(line) for line in capsys.readouterr().err.splitlines()]
    assert any(line.get("stage") == "scale" and line["level"] == "info" for line in lines)


def test_schema_and_version(toy, capsys):
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert "source" in schema["properties"] and "stages" in schema["properties"]
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert "pipeline" in capsys.readouterr().out


def test_bad_usage_exits_2(toy, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["run"])
    assert exc.value.code == 2


def test_stage_reading_metrics_reruns_when_they_change(toy):
    assert toy.run() == 0
    assert toy.product("summary.json") == {"count": 4}
    assert toy.run() == 0
    assert toy.statuses()["summary"] == "cached"
    # Same scaled values (so same histogram bytes), but load's metrics change.
    (toy.root / "numbers.txt").write_text("1\n2\n3\n10\n# now with a comment line\n")
    assert toy.run() == 0
    assert toy.statuses()["histogram"] == "cached"
    assert toy.statuses()["summary"] == "cached"  # count is still 4
    (toy.root / "numbers.txt").write_text("1\n2\n3\n10\n10\n")
    assert toy.run() == 0
    assert toy.product("summary.json") == {"count": 5}


def test_unwritable_output_folder_is_one_sentence_exit_2(toy, capsys):
    blocker = toy.root / "blocked"
    blocker.write_text("a file where the output folder should be")
    assert toy.run("--set", f"output={blocker / 'out'}") == 2
    err = capsys.readouterr().err
    assert "the output folder" in err and "is not writable" in err and "Traceback" not in err


def test_full_disk_is_reported_in_one_sentence(toy, capsys, monkeypatch):
    def full(self, ctx):
        raise OSError(errno.ENOSPC, "No space left on device", str(ctx.outputs["numbers"]))

    monkeypatch.setattr(toymod.Load, "run", full)
    assert toy.run() == 4
    cache = toy.root / "out" / ".cache"
    assert capsys.readouterr().err.strip() == (
        f"pipeline: error: stage 'load': the cache folder {cache} is full (No space left on device); "
        "free space or point `cache:` elsewhere, then run again: complete stages are reused."
    )
    # nothing half-written: no cache entry for the stage
    assert not list((toy.root / "out" / ".cache" / "load").glob("*/entry.json"))


def test_tampered_entry_json_is_recomputed(toy, capsys):
    assert toy.run() == 0
    entry = next((toy.root / "out" / ".cache" / "load").glob("*/entry.json"))
    entry.write_text(entry.read_text().replace('"count": 4', '"count": 5'))  # valid JSON, wrong content
    capsys.readouterr()
    assert toy.run() == 0
    assert toy.statuses()["load"] == "ran"
    assert "entry.json fails its checksum" in capsys.readouterr().err
    load = next(s for s in toy.manifest()["stages"] if s["name"] == "load")
    assert load["metrics"] == {"count": 4}


def test_workspace_of_a_killed_run_is_removed_but_a_live_one_is_kept(tmp_path):
    dead, live = tmp_path / "s" / ".tmp-k1-abc", tmp_path / "s" / ".tmp-k2-def"
    dead.mkdir(parents=True)
    live.mkdir()
    fd = os.open(tmp_path / "s" / ".k2.lock", os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)  # as a live run computing k2 would

        # Another process sweeps: it must see k2's lock as taken.
        code = f"from pipeline.cache import Cache; print(Cache({str(tmp_path)!r}).sweep('s', 'k3'))"
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    finally:
        os.close(fd)
    assert out.strip() == "1"
    assert not dead.exists() and live.exists()


def test_a_stage_reads_another_blocks_setting_only_when_declared():
    """ctx.setting: a declared key (or a key inside a declared block) is read; an undeclared one is a bug."""
    config = SimpleNamespace(crs="EPSG:25830", stages=SimpleNamespace(rasterize=SimpleNamespace(resolution=0.5)))
    log = logging.LoggerAdapter(logging.getLogger("t"), {})
    keys = ("crs", "stages.rasterize")
    ctx = StageContext("report", None, config, {}, {}, Path("."), 1, log, config_keys=keys)
    assert ctx.setting("crs") == "EPSG:25830"
    assert ctx.setting("stages.rasterize.resolution") == 0.5
    with pytest.raises(KeyError, match="reads 'stages.denoise' without declaring it"):
        ctx.setting("stages.denoise")
    with pytest.raises(KeyError):
        ctx.setting("crs_other")  # a prefix of a name is not the declared key
