"""The executor when the machine fails the run (issue 38).

A "scheduler" that accepts and never answers was waited on for ever; a
killed worker was ``internal error: BrokenProcessPool ... please report it``;
a Ctrl-C reaching a worker while it started printed a traceback; and
``executor.workers: 16`` on 2 cores started 16 workers.
"""

from __future__ import annotations

import ast
import json
import logging
import math
import os
import random
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

import pipeline.executor as executor_module
from pipeline.cli import main
from pipeline.errors import ConfigError, EnvironmentFailure
from pipeline.executor import DaskExecutor, LocalExecutor, make_executor

ROOT = Path(__file__).resolve().parents[2]


def square(task: dict) -> int:
    return task["i"] ** 2


def sigint_blocked(seconds: float) -> tuple[int, bool]:
    """In a worker: its pid and whether SIGINT is blocked in its mask (inherited from the run)."""
    time.sleep(seconds)
    return os.getpid(), signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, [])


# --------------------------------------------------------------------------
# a scheduler that does not answer


@pytest.fixture
def silent_listener():
    """A TCP port that accepts connections and never sends a byte."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(8)
    yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    server.close()


def test_a_listener_that_never_answers_is_no_scheduler(silent_listener):
    ex = DaskExecutor(silent_listener, 1, connect_timeout=1)
    t0 = time.monotonic()
    with pytest.raises(EnvironmentFailure) as caught:
        ex.map(square, [{"i": 1}])
    assert time.monotonic() - t0 < 20  # was: for ever
    assert str(caught.value) == (
        f"executor.address {silent_listener}: no Dask scheduler answered within 1 s; "
        "start it (`dask scheduler`) or correct the address."
    )
    assert caught.value.exit_code == 4
    ex.close()


def test_a_closed_port_is_the_same_sentence():
    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    ex = DaskExecutor(f"tcp://127.0.0.1:{port}", 1, connect_timeout=0.5)
    t0 = time.monotonic()
    with pytest.raises(EnvironmentFailure, match=r"no Dask scheduler answered within 0.5 s; start it"):
        ex.map(square, [{"i": 1}])
    assert time.monotonic() - t0 < 20
    ex.close()


def test_an_address_dask_cannot_read_is_a_configuration_error():
    for address, words in [("foo://host:1", "unknown address scheme 'foo'"), ("host", "missing port number")]:
        with pytest.raises(ConfigError, match=f"executor.address {address}: not a Dask address .*{words}"):
            DaskExecutor(address, 1, connect_timeout=1).map(square, [{"i": 1}])


def test_the_connect_timeout_is_a_config_key(toy, capsys):
    code = main(["validate", str(toy.path), "--set", "executor.connect_timeout_s=0"])
    assert code == 2 and "executor.connect_timeout_s" in capsys.readouterr().err
    assert main(["validate", str(toy.path), "--set", "executor.connect_timeout_s=2.5"]) == 0


# --------------------------------------------------------------------------
# a worker killed


@pytest.fixture
def parallel(toy, monkeypatch):
    monkeypatch.setenv("PIPELINE_PLUGIN", "tests.pipeline.toy:parallel_plugin")
    monkeypatch.setattr(executor_module, "usable_cores", lambda: 2, raising=False)  # two workers, any machine
    toy.path.write_text("name: par\nsource: {path: numbers.txt}\noutput: out\nexecutor: {kind: local, workers: 2}\n")
    return toy


def test_a_killed_worker_is_one_sentence_and_exit_4(parallel, capsys):
    code = parallel.run("--set", "stages.spread.die=true")
    err = capsys.readouterr().err
    assert code == 4, err
    assert err == (
        "pipeline: error: stage 'spread': a worker process died (killed by signal 9, SIGKILL — often the "
        "system's out-of-memory killer); run again to resume: complete stages are reused.\n"
    )
    manifest = parallel.manifest()
    assert manifest["status"] == "failed" and "SIGKILL" in manifest["error"]
    assert not (parallel.root / "out" / "squares.json").exists()  # nothing half-written
    cache = parallel.root / "out" / ".cache" / "spread"
    assert not cache.exists() or not any(p.name.startswith(".tmp") for p in cache.iterdir())
    assert parallel.run() == 0  # resumes: load is reused
    assert parallel.statuses() == {"load": "cached", "spread": "ran"}
    assert json.loads((parallel.root / "out" / "squares.json").read_text()) == [1.0, 4.0, 9.0, 100.0]


# --------------------------------------------------------------------------
# Ctrl-C while the workers start

_CHILD = """
import sys, time
from pipeline.executor import LocalExecutor
from pipeline.interrupt import Interrupted, handling

