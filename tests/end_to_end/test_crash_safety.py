"""Crash safety, damaged cache entries and concurrent runs, on the real stages.

A run is killed with SIGKILL (no clean-up handler runs) at several points of
every stage of the LAS job: when the stage starts, when it has written its
outputs but not yet committed them, and inside the commit (``entry.json``
written, the rename not yet done); then once while products are being copied.
Each killed run is a child process with one function patched to kill it; the
stages themselves are unchanged.  After each kill the cache must hold no
entry for the killed stage; the final re-run must finish, reuse the entries
of the stages that completed, and write products byte-identical to an
uninterrupted run's.

By default each stage is killed at one of the three points, in turn (every
stage once, every point on a third of the stages), and the signals test runs
four of its six moments; ``CRASH_SWEEP=full`` runs the full sweep (every
point of every stage, every moment: about 50 s more), the opt-in run for CI
to execute once.
"""

from __future__ import annotations

import hashlib
import json
import multiprocessing
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import laspy
import numpy as np
import psutil
import pytest

import pipeline.cache as cachemod
import pipeline.runner as runnermod
from pipeline.cli import main
from stages.plugin import plugin
from tests.pipeline import toy

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow

#: Every kill point of every stage, and every signal moment (slow, opt-in): CRASH_SWEEP=full.
FULL_SWEEP = os.environ.get("CRASH_SWEEP", "") == "full"
KILL_POINTS = ("start", "written", "commit")

# Products whose bytes legitimately depend on where and when a run happened.
VARIABLE = {"report.html"}


@pytest.fixture(scope="module")
def small_job(tmp_path_factory):
    """A 120 m x 120 m cut of the LAS sample with its check points and a config."""
    root = tmp_path_factory.mktemp("crash")
    las = laspy.read(ROOT / "data_samples" / "las" / "sample.laz")
    x0, y0 = las.header.mins[:2] + 150.0
    keep = (las.x >= x0) & (las.x < x0 + 120) & (las.y >= y0) & (las.y < y0 + 120)
    small = laspy.LasData(las.header)
    small.points = las.points[np.flatnonzero(keep)].copy()
    small.write(str(root / "small.laz"))
    lines = (ROOT / "data_samples" / "las" / "checkpoints.csv").read_text().splitlines()
    rows = [r for r in lines[2:] if x0 <= float(r.split(",")[1]) < x0 + 120 and y0 <= float(r.split(",")[2]) < y0 + 120]
    assert rows, "the cut must hold check points"
    (root / "cp.csv").write_text("\n".join(lines[:2] + rows) + "\n")
    config = (ROOT / "configs" / "las.yaml").read_text()
    config = config.replace("../data_samples/las/sample.laz", "small.laz").replace(
        "../data_samples/las/checkpoints.csv", "cp.csv"
    )
    (root / "job.yaml").write_text(config)
    return root


def _args(root: Path, tag: str) -> list[str]:
    return [
        "run",
        str(root / "job.yaml"),
        "-q",
        "--set",
        f"output={root / tag / 'out'}",
        "--set",
        f"cache={root / tag / 'cache'}",
    ]


def _products(root: Path, tag: str) -> dict[str, str]:
    manifest = json.loads((root / tag / "out" / "run.json").read_text())
    assert manifest["status"] == "ok"
    return {name: p["sha256"] for name, p in manifest["products"].items() if name not in VARIABLE}


def _die() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def _killed_child(args: list[str], stage: str, point: str) -> None:
    """Run the pipeline and SIGKILL this process at *point* of *stage*."""
    if point == "products":

        def copy_then_die(src, dst):
            Path(dst).parent.mkdir(parents=True, exist_ok=True)  # as _stage_copy does (qc/input_files.csv)
            shutil.copyfile(src, Path(dst).parent / f".{Path(dst).name}.half.tmp")
            _die()

        runnermod._stage_copy = copy_then_die
    elif point == "rename":
        rename = runnermod._rename_into_place
        done = []

        def rename_then_die(tmp, dst):
            if done:
                _die()
            rename(tmp, dst)
            done.append(dst)

        runnermod._rename_into_place = rename_then_die
    else:
        cls = next(c for c in plugin.stages if c.name == stage)
        original = cls.run
        if point == "start":
            cls.run = lambda self, ctx: _die()
        elif point == "written":

            def run_then_die(self, ctx):
                original(self, ctx)
                _die()

            cls.run = run_then_die
        elif point == "commit":
            replace = os.replace

            def replace_or_die(src, dst):
                if Path(src).name.startswith(".tmp-") and Path(dst).parent.name == stage:
                    assert (Path(src) / "entry.json").exists()
                    _die()
                replace(src, dst)

            cachemod.os.replace = replace_or_die  # os is shared: this child only
    sys.exit(main(args))


