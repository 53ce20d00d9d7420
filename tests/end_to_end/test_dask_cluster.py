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

The workers' folder holds no ``shared`` folder, the run's working folder
does: a path under ``/proc/self/cwd`` is then a folder this run sees and the
workers do not, as a cache on a disk of the run's machine alone would be.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
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


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """The address of a scheduler with two single-threaded worker processes on loopback."""
    tmp = tmp_path_factory.mktemp("cluster")
    workers_cwd = tmp / "workers"
    workers_cwd.mkdir()
    scheduler_file = tmp / "scheduler.json"
    procs: list[subprocess.Popen] = []
    try:
        procs.append(
            _start(
                [str(BIN / "dask"), "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard"]
                + ["--scheduler-file", str(scheduler_file)],
                tmp / "scheduler.log",
                tmp,
            )
        )
        for k in range(2):
            procs.append(
                _start(
                    [str(BIN / "dask"), "worker", "--scheduler-file", str(scheduler_file), "--host", "127.0.0.1"]
                    + ["--nworkers", "1", "--nthreads", "1", "--no-dashboard", "--local-directory", str(tmp / f"w{k}")],
                    tmp / f"worker{k}.log",
                    workers_cwd,
                )
            )
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() or not scheduler_file.read_text().strip():
            assert time.monotonic() < deadline, (tmp / "scheduler.log").read_text()
            assert procs[0].poll() is None, (tmp / "scheduler.log").read_text()
            time.sleep(0.1)
        time.sleep(0.1)  # the file is written at once, but read it whole
        address = json.loads(scheduler_file.read_text())["address"]
        with Client(address, timeout=30) as client:
            client.wait_for_workers(2, timeout=60)
        WORKERS_HOME[address] = workers_cwd
        yield address
    finally:
        for proc in reversed(procs):
            _stop(proc)
    assert all(p.returncode is not None for p in procs)


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


def _run(out: Path, survey: Path, *sets: str) -> dict:
    args = ["run", str(CONFIG), "-q", "--set", f"output={out}", "--set", f"cache={out / 'cache'}"]
    args += ["--set", f"input.paths=[{survey}]", "--set", "stages.accuracy.enabled=false"]
    args += ["--set", "stages.report.enabled=false"]  # 2 s, and it names the run's folders: not comparable
    # 100 m tiles, and SMRF on the tiles too (a survey this small would otherwise get one grid)
    args += ["--set", "tiling.size=100", "--set", "stages.classify_ground.one_grid_cells=0"]
    args += ["--set", "stages.classify_water.one_grid_cells=0"]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return json.loads((out / "run.json").read_text())


def _products(manifest: dict) -> dict[str, str]:
    return {name: p["sha256"] for name, p in manifest["products"].items()}


def _stage(manifest: dict, name: str) -> dict:
    return next(s for s in manifest["stages"] if s["name"] == name)


def test_cluster_run_equals_local_run(cluster, survey, tmp_path):
    local = _run(tmp_path / "local", survey, "executor.workers=1")
    dask = _run(tmp_path / "dask", survey, "executor.kind=dask", f"executor.address={cluster}")
    for name in ("denoise", "classify_ground", "rasterize"):
        tiling = _stage(dask, name)["metrics"]["tiling"]
        assert tiling["executor"] == f"dask {cluster}"
        assert tiling["tiles"] == 6 and tiling["tasks"] == 6, tiling
    products = _products(local)
    assert {"dtm.tif", "dsm.tif", "ndsm.tif", "density.tif", "points.laz", "contours.gpkg"} <= set(products)
    assert _products(dask) == products
    a, b = laspy.read(tmp_path / "local" / "points.laz"), laspy.read(tmp_path / "dask" / "points.laz")
    assert len(a.points) == len(b.points) > 60_000
    assert np.array_equal(a.points.array, b.points.array)


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
