"""Shared test helpers.

``need_data``: a test that needs data outside the repository (the ISPRS
samples, real surveys under ``../shared/data``: ``tests/shared_data.py``) skips where the data are
missing on a developer's machine, but *fails* when the environment variable
``CI`` is set (as every CI service sets it): a CI run that silently skips its
acceptance tests would report them as passing.

``run_stages``: a run's ``run.json`` stage entries by stage name.

``run_until``: ``pipeline run CONFIG --until STAGE`` into a folder, its stage entries.

``constant_geoid``: a GeoTIFF geoid grid of one separation.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import rasterio
from rasterio.transform import from_origin

from pipeline.cli import main


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


def constant_geoid(grid: Path, separation: float) -> Path:
    """A GeoTIFF geoid grid of one separation (metres) over 40-41 N, 4-3 W (the samples' area)."""
    with rasterio.open(
        grid,
        "w",
        driver="GTiff",
        width=20,
        height=20,
        count=1,
        dtype="float32",
        crs="EPSG:4326",
        transform=from_origin(-4.0, 41.0, 0.05, 0.05),
    ) as ds:
        ds.write(np.full((1, 20, 20), separation, np.float32))
    return grid


def run_until(config: Path, until: str, out: Path, *sets: str, cache: Path | None = None) -> dict[str, dict]:
    """Run *config* up to the stage *until* into *out* (cache: *cache* or ``out/cache``), with ``--set`` *sets*.

    Returns the run's stage entries by name (:func:`run_stages`); a run that fails fails the test.
    """
    args = ["run", str(config), "-q", "--until", until, "--set", f"output={out}"]
    args += ["--set", f"cache={cache or Path(out) / 'cache'}"]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return run_stages(out)


#: The test files that take longest in the whole suite (``--durations``, 2026-12-04), longest first; the
#: fast suite's long files are among them.  ``scripts/test.sh`` runs whole files on each core (``--dist
#: loadfile --no-loadscope-reorder``) in collection order; starting these first lets both cores finish
#: together instead of one waiting on a long file drawn last.  Only the order changes: a file missing here
#: runs after them, one renamed only costs balance.
LONGEST_FIRST = (
    "tests/end_to_end/test_crash_safety.py",
    "tests/stages/strip_adjust/test_mounting_flat.py",
    "tests/stages/strip_adjust/test_mounting.py",
    "tests/stages/parse/test_fuzz_las_damage.py",
    "tests/commands/test_evaluate_ground_isprs.py",
    "tests/stages/strip_adjust/test_strip_adjust.py",
    "tests/end_to_end/test_tiled_runs.py",
    "tests/end_to_end/test_dask_cluster.py",
    "tests/end_to_end/test_incremental.py",
    "tests/stages/parse/test_real_files.py",
    "tests/stages/strip_adjust/test_strip_adjust_no_error.py",
    "tests/stages/parse/test_real_las_metadata.py",
    "tests/stages/georeference/test_simulate_georef.py",
    "tests/stages/report/test_report.py",
    "tests/end_to_end/test_las_to_dtm.py",
    "tests/stages/export_tiles/test_deliverables.py",
    "tests/stages/classify_ground/test_smrf_one_grid.py",
    "tests/pipeline/test_executor_faults.py",
    "tests/end_to_end/test_feet_crs.py",
    "tests/stages/georeference/test_uncertainty.py",
    "tests/lidar/test_split_cloud.py",
    "tests/stages/classify_ground/test_tile_buffers.py",
    "tests/stages/parse/test_fuzz_inputs.py",
    "tests/pipeline/test_tiling.py",
    "tests/stages/accuracy/test_truth_accuracy.py",
    "tests/stages/parse/test_shipped_samples.py",
)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Put the files of :data:`LONGEST_FIRST` first, in its order; the rest keep theirs."""
    rank = {name: k for k, name in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(item.nodeid.split("::")[0], len(rank)))


#: Modules the doctest collection must not import: importing ``lowest_filter`` registers a ground filter, which
#: must exist only while its tests run (others render the configuration reference).
collect_ignore = ["stages/classify_ground/lowest_filter.py"]
