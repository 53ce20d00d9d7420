"""A Dask cluster of separate processes runs the project to the local run's products, byte for byte.

The scheduler and two workers are started the standard way (``dask
scheduler``, ``dask worker --nworkers 1 --nthreads 1``, from this
environment's ``bin``) on 127.0.0.1, meeting through a scheduler file; the
workers import this tree (``PYTHONPATH``) and run in a folder of their own.
The survey: the shipped LAS sample cut to 240 m x 180 m (about 66,000
points), in 100 m tiles (3 x 2).  The LAS job (noise, SMRF ground, TIN DTM,
DSM, nDSM, density, hillshade, contours, LAZ export; no report) runs on the local
executor, then on the cluster (``executor: {kind: dask, address: ...}``);
every product's SHA-256 in ``run.json`` must agree.

Issue 53, on clusters of their own: one of two workers killed (its process
group, nanny and worker) while it holds tiles is one WARNING line naming it,
and the products are the local run's; the only worker killed stops the run
after ``executor.no_workers_timeout_s`` (5 s here), exit 4, and the same
command run again once a worker is back makes the local run's products.

The workers' folder holds no ``shared`` folder, the run's working folder
does: a path under ``/proc/self/cwd`` is then a folder this run sees and the
workers do not, as a cache on a disk of the run's machine alone would be.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import laspy
import numpy as np
import pytest
from distributed import Client

from pipeline.cli import main
from pipeline.errors import EnvironmentFailure
from pipeline.executor import DaskExecutor

ROOT = Path(__file__).resolve().parents[2]
CONFIG = ROOT / "configs" / "las.yaml"
BIN = Path(sys.executable).parent

pytestmark = pytest.mark.slow

#: The working folder of each started cluster's workers, by scheduler address.
WORKERS_HOME: dict[str, Path] = {}


def _start(args: list[str], log: Path, cwd: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    with open(log, "wb") as out:
        # a session of its own: the teardown stops the process and every process it started
        return subprocess.Popen(args, cwd=cwd, env=env, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)


def _stop(proc: subprocess.Popen) -> None:
    for sig, wait in ((signal.SIGTERM, 10.0), (signal.SIGKILL, 10.0)):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass
        try:
            proc.wait(wait)
            return
        except subprocess.TimeoutExpired:
            continue


class Cluster:
    """A scheduler and its worker processes on 127.0.0.1, meeting through a scheduler file in *home*."""

    def __init__(self, home: Path):
        self.home = home
        self.scheduler_file = home / "scheduler.json"
        self.workers_cwd = home / "workers"
        self.workers_cwd.mkdir(parents=True)
        self.procs: list[subprocess.Popen] = []
        self.address = ""

    def start(self, workers: int) -> str:
        """Start the scheduler and *workers* workers; the scheduler's address, once every worker has joined."""
        self.procs.append(
            _start(
                [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
                + ["--scheduler-file", str(self.scheduler_file)],
                self.home / "scheduler.log",
                self.home,
            )
        )
        for _ in range(workers):
            self.add_worker()
        deadline = time.monotonic() + 60
        while not self.scheduler_file.exists() or not self.scheduler_file.read_text().strip():
            assert time.monotonic() < deadline, (self.home / "scheduler.log").read_text()
            assert self.procs[0].poll() is None, (self.home / "scheduler.log").read_text()
            time.sleep(0.1)
        time.sleep(0.1)  # the file is written at once, but read it whole
        self.address = json.loads(self.scheduler_file.read_text())["address"]
        self.wait_for_workers(workers)
        return self.address

    def add_worker(self) -> subprocess.Popen:
        """Start one more worker (one process of one thread), in a session of its own."""
        k = len(self.procs)
        proc = _start(
            [str(BIN / "dask"), "worker", "--scheduler-file", str(self.scheduler_file), "--host", "127.0.0.1"]
            + ["--nworkers", "1", "--nthreads", "1", "--no-dashboard", "--local-directory", str(self.home / f"w{k}")],
            self.home / f"worker{k}.log",
            self.workers_cwd,
        )
        self.procs.append(proc)
        return proc

    def wait_for_workers(self, n: int) -> None:
        with Client(self.address, timeout=30, set_as_default=False) as client:
            client.wait_for_workers(n, timeout=60)

    def stop(self) -> None:
        for proc in reversed(self.procs):
            _stop(proc)
        assert all(p.returncode is not None for p in self.procs)


@contextlib.contextmanager
def started(home: Path, workers: int) -> Iterator[Cluster]:
    """A :class:`Cluster` of *workers* workers, stopped (every process it started) on leaving."""
    cluster = Cluster(home)
    try:
        cluster.start(workers)
        yield cluster
    finally:
        cluster.stop()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The address of a scheduler with two single-threaded worker processes on loopback."""
    with started(tmp_path_factory.mktemp("cluster"), 2) as c:
        WORKERS_HOME[c.address] = c.workers_cwd
        yield c.address


@pytest.fixture(scope="module")
def survey(tmp_path_factory) -> Path:
    """The shipped sample's points in 440000-440240 E, 4474000-4474180 N (about 66,000 points)."""
    src = laspy.read(ROOT / "data_samples" / "las" / "sample.laz")
    keep = (src.x < 440_240) & (src.y < 4_474_180)
    out = laspy.LasData(src.header)
    out.points = src.points[keep]
    path = tmp_path_factory.mktemp("survey") / "cut.las"
    out.write(path)
    return path


def _args(out: Path, survey: Path, *sets: str) -> list[str]:
    """``pipeline run`` of the LAS job on *survey* into *out*, in 100 m tiles; *sets*: more ``--set``."""
    args = ["run", str(CONFIG), "-q", "--set", f"output={out}", "--set", f"cache={out / 'cache'}"]
    args += ["--set", f"input.paths=[{survey}]", "--set", "stages.accuracy.enabled=false"]
    args += ["--set", "stages.report.enabled=false"]  # 2 s, and it names the run's folders: not comparable
    # 100 m tiles, and SMRF on the tiles too (a survey this small would otherwise get one grid)
    args += ["--set", "tiling.size=100", "--set", "stages.classify_ground.one_grid_cells=0"]
    args += ["--set", "stages.classify_water.one_grid_cells=0"]
    for s in sets:
        args += ["--set", s]
    return args


def _run(out: Path, survey: Path, *sets: str) -> dict:
    assert main(_args(out, survey, *sets)) == 0
    return json.loads((out / "run.json").read_text())


def _products(manifest: dict) -> dict[str, str]:
    return {name: p["sha256"] for name, p in manifest["products"].items()}


def _stage(manifest: dict, name: str) -> dict:
    return next(s for s in manifest["stages"] if s["name"] == name)


@pytest.fixture(scope="module")
def local(survey, tmp_path_factory) -> Path:
    """The output folder of the LAS job on the survey, run on the local executor."""
    out = tmp_path_factory.mktemp("local") / "out"
    _run(out, survey, "executor.workers=1")
    return out


def _same_products(out: Path, local: Path) -> None:
    """The run into *out* made the *local* run's products, byte for byte."""
    products = _products(json.loads((local / "run.json").read_text()))
    assert {"dtm.tif", "dsm.tif", "ndsm.tif", "density.tif", "points.laz", "contours.gpkg"} <= set(products)
    assert _products(json.loads((out / "run.json").read_text())) == products
    a, b = laspy.read(local / "points.laz"), laspy.read(out / "points.laz")
    assert len(a.points) == len(b.points) > 60_000
    assert np.array_equal(a.points.array, b.points.array)


def test_cluster_run_equals_local_run(cluster, survey, local, tmp_path):
    dask = _run(tmp_path / "dask", survey, "executor.kind=dask", f"executor.address={cluster}")
    for name in ("denoise", "classify_ground", "rasterize"):
        tiling = _stage(dask, name)["metrics"]["tiling"]
        assert tiling["executor"] == f"dask {cluster}"
        assert tiling["tiles"] == 6 and tiling["tasks"] == 6, tiling
    _same_products(tmp_path / "dask", local)


class Killer(threading.Thread):
    """Kills a worker's process group (the worker and its nanny) once it runs or holds one of the tasks.

    Watches the scheduler from a client of its own; :attr:`killed` is the
    worker's address, :attr:`at` the time (``time.monotonic``).
    """

    def __init__(self, address: str):
        super().__init__(name="killer", daemon=True)
        self.client = Client(address, timeout=30, set_as_default=False)
        self.groups = self.client.run(os.getpgrp)  # worker address -> its process group, the `dask worker` session
        self.killed: str | None = None
        self.at = 0.0

    def run(self) -> None:
        deadline = time.monotonic() + 120
        while self.killed is None and time.monotonic() < deadline:
            busy = [w for w, keys in self.client.processing().items() if keys]
            if busy:
                os.killpg(self.groups[busy[0]], signal.SIGKILL)
                self.killed, self.at = busy[0], time.monotonic()
            time.sleep(0.02)

    def done(self) -> str:
        """The address of the worker killed (the test fails where none was)."""
        self.join(130)
        self.client.close()
        assert self.killed is not None, "no worker was seen running a task"
        return self.killed


def test_a_worker_killed_mid_run_is_said_and_the_products_are_the_same(survey, local, tmp_path, capfd):
    """Issue 53: two workers, one killed during the first tiled stage: one WARNING line, the products unchanged."""
    with started(tmp_path / "cluster", 2) as cluster:
        killer = Killer(cluster.address)
        killer.start()
        _run(tmp_path / "out", survey, "executor.kind=dask", f"executor.address={cluster.address}")
        worker = killer.done()
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if f"Dask worker {worker} " in line]
    assert len(lines) == 1, err
    assert re.search(
        rf"WARNING +(\[\w+\] )?Dask worker {worker} was lost; it had [1-9]\d* of the \d+ tasks "
        r"\(running, queued or done\), re-run on the other workers$",
        lines[0],
    ), lines[0]
    assert "Traceback" not in err
    _same_products(tmp_path / "out", local)


