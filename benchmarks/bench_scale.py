"""LAZ -> classified LAZ + DTM at survey scale: three jobs, per-stage seconds, peak memory, ratio to the I/O floor.

    .venv/bin/python benchmarks/bench_scale.py --points 10e6 [--points 40e6] [--workdir /tmp/bench_scale]
    .venv/bin/python benchmarks/bench_scale.py --points 10e6 --pairs 5 [--job idw]   # paired job / floor
    .venv/bin/python benchmarks/bench_scale.py --points 10e6 --pairs 5 --job defaults --against 9bc4798
    .venv/bin/python benchmarks/bench_scale.py --survey sparse --job defaults [--pairs 3 --against 9bc4798]

The jobs (strip adjustment and the map products off):

- ``idw``: parse -> SMRF ground -> 1 m IDW DTM (+ DSM, nDSM, density) -> LAZ
  (the PDAL reference of issue 9);
- ``tin``: the same with the default TIN DTM;
- ``defaults``: denoise + SMRF + TIN: the default job without map products.

The survey is the synthetic scene of :mod:`tests.synthetic` at 8 pulses/m2
(trees give second returns), written as LAZ; ``--survey sparse`` is instead
the scene of 2 km² at 0.25 pulses/m² with 500 trees (515 k points), a
survey whose cost should follow its points, not its area (a grid of
mostly empty cells).  Each job runs once in its own
process on an empty cache; its stages' seconds come from its ``run.json``,
its peak memory is sampled over the whole process tree (the run and its
workers); its DTM's RMSE against the scene's true terrain
(:func:`tests.synthetic.terrain`, every cell with a value) is the
accuracy check.  The I/O floor is laspy + lazrs reading the same LAZ and writing
it again, in chunks, measured in the same run and the same way as the jobs:
a whole process (interpreter start-up and imports included), wall seconds
and the peak PSS of its process tree; the ratio ``/ I/O floor`` divides
whole process by whole process.  The floor row also gives the seconds of
its read-and-write loop alone (``loop``), the figure this script divided by
until 2026-12-02 (a whole job over a loop without start-up: about 0.5 s of
interpreter and imports counted on one side only).  Every row carries the
machine's load average (other work on the machine slows every figure, the
ratios less).  Prints Markdown rows for docs/BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import laspy
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _isolated import emit, machine, run_child, tree_at  # noqa: E402

STAGES = [
    "parse",
    "denoise",
    "classify_ground",
    "classify_water",
    "classify_objects",
    "rasterize",
    "footprints",
    "export_las",
]
JOBS = {
    "idw": {"denoise": "false", "method": "idw"},
    "tin": {"denoise": "false", "method": "tin"},
    "defaults": {"denoise": "true", "method": "tin"},
}
CONFIG = """input: {{format: las, paths: [{laz}]}}
output: {out}
cache: {cache}
stages:
  strip_adjust: {{enabled: false}}
  denoise: {{enabled: {denoise}}}
  classify_ground: {{algorithm: {{name: smrf}}}}
  rasterize: {{resolution: 1.0, method: {method}}}
  hillshade: {{enabled: false}}
  contours: {{enabled: false}}
  report: {{enabled: false}}
  export_las: {{compress: true}}
"""


#: Points of one scene made in memory; a larger survey is made of such blocks side by side (:func:`_make`).
BLOCK_POINTS = 12.5e6
DENSITY = 8.0
#: The sparse survey (``--survey sparse``): 2 km² at 0.25 pulses/m², the scene's arguments.
SPARSE = "sparse"
SPARSE_SCENE = {"width": 1414, "height": 1414, "density": 0.25, "n_trees": 500}


def _tag(points: float | str) -> str:
    """The survey's name: its size (``10M``), or ``sparse``."""
    return SPARSE if points == SPARSE else f"{points / 1e6:g}M"


