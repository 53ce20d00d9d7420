"""Progress figures: their log lines, work without a stage's context (stage_progress), and the executors' part."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import ClassVar

from pipeline.cli import main
from pipeline.executor import LocalExecutor
from pipeline.log import Progress, RunLog, hosting, stage_progress
from pipeline.stage import Plugin, Stage
from tests.pipeline.toy import Load


def _lines(log: RunLog) -> list[str]:
    """The messages of the captured lines, with their stage (``[toy] ...``)."""
    return [re.sub(r"^\S+ \S+ INFO +", "", line) for line in log.lines]


def test_a_figure_is_logged_every_tenth_with_its_counts_and_unit():
    with RunLog() as log, Progress(300, "squaring", "toy", unit="squares") as bar:
        for _ in range(30):
            bar.update(10)
    assert _lines(log) == [f"[toy] squaring: {k}% ({3 * k} of 300 squares)" for k in range(10, 100, 10)]


def test_a_figure_that_jumps_is_logged_once_and_never_at_the_end():
    with RunLog() as log, Progress(1000, "reading", "toy", unit="pt") as bar:
        bar.update(450)
        bar.update(549)
        bar.update(1)
    assert _lines(log) == ["[toy] reading: 45% (450 of 1000 pt)", "[toy] reading: 99% (999 of 1000 pt)"]


def count_to(n: int) -> int:
    """A task (module level, for the workers) that reports its own progress through stage_progress."""
    with stage_progress(n, f"counting to {n}", unit="steps") as bar:
        for _ in range(n):
            bar.update(1)
    return n


def test_stage_progress_is_heard_only_where_a_stage_hosts_it():
    with RunLog() as log:
        count_to(4)
        with hosting("toy"):
            count_to(4)
            with hosting(None):
                count_to(5)
    assert _lines(log) == [f"[toy] counting to 4: {k}% ({k // 25} of 4 steps)" for k in (25, 50, 75)]


def test_a_task_run_alone_here_is_heard_and_tasks_run_one_after_another_are_counted():
    ex, seen = LocalExecutor(1), []
    with RunLog() as log, hosting("toy"):
        assert ex.map(count_to, [2]) == [2]
        assert ex.map(count_to, [4, 10], log=Progress(1, "", "toy").log, what="tasks", done=seen.append) == [4, 10]
    assert _lines(log) == [
        "[toy] counting to 2: 50% (1 of 2 steps)",
        "[toy] tasks: 1 of 2 done",
        "[toy] tasks: 2 of 2 done",
    ]
    assert seen == [4, 10]


def test_the_workers_tell_each_task_done():
    ex, seen = LocalExecutor(2), []
    try:
        with RunLog() as log, hosting("toy"):
            assert ex.map(count_to, [3, 4, 5, 6], done=seen.append) == [3, 4, 5, 6]
    finally:
        ex.close()
    assert sorted(seen) == [3, 4, 5, 6]
    assert not log.lines  # the workers' own figures reach no run log: the tasks done are the figure


class Counted(Stage):
    """Counts to each number in a task of the run's executor, as a tiled stage runs its tiles."""

    name = "counted"
    inputs = ("numbers",)
    outputs: ClassVar = {"counts": "counts.json"}

    def run(self, ctx):
        values = [int(v) for v in json.loads(ctx.inputs["numbers"].read_text())]
        ctx.outputs["counts"].write_text(json.dumps(ctx.executor.map(count_to, values[-1:], log=ctx.log)))


plugin = Plugin(name="toy-progress", stages=[Load, Counted])


def test_a_stage_hosts_its_tasks_progress_in_a_run(tmp_path, monkeypatch):
    monkeypatch.setenv("PIPELINE_PLUGIN", "tests.pipeline.test_progress:plugin")
    (tmp_path / "numbers.txt").write_text("1\n2\n10\n")
    config = tmp_path / "toy.yaml"
    config.write_text("name: toy\nsource:\n  path: numbers.txt\noutput: out\n")
    assert main(["run", str(config), "-q"]) == 0
    log = (tmp_path / "out" / "run.log").read_text()
    figures = re.findall(r"\[counted\] counting to 10: (\d+)% \((\d+) of 10 steps\)", log)
    assert figures == [(str(10 * k), str(k)) for k in range(1, 10)]
    assert Path(tmp_path / "out" / "run.json").is_file()