def test_a_cluster_without_workers_stops_the_run_then_resumes(survey, local, tmp_path, capfd):
    """Issue 53: the only worker killed: exit 4 after executor.no_workers_timeout_s; a new worker, the same command."""
    with started(tmp_path / "cluster", 1) as cluster:
        address = cluster.address
        args = _args(tmp_path / "out", survey, "executor.kind=dask", f"executor.address={address}")
        args += ["--set", "executor.no_workers_timeout_s=5"]
        killer = Killer(address)
        killer.start()
        rescue = threading.Timer(60, cluster.add_worker)  # a timeout that never fires: the run ends, and fails here
        rescue.start()
        code = main(args)
        rescue.cancel()
        waited = time.monotonic() - killer.at
        worker = killer.done()
        err = capfd.readouterr().err
        assert code == 4, err
        assert 5 <= waited < 5 + 10, waited  # the timeout, the scheduler's notice and one poll; not for ever
        lost = [line for line in err.splitlines() if f"Dask worker {worker} " in line]
        assert len(lost) == 1 and " WARNING " in lost[0], err
        assert lost[0].endswith(
            ", to re-run; no worker is left: the run waits 5 s for one (executor.no_workers_timeout_s)"
        ), lost[0]
        assert re.search(
            rf"pipeline: error: stage '\w+': executor.address {address}: no Dask worker for 5 s "
            r"\(executor.no_workers_timeout_s\) with \d+ of the \d+ tasks still to run; start workers "
            rf"\(`dask worker {address}`\), then run again to resume: complete stages are reused.\n$",
            err,
        ), err
        assert "Traceback" not in err

        cluster.add_worker()
        cluster.wait_for_workers(1)
        assert main(args) == 0
    _same_products(tmp_path / "out", local)


