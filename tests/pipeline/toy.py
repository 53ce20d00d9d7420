"""Toy stages (numbers in a text file) that drive the engine in tests.

load -> scale -> total (product)
            \\-> histogram (product)
"""

from __future__ import annotations

import json
import os
import signal
from pathlib import Path
from typing import ClassVar

from pydantic import Field

from pipeline.config import InputFile, StrictModel
from pipeline.errors import InputDataError
from pipeline.runner import FAILED_CHECKS
from pipeline.stage import Plugin, Stage, StageParams


class SourceParams(StrictModel):
    path: InputFile
    comment: str = "#"


class Load(Stage):
    name = "load"
    Params = SourceParams
    config_path = "source"
    outputs: ClassVar = {"numbers": "numbers.json"}

    def external_files(self, params, config):
        return [params.path]

    def run(self, ctx):
        values = []
        for lineno, line in enumerate(Path(ctx.params.path).read_text().splitlines(), 1):
            line = line.split(ctx.params.comment)[0].strip()
            if not line:
                continue
            try:
                values.append(float(line))
            except ValueError:
                raise InputDataError(f"{ctx.params.path}, line {lineno}: '{line}' is not a number.") from None
        ctx.metrics["count"] = len(values)
        ctx.outputs["numbers"].write_text(json.dumps(values))


class ScaleParams(StageParams):
    factor: float = Field(2.0, description="multiply every number")
    fail: bool = False


class Scale(Stage):
    name = "scale"
    Params = ScaleParams
    inputs = ("numbers",)
    outputs: ClassVar = {"scaled": "scaled.json"}
    passthrough: ClassVar = {"scaled": "numbers"}

    def run(self, ctx):
        values = json.loads(ctx.inputs["numbers"].read_text())
        with ctx.progress(len(values), "scaling") as bar:
            out = []
            for v in values:
                out.append(v * ctx.params.factor)
                bar.update()
        ctx.outputs["scaled"].write_text("partial")
        if ctx.params.fail:
            raise RuntimeError("boom")
        ctx.outputs["scaled"].write_text(json.dumps(out))


class Total(Stage):
    name = "total"
    inputs = ("scaled",)
    outputs: ClassVar = {"total": "total.json"}
    products: ClassVar = {"total": "total.json"}

    def run(self, ctx):
        values = json.loads(ctx.inputs["scaled"].read_text())
        ctx.outputs["total"].write_text(json.dumps({"total": sum(values)}))


class HistParams(StageParams):
    bins: int = Field(4, ge=1)
    max_count: int | None = Field(None, ge=0)  # a check: a bin holding more values fails it


class Histogram(Stage):
    name = "histogram"
    Params = HistParams
    inputs = ("scaled",)
    outputs: ClassVar = {"hist": "hist.json"}
    products: ClassVar = {"hist": "hist.json"}

    def run(self, ctx):
        values = json.loads(ctx.inputs["scaled"].read_text())
        if ctx.params.bins > len(values):
            ctx.log.warning("more bins (%d) than values (%d)", ctx.params.bins, len(values))
        lo, hi = min(values), max(values)
        width = (hi - lo) / ctx.params.bins or 1.0
        counts = [0] * ctx.params.bins
        for v in values:
            counts[min(int((v - lo) / width), ctx.params.bins - 1)] += 1
        ctx.outputs["hist"].write_text(json.dumps(counts))
        if ctx.params.max_count is not None:
            ctx.metrics[FAILED_CHECKS] = [
                f"bin {i} holds {n} values, more than {ctx.params.max_count}"
                for i, n in enumerate(counts)
                if n > ctx.params.max_count
            ]


class Summary(Stage):
    """Reads the metrics of the stages before it (like a report)."""

    name = "summary"
    reads_metrics = True
    inputs = ("hist",)
    outputs: ClassVar = {"summary": "summary.json"}
    products: ClassVar = {"summary": "summary.json"}

    def run(self, ctx):
        ctx.outputs["summary"].write_text(json.dumps({"count": ctx.upstream_metrics["load"]["count"]}))


class Unit(StrictModel):
    label: str = "m"


plugin = Plugin(
    name="toy",
    stages=[Load, Scale, Total, Histogram, Summary],
    global_fields={"unit": (Unit, Field(default_factory=Unit))},
)


def square_or_die(task: dict) -> float:
    """A worker task: the square of ``task["value"]``; a task with ``die`` kills its own process (SIGKILL)."""
    if task.get("die"):
        os.kill(os.getpid(), signal.SIGKILL)
    return task["value"] ** 2


class SpreadParams(StageParams):
    die: bool = Field(False, description="the worker running the second task kills itself (SIGKILL)")


class Spread(Stage):
    """Squares the numbers in worker processes (``executor.map``), as a tiled stage does its tiles."""

    name = "spread"
    Params = SpreadParams
    inputs = ("numbers",)
    outputs: ClassVar = {"squares": "squares.json"}
    products: ClassVar = {"squares": "squares.json"}

    def run(self, ctx):
        values = json.loads(ctx.inputs["numbers"].read_text())
        tasks = [{"value": v, "die": ctx.params.die and i == 1} for i, v in enumerate(values)]
        ctx.outputs["squares"].write_text("partial")
        squares = ctx.executor.map(square_or_die, tasks, log=ctx.log)
        ctx.outputs["squares"].write_text(json.dumps(squares))


#: load -> spread (product): work in worker processes.
parallel_plugin = Plugin(name="toy-parallel", stages=[Load, Spread])
