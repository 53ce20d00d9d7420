"""The engine's tiles and executors, on plain numbers (no LiDAR)."""

from __future__ import annotations

import logging
import os
from types import SimpleNamespace

import numpy as np
import pytest
from distributed import LocalCluster

from pipeline.config import ExecutorConfig
from pipeline.errors import EnvironmentFailure, InputDataError
from pipeline.executor import DaskExecutor, LocalExecutor
from pipeline.tiling import Layout, run_tiled


def _brute(layout: Layout, x, y):
    """Every (point, tile) pair with the point in the tile's core plus buffer, and each point's core tile."""
    pairs, home = [], np.full(len(x), -1)
    b = layout.buffer
    for t in layout.tiles:
        inside = (x >= t.xmin - b) & (x < t.xmax + b) & (y >= t.ymin - b) & (y < t.ymax + b)
        pairs += [(int(i), t.index) for i in np.flatnonzero(inside)]
        core = (x >= t.xmin) & (x < t.xmax) & (y >= t.ymin) & (y < t.ymax)
        assert (home[core] == -1).all(), "a point in two cores"
        home[core] = t.index
    return sorted(pairs), home


@pytest.mark.parametrize("size, buffer", [(100.0, 15.0), (40.0, 55.0), (250.0, 0.0), (150.0, 30.0)])
def test_layout_memberships_match_brute_force(size, buffer):
    rng = np.random.default_rng(3)
    x = rng.uniform(-130.0, 370.0, 4000)
    y = rng.uniform(1000.0, 1260.0, 4000)
    # points exactly on tile edges and buffer edges
    x[:50] = np.round(x[:50] / size) * size
    y[50:100] = np.round(y[50:100] / size) * size + buffer
    layout = Layout.of((x.min(), y.min(), x.max(), y.max()), size, buffer)
    point, tile = layout.memberships(x, y)
    expected, home = _brute(layout, x, y)
    assert sorted(zip(point.tolist(), tile.tolist(), strict=True)) == expected
    assert (np.diff(tile) >= 0).all(), "pairs sorted by tile"
    located = layout.locate(x, y)
    assert (located == home).all() and (home >= 0).all(), "every point in exactly one core"
    # tiles are aligned on whole multiples of the size
    assert all(t.xmin % size == 0 and t.ymin % size == 0 for t in layout.tiles)


def test_single_tile_layout_holds_everything():
    layout = Layout.of((0.0, 0.0, 10.0, 10.0), None, 5.0)
    assert len(layout) == 1
    x = np.array([0.0, 10.0, 5.0])
    assert (layout.locate(x, x) == 0).all()
    point, tile = layout.memberships(x, x)
    assert point.tolist() == [0, 1, 2] and tile.tolist() == [0, 0, 0]


def square(task: dict) -> dict:
    return {"i": task["i"], "sq": task["i"] ** 2}


def fail_on_three(task: dict) -> int:
    if task["i"] == 3:
        raise InputDataError(f"task {task['i']}: bad input")
    return task["i"]


def test_local_executor_runs_in_processes_and_keeps_order():
    ex = LocalExecutor(2)
    try:
        tasks = [{"i": i} for i in range(9)]
        assert ex.map(square, tasks) == [{"i": i, "sq": i * i} for i in range(9)]
        with pytest.raises(InputDataError, match="task 3: bad input"):
            ex.map(fail_on_three, tasks)
    finally:
        ex.close()


def test_dask_local_cluster_matches_local_executor():
    ex = DaskExecutor(None, 2)
    try:
        tasks = [{"i": i} for i in range(7)]
        assert ex.map(square, tasks) == LocalExecutor(1).map(square, tasks)
        with pytest.raises(InputDataError, match="task 3"):
            ex.map(fail_on_three, tasks)
    finally:
        ex.close()


def test_dask_executor_uses_the_scheduler_at_its_address():
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        ex = DaskExecutor(cluster.scheduler_address, 1)
        try:
            assert ex.describe() == f"dask {cluster.scheduler_address}"
            assert ex.map(square, [{"i": i} for i in range(5)]) == [{"i": i, "sq": i * i} for i in range(5)]
            workers = ex._client.scheduler_info()["workers"]
            assert len(workers) == 2
        finally:
            ex.close()


def test_unreachable_scheduler_is_one_sentence():
    ex = DaskExecutor("tcp://127.0.0.1:9", 1, connect_timeout=1)  # the discard port: nothing listens
    with pytest.raises(EnvironmentFailure, match=r"tcp://127.0.0.1:9: no Dask scheduler answered within 1 s"):
        ex.map(square, [{"i": 1}])
    ex.close()


def where(task: dict) -> tuple[int, int]:
    """The task's number and the process that ran it."""
    return task["i"], os.getpid()


@pytest.mark.parametrize("weight, here", [(99_999, True), (100_000, False), (None, False)])
def test_light_work_runs_in_this_process_and_gives_the_same_results(weight, here):
    """Below ``executor.in_process_below`` (100,000 by default) the tiles run here, no worker started."""
    ex = LocalExecutor(2)
    config = SimpleNamespace(executor=ExecutorConfig(workers=2), tiling=None)
    ctx = SimpleNamespace(config=config, executor=ex, metrics={}, log=logging.getLogger("test"))
    try:
        out = run_tiled(
            ctx,
            extent=(0.0, 0.0, 10.0, 10.0),
            buffer=0.0,
            split=lambda layout: [{"i": i} for i in range(6)],
            task=where,
            merge=lambda layout, tasks, results: results,
            weight=weight,
        )
        assert [i for i, _ in out] == list(range(6))
        pids = {pid for _, pid in out}
        assert (pids == {os.getpid()}) is here
        assert (ex._pool is None) is here
        assert ctx.executor is ex  # given back
        assert ctx.metrics["tiling"]["executor"].startswith("this process") is here
    finally:
        ex.close()
