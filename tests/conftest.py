"""Shared test helpers.

``need_data``: a test that needs data outside the repository (the ISPRS
samples, real surveys under ``../shared/data``) skips where the data are
missing on a developer's machine, but *fails* when the environment variable
``CI`` is set (as every CI service sets it): a CI run that silently skips its
acceptance tests would report them as passing.

``run_stages``: a run's ``run.json`` stage entries by stage name.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import pytest


def in_ci() -> bool:
    """Whether ``CI`` is set to anything but empty, 0 or false."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


def require_data(*paths: Path, what: str = "test data") -> None:
    """Skip (on a workstation) or fail (under CI) unless every path exists."""
    missing = [str(p) for p in paths if not Path(p).exists()]
    if not missing:
        return
    message = f"{what} not found: {', '.join(missing)} (README.md, Tests)"
    if in_ci():
        pytest.fail(f"CI is set and {message}", pytrace=False)
    pytest.skip(message)


@pytest.fixture
def need_data() -> Callable[..., None]:
    """``need_data(path, ..., what="ISPRS samples")``: see :func:`require_data`."""
    return require_data


def run_stages(out: Path) -> dict[str, dict]:
    """The stage entries of the ``run.json`` in the output folder *out*, by stage name."""
    return {s["name"]: s for s in json.loads((Path(out) / "run.json").read_text())["stages"]}