def _kill(args: list[str], stage: str, point: str) -> int:
    # spawn, not fork: a forked child would inherit the parent's dead thread pools.
    proc = multiprocessing.get_context("spawn").Process(target=_killed_child, args=(args, stage, point))
    proc.start()
    proc.join(300)
    if proc.exitcode is None:
        proc.kill()
    return proc.exitcode


def _complete_entries(cache: Path, stage: str) -> list[Path]:
    folder = cache / stage
    return (
        [d for d in folder.iterdir() if not d.name.startswith(".") and (d / "entry.json").exists()]
        if folder.exists()
        else []
    )


def test_sigkill_inside_every_stage_then_rerun_equals_uninterrupted(small_job):
    root = small_job
    assert main(_args(root, "reference")) == 0
    reference = _products(root, "reference")
    ran = [
        s["name"]
        for s in json.loads((root / "reference" / "out" / "run.json").read_text())["stages"]
        if s["status"] == "ran"
    ]
    assert len(ran) >= 8, ran
    args = _args(root, "killed")
    cache = root / "killed" / "cache"
    kills = 0
    for k, stage in enumerate(ran):
        for point in KILL_POINTS if FULL_SWEEP else KILL_POINTS[k % 3 : k % 3 + 1]:
            assert _kill(args, stage, point) == -signal.SIGKILL, (stage, point)
            kills += 1
            assert _complete_entries(cache, stage) == [], f"{stage}/{point}: an entry of a killed stage is trusted"
            if point != "start":  # the kill left a workspace behind, as a real crash would
                assert list((cache / stage).glob(".tmp-*")), (stage, point)
    assert _kill(args, "", "products") == -signal.SIGKILL
    assert list((root / "killed" / "out").rglob(".*.tmp")), "the products kill left a partial copy"
    assert main(args) == 0
    manifest = json.loads((root / "killed" / "out" / "run.json").read_text())
    # Every stage had completed before the products kill: all are reused.
    assert {s["status"] for s in manifest["stages"] if s["name"] in ran} == {"cached"}
    assert _products(root, "killed") == reference
    # Leftovers of the killed runs are cleaned up by the runs that followed.
    assert not list((root / "killed" / "out").rglob(".*.tmp"))
    assert not [p for p in cache.rglob(".tmp-*")]
    assert kills == (3 if FULL_SWEEP else 1) * len(ran)


def test_damaged_cache_entry_is_recomputed_with_a_warning(small_job, capsys):
    root = small_job
    args = _args(root, "damaged")
    assert main(args) == 0
    before = _products(root, "damaged")
    manifest = json.loads((root / "damaged" / "out" / "run.json").read_text())
    ground = next(s for s in manifest["stages"] if s["name"] == "classify_ground")
    path = Path(next(iter(ground["outputs"].values()))["file"])
    blob = bytearray(path.read_bytes())
    blob[len(blob) // 2] ^= 0x40  # same size: only the checksum can tell
    path.write_bytes(bytes(blob))
    capsys.readouterr()
    assert main(args) == 0
    statuses = {
        s["name"]: s["status"] for s in json.loads((root / "damaged" / "out" / "run.json").read_text())["stages"]
    }
    assert statuses["classify_ground"] == "ran" and statuses["parse"] == "cached"
    err = capsys.readouterr().err
    assert "cache entry classify_ground/" in err and "fails its SHA-256 checksum" in err
    assert _products(root, "damaged") == before


def test_two_concurrent_runs_on_one_cache_both_succeed_identically(small_job):
    root = small_job
    shared_cache = root / "concurrent" / "cache"
    procs = []
    for tag in ("a", "b"):
        cmd = [sys.executable, "-m", "pipeline", *_args(root, f"concurrent/{tag}")]
        cmd[cmd.index(f"cache={root / 'concurrent' / tag / 'cache'}")] = f"cache={shared_cache}"
        procs.append(subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True))
    results = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], results
    a, b = _products(root, "concurrent/a"), _products(root, "concurrent/b")
    assert a == b
    # Each entry was computed once: whatever one run computed, the other reused.
    stages = [
        {
            s["name"]: s["status"]
            for s in json.loads((root / "concurrent" / t / "out" / "run.json").read_text())["stages"]
        }
        for t in ("a", "b")
    ]
    for name, status in stages[0].items():
        if status in ("ran", "cached"):
            assert {status, stages[1][name]} == {"ran", "cached"}, (name, status, stages[1][name])
    for stage_dir in shared_cache.iterdir():
        if stage_dir.name == "tiles":  # the tiles kept for re-runs: each complete, none half-written
            kept = [p for p in stage_dir.glob("*/*/*") if p.is_dir()]
            assert kept and all((p / "tile.json").is_file() and not p.name.startswith(".") for p in kept)
            continue
        assert len(_complete_entries(shared_cache, stage_dir.name)) == 1