def _scene_size(points: float) -> tuple[float, float]:
    area = points / (DENSITY * 1.1)  # about 10 % of pulses give a second return
    width = float(int((area * 1.25) ** 0.5))
    return width, float(int(area / width))


def _make(laz: Path, points: float | str) -> None:
    """The survey: one scene, or above 2 x :data:`BLOCK_POINTS` scenes of other seeds side by side in one LAZ.

    *points* ``"sparse"``: the sparse survey of the module's docstring.
    The blocks' terrain starts again at each block's corner (steps at the
    seams, as between flights of different days; nothing the timing needs
    to avoid); ``blocks.json`` beside the survey tells :func:`_rmse`.
    """
    # lazy: the --one floor child imports only laspy (the I/O floor counts its imports)
    from tests.synthetic import make_scene, write_scene_las

    if points == SPARSE:
        scene = make_scene(**SPARSE_SCENE)
        write_scene_las(scene, laz)
        emit(points=len(scene.x))
        return
    if points <= 2 * BLOCK_POINTS:
        width, height = _scene_size(points)
        scene = make_scene(width=width, height=height, density=DENSITY, n_trees=int(width * height / 4000))
        write_scene_las(scene, laz)
        emit(points=len(scene.x))
        return
    blocks = int(np.ceil(points / BLOCK_POINTS))
    cols = int(np.ceil(np.sqrt(blocks)))
    width, height = _scene_size(points / blocks)
    part = laz.with_name("block.laz")
    n = 0
    writer = None
    for k in range(blocks):
        scene = make_scene(
            width=width, height=height, density=DENSITY, seed=20111 + k, n_trees=int(width * height / 4000)
        )
        scene.x[:] += (k % cols) * width
        scene.y[:] += (k // cols) * height
        write_scene_las(scene, part, compress=False)
        with laspy.open(str(part)) as reader:
            if writer is None:
                writer = laspy.open(str(laz), mode="w", header=reader.header, do_compress=True)
            for chunk in reader.chunk_iterator(2_000_000):
                writer.write_points(chunk)
        n += len(scene.x)
        del scene
    writer.close()
    part.unlink()
    layout = {"width": width, "height": height, "cols": cols, "blocks": blocks}
    (laz.parent / "blocks.json").write_text(json.dumps(layout))
    emit(points=n)


def _floor(laz: Path, out: Path) -> None:
    t0 = time.perf_counter()
    n = 0
    par = laspy.LazBackend.LazrsParallel  # as the pipeline reads and writes
    with (
        laspy.open(str(laz), laz_backend=par) as reader,
        laspy.open(str(out), mode="w", header=reader.header, do_compress=True, laz_backend=par) as w,
    ):
        for chunk in reader.chunk_iterator(1_000_000):
            w.write_points(chunk)
            n += len(chunk)
    emit(seconds=time.perf_counter() - t0, points=n)


def _timed(cmd: list[str], stdout=subprocess.DEVNULL) -> float:
    """Wall seconds of a child process, nothing sampled while it runs (sampling memory costs the job CPU)."""
    t0 = time.perf_counter()
    if subprocess.run(cmd, stdout=stdout).returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}")
    return time.perf_counter() - t0


def _measured(cmd: list[str], stdout=subprocess.DEVNULL) -> tuple[float, float, float]:
    """Wall seconds and peak memory (MB) of a child process *and its workers*.

    The process tree is sampled every 0.1 s (psutil; every 0.2 s until
    2026-12-04, when a peak of 2.5 GB lasting 0.1 s went unseen): the peak
    of the summed RSS (pages shared by the processes, such as libraries,
    counted once per process) and the peak of the summed PSS (shared pages split between the
    processes that share them: the memory the job really takes).  *stdout*:
    where the child's output goes.
    """
    import psutil  # lazy: the --one floor child imports only laspy (the I/O floor counts its imports)

    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=stdout)
    root = psutil.Process(proc.pid)
    peak_rss = peak_pss = 0
    while proc.poll() is None:
        rss = pss = 0
        try:
            for p in [root, *root.children(recursive=True)]:
                try:
                    info = p.memory_full_info()
                    rss += info.rss
                    pss += info.pss
                except (psutil.NoSuchProcess, psutil.AccessDenied):
                    pass
        except psutil.NoSuchProcess:
            break
        peak_rss, peak_pss = max(peak_rss, rss), max(peak_pss, pss)
        time.sleep(0.1)
    proc.wait()
    seconds = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}")
    return seconds, peak_rss / 2**20, peak_pss / 2**20


