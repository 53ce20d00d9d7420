"""Every stage that does work shows a figure that moves (issue 53, "Messages and progress").

A run's ``run.log`` (the log of a batch job: no terminal, so progress is
log lines) is read stage by stage, between its ``running (stage k of n)``
and ``done in`` lines.  A stage passes when one of its progress reporters
logs at least two distinct figures, increasing, each with the work done,
the total and their unit (``writing: 40% (122562 of 306405 pt)``), or the
executor's ``tiles: 1 of 2 done``.  Two jobs between them run every stage:
the raw helicopter flight (with the DTM cut into tiles) and the LAS sample.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from pipeline.cli import main

ROOT = Path(__file__).resolve().parents[2]

pytestmark = pytest.mark.slow

#: The stages allowed to show no figure, and why: each is one short step over a grid or a few files, with no loop
#: over the survey's points, tiles or rows to count.
INSTANT = {
    "hillshade": "one vectorised pass over the DTM's cells, then GDAL's COG copy (neither reports progress)",
    "accuracy": "the DTM sampled at the check points (tens to thousands) and compared with one truth raster",
    "qgis": "XML styles and a project file for the products: no point or cell is read",
}

#: ``desc: 40% (122562 of 306405 pt)``: a figure with the work done, the total and their unit.
FIGURE = re.compile(r"\[(\w+)\] (.+): (\d+)% \((\d+) of (\d+) (\S+)\)$")
#: The executor's ``tiles: 1 of 2 done``.
TASKS = re.compile(r"\[(\w+)\] (.+): (\d+) of (\d+) done$")

JOBS = {
    "flight": ("configs/flight.yaml", ["stages.export_tiles.tile_size=50"]),
    "las": ("configs/las.yaml", []),
}


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, str]:
    """Job name -> the ``run.log`` of its run."""
    out = {}
    for job, (config, sets) in JOBS.items():
        folder = tmp_path_factory.mktemp(f"progress-{job}")
        args = ["run", str(ROOT / config), "-q", "--set", f"output={folder / 'out'}"]
        for s in [f"cache={folder / 'cache'}", *sets]:
            args += ["--set", s]
        assert main(args) == 0
        out[job] = (folder / "out" / "run.log").read_text()
    return out


def stage_figures(log: str) -> dict[str, dict[str, list[float]]]:
    """Stage -> progress reporter -> its figures (fractions of its total, in order), from ``running`` to ``done``."""
    out: dict[str, dict[str, list[float]]] = {}
    stage = None
    for line in log.splitlines():
        if m := re.search(r"\[(\w+)\] running \(stage \d+ of \d+\)$", line):
            stage = m.group(1)
            out[stage] = {}
        elif m := re.search(r"\[(\w+)\] done in [\d.]+ s$", line):
            assert m.group(1) == stage, line
            stage = None
        elif stage is not None and (m := FIGURE.search(line)):
            assert m.group(1) == stage, line
            done, total = int(m.group(4)), int(m.group(5))
            assert 0 < done < total, line
            assert int(100 * (done - 0.5) / total) <= int(m.group(3)) <= 100 * (done + 0.5) / total, (
                line
            )  # done: rounded
            out[stage].setdefault(m.group(2), []).append(done / total)
        elif stage is not None and (m := TASKS.search(line)):
            assert m.group(1) == stage, line
            out[stage].setdefault(m.group(2), []).append(int(m.group(3)) / int(m.group(4)))
    return out


def test_every_stage_that_works_shows_a_figure_that_moves(logs):
    for job, log in logs.items():
        still = []
        for stage, reporters in stage_figures(log).items():
            if stage in INSTANT:
                continue
            moving = [desc for desc, values in reporters.items() if len(set(values)) >= 2]
            if not moving:
                still.append(f"{stage} ({', '.join(f'{d}: {v}' for d, v in reporters.items()) or 'no figure'})")
        assert not still, f"{job}: stages without a figure that moves: {'; '.join(still)}"


def test_figures_only_increase(logs):
    for job, log in logs.items():
        for stage, reporters in stage_figures(log).items():
            for desc, values in reporters.items():
                assert values == sorted(values), f"{job}: {stage}'s '{desc}' goes back: {values}"


def test_the_jobs_run_every_stage(logs):
    """Between them the two jobs run every stage (so every stage is held to it); each exemption is of a stage."""
    from stages.catalogue import STAGES

    ran = set().union(*(stage_figures(log) for log in logs.values()))
    assert ran == {s.name for s in STAGES}
    assert set(INSTANT) < ran