ex = LocalExecutor(2)
try:
    with handling():
        print(ex.map(__import__("tests.pipeline.test_executor_faults", fromlist=["x"]).sigint_blocked, [0.4] * 4))
except Interrupted:
    sys.exit(130)
finally:
    ex.close(abort=True)
"""


def _child(**kwargs) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-c", _CHILD], env=env, cwd=ROOT, text=True, start_new_session=True, **kwargs
    )


def test_every_worker_starts_with_sigint_held():
    """The first pool of a process too: starting multiprocessing's resource tracker opened SIGINT again."""
    child = _child(stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out, err = child.communicate(timeout=60)
    assert child.returncode == 0, err
    blocked = dict(ast.literal_eval(out))  # [(pid, blocked), ...] printed by the child
    assert len(blocked) == 2 and all(blocked.values())


def test_a_ctrl_c_of_the_group_while_workers_start_prints_no_traceback():
    rng = random.Random(38)
    for _ in range(4):
        child = _child(stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        time.sleep(0.2 + 0.4 * rng.random())  # the workers' interpreters are starting
        try:
            os.killpg(child.pid, signal.SIGINT)
        except ProcessLookupError:
            pass
        err = child.communicate(timeout=60)[1]
        assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
        assert child.returncode in (0, 130)


# --------------------------------------------------------------------------
# no more workers than cores, nor than tasks


def test_no_more_worker_processes_than_usable_cores(monkeypatch):
    monkeypatch.setattr(executor_module, "usable_cores", lambda: 2)
    ex = LocalExecutor(16)
    try:
        assert ex.workers == 2 and ex.describe() == "local, 2 workers"
        ex.prepare(square)
        assert ex.map(square, [{"i": i} for i in range(20)]) == [i * i for i in range(20)]
        assert len(ex._pool._processes) == 2
    finally:
        ex.close()


def test_no_more_worker_processes_than_tasks(monkeypatch):
    monkeypatch.setattr(executor_module, "usable_cores", lambda: 8)
    ex = LocalExecutor(8)
    try:
        ex.prepare(square, 1)  # one task: nothing to start
        assert ex._pool is None
        assert ex.map(square, [{"i": 2}, {"i": 3}]) == [4, 9]
        assert len(ex._pool._processes) == 2
    finally:
        ex.close()


def test_the_lowered_number_is_said_once(monkeypatch, caplog):
    monkeypatch.setattr(executor_module, "usable_cores", lambda: 2)

    class Config:
        class executor:  # noqa: N801 - stands for the configuration's block
            kind, workers, address = "local", 16, None

    with caplog.at_level(logging.INFO, logger="pipeline"):
        ex = make_executor(Config)
    assert ex.workers == 2
    assert [r.getMessage() for r in caplog.records] == ["executor.workers: 16 asked, 2 cores usable: using 2"]
    with caplog.at_level(logging.INFO, logger="pipeline"):
        Config.executor.workers = 2
        make_executor(Config)
    assert len(caplog.records) == 1  # nothing to say when the number fits


# --------------------------------------------------------------------------
# Dask workers lost (issue 53): the watch, on a fake clock and a fake cluster


class Clock:
    """``time.monotonic`` and ``time.sleep`` of a test: sleeping moves the time on, at once."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


class Pending:
    """A ``distributed.as_completed`` of futures named by their keys, each done at its time on *clock*."""

    def __init__(self, clock: Clock, done_at: dict[str, float]):
        self.clock, self.done_at = clock, dict(done_at)

    def is_empty(self) -> bool:
        return not self.done_at

    def count(self) -> int:
        return len(self.done_at)

    def next_batch(self, block: bool = True) -> list[str]:
        assert not block  # the watch must never wait inside distributed: it would not see the time pass
        assert self.clock() < 3600, "waited for an hour of the test's clock: for ever"
        ready = sorted(k for k, t in self.done_at.items() if t <= self.clock())
        for k in ready:
            del self.done_at[k]
        return ready


def _watch(clock: Clock, workers: Callable[[float], int], timeout: float = 5.0) -> executor_module._WorkerWatch:
    return executor_module._WorkerWatch(
        lambda: workers(clock()),
        timeout,
        "executor.address tcp://10.0.0.1:8786",
        "tcp://10.0.0.1:8786",
        clock=clock,
        sleep=clock.sleep,
    )


def _removed(worker: str, processing=(), computed=(), expected=False) -> tuple[float, dict]:
    message = {"action": "remove-worker", "processing-tasks": set(processing), "lost-computed-tasks": set(computed)}
    return 0.0, {**message, "expected": expected, "worker": worker}


def test_a_cluster_without_workers_for_the_timeout_stops_the_wait():
    clock = Clock()
    watch = _watch(clock, lambda t: 0)  # no worker at all, from the start
    pending = Pending(clock, dict.fromkeys("abc", math.inf))
    done = []
    with pytest.raises(EnvironmentFailure) as caught:
        done.extend(watch.completed(pending, ["a", "b", "c"]))
    assert done == []  # no worker: nothing completes
    assert 5.0 <= clock.now <= 5.0 + watch.every + 0.2
    assert caught.value.exit_code == 4
    assert str(caught.value) == (
        "executor.address tcp://10.0.0.1:8786: no Dask worker for 5 s (executor.no_workers_timeout_s) with 3 of "
        "the 3 tasks still to run; start workers (`dask worker tcp://10.0.0.1:8786`), then run again to resume: "
        "complete stages are reused."
    )


def test_workers_back_within_the_timeout_start_the_clock_again():
    clock = Clock()
    # none in 2-6 s and 8-12 s: never 5 s in a row; not known in 14-18 s (the scheduler being lost); none from 20 s
    watch = _watch(clock, lambda t: 0 if 2 <= t < 6 or 8 <= t < 12 or t >= 20 else None if 14 <= t < 18 else 1)
    pending = Pending(clock, {"a": 1.0, "b": 7.0, "c": 13.0, "d": math.inf})
    done = []
    with pytest.raises(EnvironmentFailure, match="with 1 of the 4 tasks still to run"):
        done.extend(watch.completed(pending, ["a", "b", "c", "d"]))
    assert done == ["a", "b", "c"]
    assert 25.0 <= clock.now <= 25.0 + watch.every + 0.2


def test_each_worker_lost_is_one_warning_line(caplog):
    clock = Clock()
    workers = {"n": 2}
    watch = _watch(clock, lambda t: workers["n"], timeout=300)
    keys = ["t0", "t1", "t2", "t3"]
    pending = Pending(clock, {"t0": 1.0, "t1": 2.0, "t2": 3.0, "t3": 4.0})
    log = logging.getLogger("pipeline.test")

    def lose(event, left):
        watch.removed(event)
        workers["n"] = left

    with caplog.at_level(logging.INFO, logger="pipeline.test"):
        for key in watch.completed(pending, keys, log):
            if key == "t0":  # running t2, holding t0's result, and another run's task
                lose(_removed("tcp://10.0.0.2:40123", ["t2", "other-run"], ["t0"]), 1)
            if key == "t1":
                lose(_removed("tcp://10.0.0.3:40124", [], [], expected=True), 1)
            if key == "t2":
                lose(_removed("tcp://10.0.0.4:40125", ["t3"]), 0)
        watch.removed((0.0, {"action": "add-worker", "worker": "tcp://10.0.0.5:1"}))  # not a loss: not said
        assert list(watch.completed(Pending(clock, {}), keys, log)) == []
    assert [(r.levelname, r.getMessage()) for r in caplog.records] == [
        (
            "WARNING",
            "Dask worker tcp://10.0.0.2:40123 was lost; it had 2 of the 4 tasks (running, queued or done), "
            "re-run on the other workers",
        ),
        ("WARNING", "Dask worker tcp://10.0.0.3:40124 was retired; it had none of the 4 tasks"),
        (
            "WARNING",
            "Dask worker tcp://10.0.0.4:40125 was lost; it had 1 of the 4 tasks (running, queued or done), to re-run; "
            "no worker is left: the run waits 300 s for one (executor.no_workers_timeout_s)",
        ),
    ]


def test_the_no_workers_timeout_is_a_config_key(toy, capsys):
    for wrong in ("0", "-1", "inf"):
        code = main(["validate", str(toy.path), "--set", f"executor.no_workers_timeout_s={wrong}"])
        assert code == 2 and "executor.no_workers_timeout_s" in capsys.readouterr().err
    assert main(["validate", str(toy.path), "--set", "executor.no_workers_timeout_s=5"]) == 0

    class Config:
        class executor:  # noqa: N801 - stands for the configuration's block
            kind, workers, address, no_workers_timeout_s = "dask", 1, "tcp://10.0.0.1:8786", 7.5

    assert make_executor(Config).no_workers_timeout == 7.5