def test_a_run_writes_only_inside_its_output_and_cache_folders(small_job, tmp_path, monkeypatch):
    root = small_job
    monkeypatch.chdir(tmp_path)  # a working directory that must stay untouched

    def snapshot() -> dict[str, int]:
        files = {}
        for base in (root, tmp_path):
            for p in base.rglob("*"):
                rel = p.relative_to(root if base == root else tmp_path.parent)
                if p.is_file() and not str(rel).startswith(
                    ("contained/", "reference/", "killed/", "damaged/", "concurrent/")
                ):
                    files[str(rel)] = p.stat().st_mtime_ns
        return files

    before = snapshot()
    assert main(_args(root, "contained")) == 0
    assert snapshot() == before
    written = {p.relative_to(root / "contained").parts[0] for p in (root / "contained").rglob("*") if p.is_file()}
    assert written == {"out", "cache"}


def test_a_product_name_leaving_the_output_folder_is_refused(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PIPELINE_PLUGIN", "tests.pipeline.toy:plugin")
    monkeypatch.setattr(toy.Total, "products", {"total": "../escaped.json"})
    (tmp_path / "numbers.txt").write_text("1\n2\n")
    (tmp_path / "toy.yaml").write_text("source: {path: numbers.txt}\noutput: out\n")
    assert main(["run", str(tmp_path / "toy.yaml"), "-q"]) == 2
    assert "would be written outside the output folder" in capsys.readouterr().err
    assert not (tmp_path / "escaped.json").exists()
    assert not (tmp_path / "out" / ".cache").exists()  # refused at planning: no stage ran


def test_two_concurrent_runs_of_one_configuration_same_output(small_job):
    """The overlapping-cron-job case: same configuration, same output and cache folders."""
    root = small_job
    reference = _products(root, "reference") if (root / "reference" / "out" / "run.json").exists() else None
    cmd = [sys.executable, "-m", "pipeline", *_args(root, "same")]
    procs = [subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in "ab"]
    results = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], results
    products = _products(root, "same")
    if reference is not None:
        assert products == reference
    for name, digest in products.items():
        assert hashlib.sha256((root / "same" / "out" / name).read_bytes()).hexdigest() == digest
    assert not list((root / "same" / "out").glob(".*.tmp"))


def test_a_killed_run_leaves_no_worker_behind(small_job, tmp_path):
    """SIGKILL a tiled run while its worker processes work: they exit too (no orphans), and a re-run completes."""
    out = tmp_path / "out"
    cmd = [str(Path(sys.executable).with_name("pipeline")), "run", str(small_job / "job.yaml"), "-q"]
    cmd += ["--set", f"output={out}", "--set", f"cache={tmp_path / 'cache'}"]
    cmd += ["--set", "tiling.size=50", "--set", "executor.workers=2", "--set", "executor.kind=local"]
    cmd += ["--set", "executor.in_process_below=0"]  # a small job: workers all the same
    run = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    parent = psutil.Process(run.pid)
    workers: list = []
    deadline = time.time() + 60
    while not workers and time.time() < deadline and run.poll() is None:
        workers = [c for c in parent.children(recursive=True) if "spawn_main" in " ".join(c.cmdline())]
        time.sleep(0.05)
    assert workers, "the run should have started worker processes"
    run.send_signal(signal.SIGKILL)
    run.wait()
    gone, alive = psutil.wait_procs(workers, timeout=10)
    assert not alive, f"{len(alive)} worker(s) outlived the killed run"
    assert main(cmd[1:]) == 0
    assert (out / "dtm.tif").exists()


def _run_until(cmd: list[str], trigger: str, signum: int, group: bool):
    """Start a run, send *signum* when its log shows *trigger*; return (exit code, log, processes it had)."""
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines = []
    for line in proc.stderr:
        lines.append(line)
        if trigger in line:
            break
    else:
        proc.wait()
        raise AssertionError(f"the run ended before '{trigger}':\n{''.join(lines)}")
    children = psutil.Process(proc.pid).children(recursive=True)
    if group:  # Ctrl-C on a terminal, systemd: every process of the group gets it
        os.killpg(proc.pid, signum)
    else:  # kill PID, a batch scheduler
        proc.send_signal(signum)
    rest = proc.stderr.read()
    code = proc.wait(timeout=60)  # a hang (as in ProcessPoolExecutor.shutdown) fails here
    return code, "".join(lines) + rest, children