def _rmse(dtm: Path) -> float:
    """RMSE (m) of a DTM of the scene against its true terrain, over every cell with a value."""
    # lazy: the --one floor child imports only laspy (the I/O floor counts its imports)
    import rasterio

    from tests.synthetic import SAMPLE_ORIGIN, terrain

    with rasterio.open(dtm) as src:
        z = src.read(1).astype(np.float64)
        t = src.transform
        z[z == src.nodata] = np.nan
    rows, cols = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    x, y = t.c + (cols + 0.5) * t.a - SAMPLE_ORIGIN[0], t.f + (rows + 0.5) * t.e - SAMPLE_ORIGIN[1]
    blocks = dtm.parent.parent / "blocks.json"
    if blocks.exists():  # a survey of blocks: each block's terrain from its corner; none where no block lies
        b = json.loads(blocks.read_text())
        block = (y // b["height"]) * b["cols"] + x // b["width"]
        z[(x < 0) | (y < 0) | (x >= b["cols"] * b["width"]) | (block >= b.get("blocks", b["cols"] ** 2))] = np.nan
        x, y = x % b["width"], y % b["height"]
    e = z - terrain(x, y)
    return float(np.sqrt(np.nanmean(e**2)))


def _floor_command(laz: Path, out: Path) -> list[str]:
    """The I/O floor as a process of its own: this script's ``--one floor``."""
    return [sys.executable, __file__, "--one", "floor", str(laz), str(out)]


def _job_config(work: Path, laz: Path, job: str) -> Path:
    """Write *job*'s configuration for the survey *laz* in *work* (output and cache beside it)."""
    config = work / f"{job}.yaml"
    config.write_text(CONFIG.format(laz=laz, out=work / job, cache=work / f"{job}-cache", **JOBS[job]))
    return config


def _floor_process(laz: Path, out: Path) -> tuple[tuple[float, float, float], dict]:
    """The I/O floor as a whole process (as the jobs are timed), and the figures its loop printed."""
    with tempfile.TemporaryFile(mode="w+") as printed:
        measured = _measured(_floor_command(laz, out), stdout=printed)
        printed.seek(0)
        loop = json.loads(printed.read().strip().splitlines()[-1])
    return measured, loop


def _load() -> str:
    return f"{os.getloadavg()[0]:.1f}"


def bench(points: float | str, workdir: Path, jobs: list[str]) -> list[str]:
    tag = _tag(points)
    work = workdir / tag
    laz = work / "survey.laz"
    if laz.exists():  # the survey of an earlier run (it depends on nothing but the point count)
        with laspy.open(str(laz)) as reader:
            n = int(reader.header.point_count)
        for old in work.iterdir():
            if old not in (laz, work / "blocks.json"):
                shutil.rmtree(old) if old.is_dir() else old.unlink()
    else:
        shutil.rmtree(work, ignore_errors=True)
        work.mkdir(parents=True)
        n = run_child(__file__, "make", str(laz), str(points))["points"]
    pipeline = str(Path(sys.executable).with_name("pipeline"))
    load = _load()
    floor, loop = _floor_process(laz, work / "copy.laz")
    rows = [
        f"| {n:,} | I/O floor (laspy + lazrs read + write; loop {loop['seconds']:.1f} s) |{' |' * len(STAGES)} "
        f"{floor[0]:.1f} | {floor[2]:,.0f} | 1 × | | {load} |"
    ]
    print(rows[-1], flush=True)
    for job in jobs:
        config = _job_config(work, laz, job)
        load = _load()
        total, _, pss = _measured([pipeline, "run", str(config), "-q"])
        run = json.loads((work / job / "run.json").read_text())
        ran = {s["name"]: s.get("seconds") for s in run["stages"]}
        cells = " | ".join(f"{ran[s]:.1f}" if ran.get(s) else "–" for s in STAGES)
        rmse = _rmse(work / job / "dtm.tif")
        rows.append(
            f"| {n:,} | {job} | {cells} | **{total:.1f}** | {pss:,.0f} | **{total / floor[0]:.2f} ×** "
            f"| {rmse:.4f} | {load} |"
        )
        print(rows[-1], flush=True)
        shutil.rmtree(work / f"{job}-cache", ignore_errors=True)
    print(f"{tag}: {n:,} points, LAZ {laz.stat().st_size / 1e6:.0f} MB", file=sys.stderr)
    return rows


def pairs(points: float | str, workdir: Path, jobs: list[str], n: int) -> list[str]:
    """Each job and the floor in turn, *n* times (job, floor, job, floor ...): the median of the pair ratios.

    One run of a job moves by about 5 % from run to run; pairing keeps the
    ratio meaningful when the machine's speed drifts.  Whole processes on
    both sides, each job on an empty cache, nothing sampled while they run
    (sampling the process tree's memory, as :func:`bench` does, costs the
    job more than the floor; every 0.2 s then: at 10 M, 5 pairs each, 3.36 ×
    sampled against 3.31 × not, minutes apart).  Needs the survey of an earlier
    run of this script at the same size.
    """
    tag = _tag(points)
    work = workdir / tag
    laz = work / "survey.laz"
    if not laz.exists():
        raise SystemExit(f"{laz}: no survey; run this script once for {tag} first")
    pipeline = str(Path(sys.executable).with_name("pipeline"))
    rows = []
    for job in jobs:
        config = _job_config(work, laz, job)
        times, floors = [], []
        for _ in range(n):
            shutil.rmtree(work / f"{job}-cache", ignore_errors=True)
            times.append(_timed([pipeline, "run", str(config), "-q"]))
            floors.append(_timed(_floor_command(laz, work / "copy.laz")))
        ratios = np.array(times) / np.array(floors)
        rows.append(
            f"| {tag} | {job} / floor, {n} pairs | {np.median(times):.2f} | {np.median(floors):.2f} "
            f"| **{np.median(ratios):.2f} ×** ({ratios.min():.2f}–{ratios.max():.2f}) |"
        )
        print(rows[-1], flush=True)
        shutil.rmtree(work / f"{job}-cache", ignore_errors=True)
    return rows


def _waited(cmd: list[str], cwd: Path, env: dict[str, str]) -> tuple[float, float]:
    """Wall seconds of a whole process, and the peak resident memory (MB) of the largest process it and its
    workers had (the kernel's accounting of the waited-for tree, ``wait4``'s ``ru_maxrss``)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"failed: {' '.join(cmd)}")
    return time.perf_counter() - t0, usage.ru_maxrss / 1024


def against(points: float | str, workdir: Path, jobs: list[str], n: int, commit: str) -> list[str]:
    """Each job run from this tree and from *commit*, in turn (this, that, this, that ...), *n* pairs after one
    warm-up pair: the medians of the pair ratios of wall time and of the largest process's peak memory.

    Both sides on an empty cache, the same survey and configuration, as
    whole processes.  Needs the survey of an earlier run at the same size.
    """
    tag = _tag(points)
    work = workdir / tag
    laz = work / "survey.laz"
    if not laz.exists():
        raise SystemExit(f"{laz}: no survey; run this script once for {tag} first")
    tree, env = tree_at(commit, workdir)
    rows = []
    for job in jobs:
        config = _job_config(work, laz, job)
        sides = {
            "this": (ROOT, dict(os.environ, PYTHONPATH=str(ROOT)), work / "this"),
            commit: (tree, env, work / "that"),
        }
        figures: dict[str, list[tuple[float, float]]] = {k: [] for k in sides}
        for k in range(n + 1):
            for name, (cwd, run_env, out) in sides.items():
                shutil.rmtree(out, ignore_errors=True)
                cmd = [sys.executable, "-m", "pipeline", "run", str(config), "-q"]
                cmd += ["--set", f"output={out}", "--set", f"cache={out}-cache"]
                wall, peak = _waited(cmd, cwd, run_env)
                ran = {s["name"]: s.get("seconds") for s in json.loads((out / "run.json").read_text())["stages"]}
                shutil.rmtree(f"{out}-cache", ignore_errors=True)
                if k:  # the first pair warms the caches of the machine
                    figures[name].append((wall, peak, ran["classify_ground"]))
        this, that = (np.array(figures[name]) for name in sides)
        wall, memory, ground = (this[:, i] / that[:, i] for i in range(3))
        rows.append(
            f"| {tag} | {job}, {n} pairs | {np.median(this[:, 0]):.1f} | {np.median(that[:, 0]):.1f} "
            f"| **{np.median(wall):.3f}** ({wall.min():.3f}–{wall.max():.3f}) "
            f"| {np.median(this[:, 1]):.0f} | {np.median(that[:, 1]):.0f} | **{np.median(memory):.3f}** "
            f"| {np.median(this[:, 2]):.1f} | {np.median(that[:, 2]):.1f} "
            f"| **{np.median(ground):.3f}** ({ground.min():.3f}–{ground.max():.3f}) |"
        )
        print(rows[-1], flush=True)
    return rows


def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--one":
        what, *rest = sys.argv[2:]
        if what == "make":
            _make(Path(rest[0]), rest[1] if rest[1] == SPARSE else float(rest[1]))
        else:
            _floor(Path(rest[0]), Path(rest[1]))
        return
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--points", type=float, action="append", help="survey size (repeatable); default 10e6")
    parser.add_argument(
        "--survey", choices=["dense", SPARSE], default="dense", help="sparse: the 2 km² survey at 0.25 pulses/m²"
    )
    parser.add_argument("--workdir", type=Path, default=Path("/tmp/bench_scale"))
    parser.add_argument("--job", choices=list(JOBS), action="append", help="job to run (repeatable); default all")
    parser.add_argument(
        "--pairs", type=int, default=0, help="instead: each job and the floor in turn, this many times (median ratio)"
    )
    parser.add_argument("--against", metavar="COMMIT", help="with --pairs: each job against the same at COMMIT")
    args = parser.parse_args()
    surveys = [SPARSE] if args.survey == SPARSE else args.points or [10e6]
    print(machine())
    if args.pairs and args.against:
        print(
            f"| points | pair | this tree: wall s (median) | {args.against}: wall s | wall ratio: median (min–max) "
            f"| this tree: largest process MB | {args.against}: MB | memory ratio "
            f"| this tree: classify_ground s | {args.against}: s | classify_ground ratio: median (min–max) |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        for points in surveys:
            against(points, args.workdir, args.job or ["defaults"], args.pairs, args.against)
        return
    if args.pairs:
        print("| points | pair | job s (median) | floor s (median) | job / floor: median (min–max) |")
        print("|---|---|---|---|---|")
        for points in surveys:
            pairs(points, args.workdir, args.job or ["idw"], args.pairs)
        return
    stage_cells = " | ".join(f"{name} s" for name in STAGES)
    print(
        f"| points | job | {stage_cells} | whole job s | peak PSS MB (process tree) | / I/O floor | DTM RMSE m | load (1 min) |"
    )
    print("|" + "---|" * (len(STAGES) + 7))
    for points in surveys:
        bench(points, args.workdir, args.job or list(JOBS))


if __name__ == "__main__":
    main()
