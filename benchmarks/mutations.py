"""Mutation score: do the tests fail when the behaviour they claim breaks? (issue 19)

Each entry of :data:`MUTATIONS` is a small, realistic bug written as data: a
source file, the exact text it replaces, the text that replaces it, and the
tests that should catch it.  The script copies the tree to a scratch folder
(never touching the checkout it runs from), applies one mutation at a time,
runs those tests, fast ones (``-m "not slow"``) and slow ones (``-m slow``)
separately, restores the file, and prints a table::

    python benchmarks/mutations.py                       # this checkout's code and tests
    python benchmarks/mutations.py --tests-from OLD      # this code, the tests of another checkout
    python benchmarks/mutations.py --only buffer --fast-only
    python benchmarks/mutations.py --slow-if-missed      # slow tests only for what the fast ones miss

A mutation whose text is not found exactly once is reported as ``does not
apply`` (the code was rewritten: re-target the entry).  Test files that do
not exist in the tree are left out (so older checkouts can be scored too).
The tree's parent gets a ``shared`` link to this checkout's ``../shared``,
so the data-dependent tests find their data as they do here.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from tests.shared_data import SHARED  # noqa: E402


@dataclass(frozen=True)
class Mutation:
    name: str
    file: str
    old: str
    new: str
    tests: tuple[str, ...]


TILED = "tests/end_to_end/test_tiled_runs.py"
BUFFERS = "tests/stages/classify_ground/test_tile_buffers.py"
SMRF_REACH = "tests/stages/classify_ground/test_smrf_reach.py"

MUTATIONS: list[Mutation] = [
    Mutation(
        "euler_quat multiplies in the order roll, pitch, yaw",
        "lidar/rotation.py",
        "return quat_mul(quat_mul(_axis_quat(2, yaw), _axis_quat(1, pitch)), _axis_quat(0, roll))",
        "return quat_mul(quat_mul(_axis_quat(0, roll), _axis_quat(1, pitch)), _axis_quat(2, yaw))",
        ("tests/stages/georeference/test_simulate_georef.py",),
    ),
    Mutation(
        "SMRF tile buffer 74 m (the first pass's reach) instead of 146 m",
        "stages/classify_ground/ground_classes.py",
        "return 8.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size",
        "return 4.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size",
        (SMRF_REACH, BUFFERS, TILED),
    ),
    Mutation(
        "SMRF tile buffer 38 m instead of 146 m",
        "stages/classify_ground/ground_classes.py",
        "return 8.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size",
        "return 2.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size",
        (SMRF_REACH, BUFFERS, TILED),
    ),
    Mutation(
        "SMRF tile buffer 20 m instead of 146 m",
        "stages/classify_ground/ground_classes.py",
        "return 8.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size",
        "return 1.0 * algorithm.max_window_size + 2.0 * algorithm.cell_size",
        (SMRF_REACH, BUFFERS, TILED),
    ),
    Mutation(
        "raster tile buffer 12 m instead of 102 m",
        "stages/rasterize/tile_rasters.py",
        "return far * params.nodata_distance + 2.0 * params.resolution",
        "return 10.0 + 2.0 * params.resolution",
        (BUFFERS, TILED),
    ),
    Mutation(
        "denoise tile buffer 6 m instead of 61 m",
        "stages/denoise/noise_classes.py",
        "return max(2.0 * params.isolated.radius, params.low.cell_size) + 1.0",
        "return 6.0",
        (BUFFERS, TILED),
    ),
    Mutation(
        "ClassifyGround.config_keys = () (the tiling buffer leaves the cache key)",
        "stages/classify_ground/stage.py",
        'config_keys = ("tiling.buffer",)',
        "config_keys = ()",
        (BUFFERS,),
    ),
    Mutation(
        "max_gap_s ignored: pulses interpolated across trajectory gaps",
        "lidar/georeferencing.py",
        "ok = (t >= tt[0]) & (t <= tt[-1]) & ((dt <= max_gap_s) | (f == 0.0) | (f == 1.0))",
        "ok = (t >= tt[0]) & (t <= tt[-1])",
        ("tests/stages/georeference/test_trajectory_gaps.py", "tests/lidar/test_georef_math.py"),
    ),
    Mutation(
        "DSM from noise-class points too",
        "stages/rasterize/tile_rasters.py",
        'masks.append((cls == glossary.GROUND, glossary.usable(cls, np.load(part / "withheld.npy"))))',
        'masks.append((cls == glossary.GROUND, ~np.load(part / "withheld.npy")))',
        ("tests/stages/denoise/test_noise_classes.py", "tests/stages/test_products_units.py"),
    ),
    Mutation(
        "low-outlier test flags only the lowest point of a cell",
        "stages/denoise/outliers.py",
        "outlier_sorted = (small_so_far - before) == 0",
        "outlier_sorted = ((small_so_far - before) == 0) & start",
        ("tests/stages/denoise/test_noise_classes.py", "tests/stages/classify_ground/test_ground.py"),
    ),
    Mutation(
        "isolated-point threshold halved (5 local spacings instead of 10)",
        "stages/denoise/outliers.py",
        "out[cand] = far > np.maximum(multiplier * spacing, min_distance)",
        "out[cand] = far > np.maximum(multiplier / 2 * spacing, min_distance)",
        ("tests/stages/denoise/test_noise_classes.py", "tests/stages/classify_ground/test_ground.py"),
    ),
    Mutation(
        "PMF within-cell slope allowance 0",
        "stages/classify_ground/pmf.py",
        "within_cell = slope * cell_size",
        "within_cell = 0.0",
        ("tests/stages/classify_ground/test_pmf.py", "tests/stages/classify_ground/test_ground_known_answers.py"),
    ),
    Mutation(
        "strip datum most_overlap takes the least-overlapping strip",
        "stages/strip_adjust/rigid.py",
        "max(linked, key=lambda s: overlap[s]) if linked else None",
        "min(linked, key=lambda s: overlap[s]) if linked else None",
        (
            "tests/stages/strip_adjust/test_strip_datum.py",
            "tests/stages/strip_adjust/test_strip_adjust.py",
            "tests/stages/strip_adjust/test_strip_adjust_no_error.py",
        ),
    ),
    Mutation(
        "uncertainty: attitude Jacobian ignores the lever arm",
        "stages/georeference/uncertainty.py",
        "add(sig.attitude_rad[j], _rot(body, _cross(unit[j], v_b)))",
        "add(sig.attitude_rad[j], _rot(body, _cross(unit[j], vb_s)))",
        ("tests/stages/georeference/test_uncertainty_monte_carlo.py", "tests/stages/georeference/test_uncertainty.py"),
    ),
    Mutation(
        "uncertainty: position sigmas E/N/U taken as U/N/E",
        "stages/georeference/uncertainty.py",
        "var[j] += np.square(sig.position_enu_m[j])",
        "var[j] += np.square(sig.position_enu_m[2 - j])",
        ("tests/stages/georeference/test_uncertainty_monte_carlo.py", "tests/stages/georeference/test_uncertainty.py"),
    ),
    Mutation(
        "SMRF threshold does not grow with the window (s c instead of s r c)",
        "stages/classify_ground/smrf.py",
        "flagged = (previous - opened) > slope * radius * cell_size",
        "flagged = (previous - opened) > slope * cell_size",
        (
            "tests/stages/classify_ground/test_ground_known_answers.py",
            "tests/stages/classify_ground/test_ground.py",
            "tests/commands/test_evaluate_ground.py",
            "tests/commands/test_evaluate_ground_isprs.py",
        ),
    ),
    Mutation(
        "SMRF window radius halved (w_max read as a diameter)",
        "stages/classify_ground/smrf.py",
        "max_radius = max(1, int(math.ceil(max_window_size / cell_size)))",
        "max_radius = max(1, int(math.ceil(max_window_size / (2 * cell_size))))",
        (
            "tests/stages/classify_ground/test_ground_known_answers.py",
            "tests/stages/classify_ground/test_ground.py",
            "tests/commands/test_evaluate_ground.py",
            "tests/commands/test_evaluate_ground_isprs.py",
        ),
    ),
    Mutation(
        "inpainting: an unknown cell averages three of its four neighbours",
        "stages/classify_ground/surface.py",
        "for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):",
        "for dr, dc in ((0, 1), (0, -1), (1, 0)):",
        (
            "tests/stages/classify_ground/test_ground_known_answers.py",
            "tests/stages/classify_ground/test_ground.py",
            "tests/commands/test_evaluate_ground.py",
            "tests/commands/test_evaluate_ground_isprs.py",
        ),
    ),
    Mutation(
        "inpainting: edge cells divided by four neighbours (zero outside the grid)",
        "stages/classify_ground/surface.py",
        "diag[me] += 1.0",
        "diag[me] = 4.0",
        (
            "tests/stages/classify_ground/test_ground_known_answers.py",
            "tests/stages/classify_ground/test_ground.py",
            "tests/commands/test_evaluate_ground.py",
            "tests/commands/test_evaluate_ground_isprs.py",
        ),
    ),
    Mutation(
        "DTM check: reference minus run (a false hill reads as a hole)",
        "commands/evaluate/scores.py",
        "d = (evaluated[both] - reference[both])",
        "d = (reference[both] - evaluated[both])",
        ("tests/commands/test_dtm_check.py",),
    ),
    Mutation(
        "DTM check: the reference's voids compared (no triangle-edge limit)",
        "commands/evaluate/scores.py",
        "dense = defined & ~_in_long_triangles(vxy, grid, max_edge)",
        "dense = defined",
        ("tests/commands/test_dtm_check.py",),
    ),
    Mutation(
        "DTM check in the CRS's units (feet) instead of metres",
        "commands/evaluate/command.py",
        "xyz = cloud_info(classified).units.to_metres(",
        "xyz = (",
        ("tests/commands/test_dtm_check.py",),
    ),
    Mutation(
        "truth raster resampled by nearest cell instead of bilinear",
        "stages/accuracy/vertical.py",
        "_onto(truth_path, dtm.shape, transform, crs, Resampling.bilinear)",
        "_onto(truth_path, dtm.shape, transform, crs, Resampling.nearest)",
        ("tests/stages/accuracy/test_truth_accuracy.py",),
    ),
    Mutation(
        "truth raster: cells more than 5 m below the truth not counted",
        "stages/accuracy/vertical.py",
        '"off_5m": float(np.mean(np.abs(e) > TRUTH_OFF_M[1]))',
        '"off_5m": float(np.mean(e > TRUTH_OFF_M[1]))',
        ("tests/stages/accuracy/test_truth_accuracy.py",),
    ),
    Mutation(
        "boresight inverted: scanner-from-body instead of body-from-scanner",
        "stages/parse/intermediates.py",
        '"rotation": euler_matrix(*np.radians(p.boresight_deg)).tolist(),',
        '"rotation": euler_matrix(*np.radians(p.boresight_deg)).T.tolist(),',
        ("tests/stages/parse/test_boresight.py",),
    ),
    Mutation(
        "map transform in the CRS's authority axis order (northing first swapped)",
        "lidar/geodesy.py",
        'self._exact = pyproj.Transformer.from_crs("EPSG:4978", crs, always_xy=True)',
        'self._exact = pyproj.Transformer.from_crs("EPSG:4978", crs)',
        ("tests/lidar/test_axis_order.py",),
    ),
    Mutation(
        "smrmsg attitude sigmas taken in degrees instead of arc-minutes",
        "stages/parse/read_ins.py",
        """"sigma_roll_deg": r[:, 7] / 60.0,
        "sigma_pitch_deg": r[:, 8] / 60.0,
        "sigma_heading_deg": r[:, 9] / 60.0,""",
        """"sigma_roll_deg": r[:, 7],
        "sigma_pitch_deg": r[:, 8],
        "sigma_heading_deg": r[:, 9],""",
        ("tests/stages/parse/test_smrmsg_sigmas.py",),
    ),
    Mutation(
        "LAS reprojection in the CRS's authority axis order (northing first swapped)",
        "stages/parse/read_las.py",
        "transformer = pyproj.Transformer.from_crs(src_crs, target, always_xy=True)",
        "transformer = pyproj.Transformer.from_crs(src_crs, target)",
        ("tests/lidar/test_axis_order.py", "tests/stages/parse/test_read_las.py"),
    ),
    Mutation(
        "LAS header bounds reprojected in the CRS's authority axis order",
        "stages/parse/read_las.py",
        "t = pyproj.Transformer.from_crs(crs, target, always_xy=True)",
        "t = pyproj.Transformer.from_crs(crs, target)",
        ("tests/lidar/test_axis_order.py", "tests/stages/parse/test_read_las.py"),
    ),
    Mutation(
        "strip datum: the reference strip held even when control points are given",
        "stages/strip_adjust/stage.py",
        """        if control is not None and len(control):
            reference = None