def listing(folder: str) -> list[str]:
    """The names in *folder* (a task that reads its folder, as the stages' tasks do)."""
    return sorted(os.listdir(folder))


def test_a_folder_the_workers_cannot_see_is_one_sentence(cluster, tmp_path, monkeypatch):
    """A task whose folder exists here but not on the worker: EnvironmentFailure naming it (exit 4)."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "shared" / "tile").mkdir(parents=True)
    folder = "/proc/self/cwd/shared/tile"
    assert listing(folder) == []  # here it exists
    ex = DaskExecutor(cluster, 1)
    try:
        with pytest.raises(EnvironmentFailure) as caught:
            ex.map(listing, [folder, folder])
    finally:
        ex.close()
    assert caught.value.exit_code == 4
    assert str(caught.value) == (
        f"a Dask worker of {cluster} cannot see the folder {folder}, which this run sees: the cache and its "
        "workspaces must be on a filesystem every worker mounts at the same path."
    )


def test_a_cache_the_workers_cannot_see_stops_the_run_with_exit_4(cluster, survey, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    cache = "/proc/self/cwd/cache"
    args = ["run", str(CONFIG), "-q", "--set", f"output={tmp_path / 'out'}", "--set", f"cache={cache}"]
    args += ["--set", f"input.paths=[{survey}]", "--set", "stages.accuracy.enabled=false"]
    args += ["--set", "tiling.size=100", "--set", "executor.kind=dask", "--set", f"executor.address={cluster}"]
    assert main(args) == 4
    err = capsys.readouterr().err
    # checked on connecting, before any task: the first worker that does not see the cache is named
    assert "stage 'denoise': worker tcp://127.0.0.1:" in err, err
    assert f" of {cluster} cannot see the folder {cache}, which this run sees: " in err, err
    assert "Traceback" not in err
    # and no worker wrote tile parts into the folder it sees at that path, its own (they did before the check)
    assert not (WORKERS_HOME[cluster] / "cache").exists()


def stop_scheduler(pid: int) -> int:
    """A task that kills the scheduler's process group (*pid*), then waits as a long task would."""
    os.killpg(pid, signal.SIGKILL)
    time.sleep(60)
    return pid


