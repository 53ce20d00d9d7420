"""Log lines (text or JSON) and progress bars.

On a terminal, long work shows a progress bar per stage (tqdm, on stderr).
Otherwise (batch jobs, CI, ``--log-format json``) progress becomes a log line
at about every tenth of the work, so logs stay readable and bounded:
``desc: 40% (1200 of 3000 pt)``.  Code without the stage's context (an executor's
task) reports through :func:`stage_progress`, heard when it runs in its
stage's own process.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Any

LOGGER_NAME = "pipeline"


class TextFormatter(logging.Formatter):
    """``HH:MM:SS LEVEL [stage] message``; *dated*: with the date and the UTC offset (a log file's lines)."""

    def __init__(self, dated: bool = False):
        super().__init__()
        self.dated = dated

    def format(self, record: logging.LogRecord) -> str:
        when = "%Y-%m-%d %H:%M:%S%z" if self.dated else "%H:%M:%S"
        stamp = time.strftime(when, time.localtime(record.created))
        stage = getattr(record, "stage", None)
        where = f" [{stage}]" if stage else ""
        return f"{stamp} {record.levelname:<7}{where} {record.getMessage()}"


class JsonFormatter(logging.Formatter):
    def format(self, record: logging.LogRecord) -> str:
        line: dict[str, Any] = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created)) + f".{int(record.msecs):03d}Z",
            "level": record.levelname.lower(),
            "message": record.getMessage(),
        }
        for key in ("stage", "step", "event", "fields"):
            value = getattr(record, key, None)
            if value is not None:
                if key == "fields":
                    line.update(value)
                else:
                    line[key] = value
        return json.dumps(line, default=str)


def setup_logging(fmt: str = "text", verbosity: int = 0) -> logging.Logger:
    """Configure the engine's logger: ``fmt`` text|json, verbosity -1..2."""
    logger = logging.getLogger(LOGGER_NAME)
    logger.handlers.clear()
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(JsonFormatter() if fmt == "json" else TextFormatter())
    logger.addHandler(handler)
    logger.propagate = False
    logger.setLevel({-1: logging.WARNING, 0: logging.INFO}.get(verbosity, logging.DEBUG))
    logger.pipeline_format = fmt  # type: ignore[attr-defined]
    return logger


def stage_logger(stage: str, step: str | None = None) -> logging.LoggerAdapter:
    """The log of *stage*; *step*: where it is in the run (``"5 of 13"``): a JSON line's ``step``."""
    extra = {"stage": stage} if step is None else {"stage": stage, "step": step}
    return logging.LoggerAdapter(logging.getLogger(LOGGER_NAME), extra)


class Progress:
    """Progress of one piece of work: a bar on a terminal, else log lines; *quiet*: neither (work nobody hears)."""

    def __init__(self, total: float, desc: str, stage: str | None, unit: str = "it", *, quiet: bool = False):
        self.total = max(float(total), 0.0)
        self.done = 0.0
        self.desc = desc
        self.unit = unit
        self.log = stage_logger(stage) if stage is not None else None
        self._next_tenth = 1  # the next tenth of the total a line is logged at (whole numbers: no drift)
        self._bar = None
        if quiet or self.log is None:
            self.log = None
            return
        logger = logging.getLogger(LOGGER_NAME)
        console = [h.level for h in logger.handlers if type(h) is logging.StreamHandler]
        interactive = (
            sys.stderr.isatty()
            and getattr(logger, "pipeline_format", "text") == "text"
            and logger.isEnabledFor(logging.INFO)
            and min(console, default=logging.INFO) <= logging.INFO  # -q: no bar, though a run's log takes INFO
        )
        if interactive:
            from tqdm import tqdm  # lazy: ~70 ms to import; pipeline --help imports this module (start-up time)

            total_shown = int(self.total) if float(self.total).is_integer() else self.total
            self._bar = tqdm(total=total_shown, desc=f"{stage}: {desc}", unit=unit, leave=False, file=sys.stderr)

    def update(self, n: float = 1) -> None:
        self.done += n
        if self._bar is not None:
            self._bar.update(n)
        elif self.log is not None and self._next_tenth * self.total <= 10 * self.done < 10 * self.total:
            self.log.info(
                "%s: %d%% (%.0f of %.0f %s)",
                self.desc,
                int(100 * self.done / self.total),
                self.done,
                self.total,
                self.unit,
            )
            while self._next_tenth * self.total <= 10 * self.done:
                self._next_tenth += 1

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


#: The stage whose ``run`` this process is in, for :func:`stage_progress`.
_HOST: ContextVar[str | None] = ContextVar("pipeline_progress_host", default=None)


@contextmanager
def hosting(stage: str | None) -> Iterator[None]:
    """Within it, :func:`stage_progress` reports as *stage* (None: says nothing).

    The runner hosts each stage's ``run``; an executor running several
    tasks one after the other in this process hosts none (it counts the
    tasks as they finish).  Threads and worker processes start without a
    host.
    """
    token = _HOST.set(stage)
    try:
        yield
    finally:
        _HOST.reset(token)


def stage_progress(total: float, desc: str, unit: str = "it") -> Progress:
    """A progress reporter of the stage running in this process, for code without its :class:`~pipeline.stage.StageContext`.

    An executor's task, or a library function under a stage's ``run``: it
    reports as the stage hosting it (:func:`hosting`), so a task run alone
    in its stage's own process (one tile, or work too light for the
    workers) moves the stage's figure; in a worker process (whose log
    lines reach no run log) or among several tasks (counted as they
    finish) it is quiet.
    """
    stage = _HOST.get()
    return Progress(total, desc, stage, unit, quiet=stage is None)


class StageWarnings(logging.Handler):
    """One stage's WARNING and ERROR log lines while it runs: ``with StageWarnings(name) as w: ...; w.lines``."""

    def __init__(self, stage: str):
        super().__init__(logging.WARNING)
        self.stage = stage
        self.lines: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(record, "stage", None) == self.stage:
            self.lines.append(record.getMessage())

    def __enter__(self) -> StageWarnings:
        logging.getLogger(LOGGER_NAME).addHandler(self)
        return self

    def __exit__(self, *exc: object) -> None:
        logging.getLogger(LOGGER_NAME).removeHandler(self)


class RunLog(logging.Handler):
    """Every line of INFO and above of one run, whatever ``-q`` keeps off the console: ``run.log``'s text.

    ``with RunLog() as log: ...; log.text()``.  While it is open the logger
    passes INFO on, and each handler it had is held to the level the logger
    had, so the console shows what it showed.  Lines are kept in memory (a
    run logs a bounded number: progress every tenth of a step) and written
    once, atomically, by the runner.
    """

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.setFormatter(TextFormatter(dated=True))
        self.lines: list[str] = []
        self._saved: list[tuple[logging.Handler, int]] = []
        self._level = logging.NOTSET

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(self.format(record))

    def text(self) -> str:
        return "".join(line + "\n" for line in self.lines)

    def __enter__(self) -> RunLog:
        logger = logging.getLogger(LOGGER_NAME)
        self._level = logger.level
        self._saved = [(h, h.level) for h in logger.handlers]
        for handler, level in self._saved:
            handler.setLevel(max(level, self._level))
        if logger.getEffectiveLevel() > logging.INFO:
            logger.setLevel(logging.INFO)
        logger.addHandler(self)
        return self

    def __exit__(self, *exc: object) -> None:
        logger = logging.getLogger(LOGGER_NAME)
        logger.removeHandler(self)
        logger.setLevel(self._level)
        for handler, level in self._saved:
            handler.setLevel(level)
