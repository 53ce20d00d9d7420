"""The engine's tile cache: a tile whose input did not change is not run again (plain files, no LiDAR)."""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pytest

from pipeline.cache import TileCache
from pipeline.executor import LocalExecutor
from pipeline.tiling import TileMemo, run_tiled


@dataclass(frozen=True)
class SumTask:
    """Sum the numbers of one file into another; ``weight`` for the executor's order."""

    source: str
    result: str
    weight: int = 1


def add_up(task: SumTask) -> dict:
    total = sum(int(v) for v in Path(task.source).read_text().split())
    Path(task.result).write_text(str(total))
    with open(Path(task.source).parent / "calls", "a") as fh:  # the test counts the tasks that ran
        fh.write(Path(task.source).name + "\n")
    return {"total": total}


def _digest(path: str) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


MEMO = TileMemo(
    key=lambda t: {"source": _digest(t.source)},
    save=lambda t, result, folder: (Path(folder, "sum").write_bytes(Path(t.result).read_bytes()), result)[1],
    load=lambda t, folder, kept: (Path(t.result).write_bytes(Path(folder, "sum").read_bytes()), kept)[1],
)


def _run(tmp: Path, values: list[str], reuse: bool = True) -> tuple[list, list[str], dict]:
    """Run one task per value through run_tiled with the memo; the results, the tasks that ran, the tiling metrics."""
    work = tmp / "work"
    work.mkdir(exist_ok=True)
    (work / "calls").unlink(missing_ok=True)
    tasks = []
    for i, v in enumerate(values):
        (work / f"in{i}").write_text(v)
        tasks.append(SumTask(str(work / f"in{i}"), str(work / f"out{i}")))
    ctx = SimpleNamespace(
        config=SimpleNamespace(tiling=None, executor=None),
        executor=LocalExecutor(1),
        metrics={},
        log=logging.LoggerAdapter(logging.getLogger("test"), {}),
        workers=1,
        tile_cache=TileCache(tmp / "cache", "sum", {"stage": "sum", "version": "1"}, reuse=reuse),
    )

    def merge(layout, tasks, results):
        return [(r["total"], int(Path(t.result).read_text())) for t, r in zip(tasks, results, strict=True)]

    out = run_tiled(
        ctx, extent=(0, 0, 1, 1), buffer=0.0, split=lambda layout: tasks, task=add_up, merge=merge, memo=MEMO
    )
    calls = (work / "calls").read_text().split() if (work / "calls").exists() else []
    return out, calls, ctx.metrics["tiling"]


def test_only_the_tiles_whose_input_changed_run_again(tmp_path):
    out, calls, tiling = _run(tmp_path, ["1 2", "3 4", "5 6"])
    assert out == [(3, 3), (7, 7), (11, 11)] and calls == ["in0", "in1", "in2"]
    assert (tiling["reused"], tiling["ran"]) == (0, 3)
    out, calls, tiling = _run(tmp_path, ["1 2", "3 40", "5 6"])
    assert out == [(3, 3), (43, 43), (11, 11)], "the kept tiles' results and files are restored"
    assert calls == ["in1"] and (tiling["reused"], tiling["ran"]) == (2, 1)
    # the same content at another position is the same tile
    out, calls, _ = _run(tmp_path, ["5 6", "1 2"])
    assert out == [(11, 11), (3, 3)] and calls == []


def test_force_runs_every_tile_again(tmp_path):
    _run(tmp_path, ["1", "2"])
    _, calls, tiling = _run(tmp_path, ["1", "2"], reuse=False)
    assert calls == ["in0", "in1"] and tiling["reused"] == 0


def test_a_damaged_tile_is_run_again_and_replaced(tmp_path, caplog):
    _run(tmp_path, ["1 2", "3 4"])
    kept = sorted((tmp_path / "cache" / "tiles" / "sum").glob("*/*/sum"))
    assert len(kept) == 2
    for path in kept:
        path.write_text("999")  # not what tile.json's checksum says
    with caplog.at_level(logging.WARNING):
        out, calls, _ = _run(tmp_path, ["1 2", "3 4"])
    assert out == [(3, 3), (7, 7)] and calls == ["in0", "in1"]
    assert "damaged" in caplog.text
    _, calls, _ = _run(tmp_path, ["1 2", "3 4"])
    assert calls == [], "the damaged entries were replaced by good ones"


def test_a_link_in_the_tile_cache_is_never_followed(tmp_path, caplog):
    outside = tmp_path / "outside"
    outside.mkdir()
    (tmp_path / "cache").mkdir()
    (tmp_path / "cache" / "tiles").mkdir()
    os.symlink(outside, tmp_path / "cache" / "tiles" / "sum")
    with caplog.at_level(logging.WARNING):
        out, calls, _ = _run(tmp_path, ["1", "2"])
        out2, calls2, _ = _run(tmp_path, ["1", "2"])
    assert out == out2 == [(1, 1), (2, 2)] and calls == calls2 == ["in0", "in1"]
    assert list(outside.iterdir()) == [], "nothing written through the link"
    assert "not a folder" in caplog.text


@pytest.mark.parametrize("base", [{"stage": "sum", "version": "2"}, {"stage": "sum", "version": "1", "p": 1}])
def test_other_settings_are_other_tiles(tmp_path, base):
    _run(tmp_path, ["1"])
    cache = TileCache(tmp_path / "cache", "sum", base)
    key = cache.key({"source": _digest(str(tmp_path / "work" / "in0"))})
    assert cache.get(key) is None
    same = TileCache(tmp_path / "cache", "sum", {"stage": "sum", "version": "1"})
    assert same.get(same.key({"source": _digest(str(tmp_path / "work" / "in0"))})) is not None


def test_what_a_killed_run_left_while_keeping_a_tile_is_removed(tmp_path):
    cache = TileCache(tmp_path / "cache", "sum", {"stage": "sum"})
    key = cache.key({"source": "x"})
    shard = tmp_path / "cache" / "tiles" / "sum" / key[:2]
    shard.mkdir(parents=True)
    dead = shard / ".tmp-999999999-abc"  # no such process
    dead.mkdir()
    (dead / "sum").write_text("half")
    alive = shard / f".tmp-{os.getpid()}-xyz"  # a run keeping a tile right now
    alive.mkdir()
    cache.put(key, lambda folder: (Path(folder, "sum").write_text("3"), {"total": 3})[1])
    assert not dead.exists() and alive.exists()
    folder, kept = cache.get(key)
    assert kept == {"total": 3} and Path(folder, "sum").read_text() == "3"


def test_a_tile_kept_meanwhile_by_another_run_is_left_as_it_is(tmp_path, caplog):
    cache = TileCache(tmp_path / "cache", "sum", {"stage": "sum"})
    key = cache.key({"source": "y"})

    def fill(folder):  # another run keeps the same tile while this one writes it
        other = TileCache(tmp_path / "cache", "sum", {"stage": "sum"})
        other.put(key, lambda f: (Path(f, "sum").write_text("5"), {"total": 5})[1])
        Path(folder, "sum").write_text("5")
        return {"total": 5}

    with caplog.at_level(logging.WARNING):
        cache.put(key, fill)
    assert caplog.text == "", "no warning: the tile is kept"
    assert cache.get(key)[1] == {"total": 5}
    assert not [p for p in (tmp_path / "cache" / "tiles" / "sum").rglob(".tmp-*")]