def test_a_scheduler_lost_during_the_tasks_is_exit_4(tmp_path, capfd):
    """Its own scheduler and worker: the task kills the scheduler; the run's wait ends in one sentence."""
    sf = tmp_path / "scheduler.json"
    scheduler = _start(
        [
            str(BIN / "dask"),
            "scheduler",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--no-dashboard",
            "--scheduler-file",
            str(sf),
        ],
        tmp_path / "scheduler.log",
        tmp_path,
    )
    worker = _start(
        [str(BIN / "dask"), "worker", "--scheduler-file", str(sf), "--host", "127.0.0.1", "--nworkers", "1"]
        + ["--nthreads", "1", "--no-dashboard", "--local-directory", str(tmp_path / "w")],
        tmp_path / "worker.log",
        tmp_path,
    )
    try:
        deadline = time.monotonic() + 60
        while not sf.exists() or not sf.read_text().strip():
            assert time.monotonic() < deadline and scheduler.poll() is None, (tmp_path / "scheduler.log").read_text()
            time.sleep(0.1)
        time.sleep(0.1)
        address = json.loads(sf.read_text())["address"]
        ex = DaskExecutor(address, 1)
        with pytest.raises(EnvironmentFailure) as caught:
            ex.map(stop_scheduler, [scheduler.pid])
        ex.close()
    finally:
        _stop(worker)
        _stop(scheduler)
    assert caught.value.exit_code == 4
    assert str(caught.value) == (
        f"executor.address {address}: the Dask scheduler cancelled the tasks (scheduler-connection-lost); "
        "run again to resume: complete stages are reused."
    )
    assert "Traceback" not in capfd.readouterr().err