#: (log line that triggers the signal, signal, sent to the process group): the first, second, fourth
#: and last cover both signals, both ways of sending them and the three tiled stages; CRASH_SWEEP=full
#: adds SIGTERM before classify_ground's tiles and SIGINT in rasterize.
SIGNAL_MOMENTS = [
    ("[denoise] tiles: 1 of", signal.SIGINT, True),
    ("[denoise] tiles: 1 of", signal.SIGTERM, False),
    ("[classify_ground] running", signal.SIGTERM, True),
    ("[classify_ground] tiles: 1 of", signal.SIGINT, False),
    ("[rasterize] tiles: 1 of", signal.SIGINT, True),
    ("[rasterize] tiles: 1 of", signal.SIGTERM, True),
]


@pytest.mark.parametrize(
    ("trigger", "signum", "group"),
    SIGNAL_MOMENTS if FULL_SWEEP else [SIGNAL_MOMENTS[i] for i in (0, 1, 3, 5)],
)
def test_sigint_and_sigterm_stop_a_tiled_run_cleanly(small_job, trigger, signum, group):
    """Interrupted while its workers hold tiles: exit 128+signal, no traceback, run.json 'interrupted', no process left.

    The products of the last complete run stay, and run.json still describes them.
    """
    root = small_job
    base = root / "signals"
    tiled = ["--set", "tiling.size=50", "--set", "executor.workers=2", "--set", "executor.kind=local"]
    tiled += ["--set", "executor.in_process_below=0"]  # a small job: workers all the same
    if trigger.startswith("[classify_ground] tiles"):  # SMRF filters a grid this small whole, in this process
        tiled += ["--set", "stages.classify_ground.one_grid_cells=0"]
    pipeline = str(Path(sys.executable).with_name("pipeline"))
    if not (base / "out" / "run.json").exists():
        args = _args(root, "signals")
        assert main([*args, *tiled]) == 0
    before = json.loads((base / "out" / "run.json").read_text())
    trial = base / f"cache-{signum}-{trigger.split(']')[0][1:]}-{group}"
    cmd = [pipeline, "run", str(root / "job.yaml"), "--set", f"output={base / 'out'}", "--set", f"cache={trial}"]
    code, log, children = _run_until([*cmd, *tiled], trigger, signum, group)
    assert code == 128 + signum, log
    assert "Traceback" not in log and "leaked" not in log, log
    assert f"pipeline: interrupted by {signal.Signals(signum).name}" in log
    manifest = json.loads((base / "out" / "run.json").read_text())
    assert manifest["status"] == "interrupted"
    assert manifest["error"] == f"interrupted by {signal.Signals(signum).name}"
    assert manifest["products"] == before["products"]
    for name, product in manifest["products"].items():
        assert hashlib.sha256((base / "out" / name).read_bytes()).hexdigest() == product["sha256"], name
    gone, alive = psutil.wait_procs(children, timeout=5)
    assert not alive, f"{len(alive)} process(es) outlived the interrupted run"
    assert not [p for p in trial.rglob(".tmp-*")], "the interrupted run left a workspace"
    # Run again: it resumes (complete stages reused) and finishes.
    assert main([*cmd[1:], "-q", *tiled]) == 0
    assert json.loads((base / "out" / "run.json").read_text())["status"] == "ok"


def test_sigkill_while_renaming_products_leaves_run_json_publishing(small_job):
    """A kill between two renames of publication shows in run.json (the first publication too); a re-run completes it."""
    root = small_job
    for tag in ("pubkill-first", "pubkill-again"):
        args = _args(root, tag)
        if (root / "reference" / "cache").exists():  # the stages' entries are not what is tested: reuse them
            shutil.copytree(root / "reference" / "cache", root / tag / "cache")
        if tag == "pubkill-again":
            assert main(args) == 0
            args = [*args, "--set", "stages.rasterize.resolution=2.0"]  # new products to rename into place
        assert _kill(args, "", "rename") == -signal.SIGKILL
        manifest = json.loads((root / tag / "out" / "run.json").read_text())
        assert manifest["status"] == "publishing", tag
        assert main(args) == 0
        assert json.loads((root / tag / "out" / "run.json").read_text())["status"] == "ok"
        assert not list((root / tag / "out").glob(".*.tmp"))
