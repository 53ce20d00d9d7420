"""Exceptions of the engine and the exit codes they map to.

Every error a user can cause is a :class:`PipelineError` carrying one sentence
that names the file, the line or record, and the field.  The command line maps
them to the documented exit codes and never prints a traceback for them.
:data:`FULL` and :data:`UNWRITABLE` are the ``errno`` values of the disk
failures reported as an :class:`EnvironmentFailure` (exit code 4).
"""

from __future__ import annotations

import errno

EXIT_OK = 0
EXIT_INTERNAL = 1
EXIT_USAGE = 2
EXIT_INPUT = 3
EXIT_ENVIRONMENT = 4
#: The run finished and published its products, but a stage's checks failed (``pipeline run --strict``).
EXIT_CHECKS_FAILED = 5

#: errno values of a disk that is full (or a quota that is used up).
FULL = frozenset({errno.ENOSPC, errno.EDQUOT})
#: errno values of a folder that cannot be written (a read-only mount, permissions).
UNWRITABLE = frozenset({errno.EACCES, errno.EPERM, errno.EROFS})


class PipelineError(Exception):
    """Root of every error the engine reports without a traceback."""

    exit_code: int = EXIT_INTERNAL


class ConfigError(PipelineError):
    """The configuration or the command line is wrong (exit code 2)."""

    exit_code = EXIT_USAGE


class InputDataError(PipelineError):
    """An input file is malformed or cannot be used (exit code 3)."""

    exit_code = EXIT_INPUT


class PlanError(ConfigError):
    """The enabled stages do not form a runnable graph (exit code 2)."""


class EnvironmentFailure(PipelineError):
    """The machine cannot carry out the run (exit code 4).

    A full disk, a cache or output folder that cannot be written, a worker
    process killed, a scheduler that does not answer: nothing is wrong with
    the configuration or the data, and running again once the cause is
    fixed resumes (complete stages are reused).  The sentence names the
    folder or the stage and says which side (cache or output) it concerns.
    """

    exit_code = EXIT_ENVIRONMENT