""",
        "",
        ("tests/stages/strip_adjust/test_control_datum.py", "tests/stages/strip_adjust/test_strip_adjust.py"),
    ),
    Mutation(
        "calibration: every patch slope counts, however level (issue 37)",
        "stages/strip_adjust/mounting.py",
        "seen = np.where((t2 >= LEVEL_T2)[:, None], slope, 0.0)",
        "seen = slope",
        ("tests/stages/strip_adjust/test_mounting_flat.py",),
    ),
    Mutation(
        "calibration: a held unknown's error not carried into the others (issue 37)",
        "stages/strip_adjust/mounting.py",
        "    sd_full[applied] = np.sqrt(np.maximum(sd_full[applied] ** 2, geometric) + added)",
        "    sd_full[applied] = np.sqrt(np.maximum(sd_full[applied] ** 2, geometric))",
        ("tests/stages/strip_adjust/test_mounting_flat.py",),
    ),
]


def _copy_tree(code: Path, tests: Path, dest: Path) -> None:
    ignore = shutil.ignore_patterns(".git", ".venv", "out", ".cache", "__pycache__", "*.pyc", ".pytest_cache")
    if dest.exists():
        shutil.rmtree(dest)
    shutil.copytree(code, dest, ignore=ignore, symlinks=True)
    if tests != code:
        shutil.rmtree(dest / "tests")
        shutil.copytree(tests / "tests", dest / "tests", ignore=ignore)


def _pytest(tree: Path, tests: list[str], marker: str, timeout: float) -> str:
    """'yes' (a test failed: caught), 'no' (all passed), '-' (no such test), 'error ...' otherwise."""
    if not tests:
        return "-"
    # the copy has no ../shared beside it: the tests read the data through SHARED_DIR (tests/shared_data.py)
    env = {**os.environ, "PYTHONPATH": str(tree), "PYTHONDONTWRITEBYTECODE": "1", "SHARED_DIR": str(SHARED)}
    cmd = [sys.executable, "-m", "pytest", "-x", "-q", "-p", "no:cacheprovider", "-m", marker, *tests]
    try:
        run = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return "timeout"
    return {0: "no", 1: "yes", 5: "-"}.get(run.returncode, f"error {run.returncode}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tree", type=Path, default=ROOT, help="checkout whose code is mutated (default: this one)")
    ap.add_argument("--tests-from", type=Path, default=None, help="checkout whose tests/ are run (default: --tree)")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp") / f"mutations-{os.getpid()}")
    ap.add_argument("--only", default=None, help="only mutations whose name contains this text")
    ap.add_argument("--fast-only", action="store_true", help="skip the slow tests")
    ap.add_argument("--slow-if-missed", action="store_true", help="run the slow tests only when the fast ones miss")
    ap.add_argument("--timeout", type=float, default=900.0, help="seconds per pytest run")
    args = ap.parse_args(argv)
    tree = args.workdir / "tree"
    _copy_tree(args.tree.resolve(), (args.tests_from or args.tree).resolve(), tree)
    chosen = [m for m in MUTATIONS if args.only is None or args.only.lower() in m.name.lower()]
    rows = []
    for m in chosen:
        path = tree / m.file
        text = path.read_text()
        tests = [t for t in m.tests if (tree / t).exists()]
        if text.count(m.old) != 1:
            rows.append((m.name, m.file, "does not apply", "", 0.0))
            continue
        start = time.monotonic()
        path.write_text(text.replace(m.old, m.new))
        try:
            fast = _pytest(tree, tests, "not slow", args.timeout)
            if args.fast_only or (args.slow_if_missed and fast == "yes"):
                slow = "(not run)"
            else:
                slow = _pytest(tree, tests, "slow", args.timeout)
        finally:
            path.write_text(text)
        rows.append((m.name, m.file, fast, slow, time.monotonic() - start))
        print(f"  {m.name}: fast {fast}, slow {slow} ({rows[-1][4]:.0f} s)", file=sys.stderr, flush=True)
    width = max(len(r[0]) for r in rows) if rows else 10
    print(f"{'mutation':<{width}}  {'file':<30} {'caught by fast tests?':<22} caught by slow tests?")
    for name, file, fast, slow, _ in rows:
        print(f"{name:<{width}}  {file:<30} {fast:<22} {slow}")
    applied = [r for r in rows if r[2] != "does not apply"]
    fast_n = sum(r[2] == "yes" for r in applied)
    any_n = sum(r[2] == "yes" or r[3] == "yes" for r in applied)
    print(f"\n{len(applied)} mutations applied: {any_n} caught ({fast_n} by the fast tests alone)")
    shutil.rmtree(args.workdir, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
