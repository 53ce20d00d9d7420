"""The DTM check of ``pipeline evaluate ground``: the run's ground DTM against the reference ground's.

Known answers from geometry: ground points on the cell centres make each
TIN cell take its own point's height exactly, so a patch of points raised
by a known height gives a known number of cells, RMS and mean.  On real
data (Megaplot), the figures are checked against an independent TIN
(SciPy's Qhull linear interpolation) of the same classes.
"""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from scipy.interpolate import LinearNDInterpolator
from scipy.spatial import cKDTree

from commands.evaluate.command import evaluate_ground
from commands.evaluate.scores import dtm_check
from lidar.grid import Grid
from pipeline.cli import main
from tests.shared_data import REAL as SHARED_REAL

ROOT = Path(__file__).resolve().parents[2]
MEGAPLOT = SHARED_REAL / "lidR" / "Megaplot.laz"


def _lattice(side: int = 60) -> np.ndarray:
    """Points at the centres of 1 m cells, on the plane z = 100 + 0.05 x (an exact TIN: no interpolation)."""
    x, y = np.meshgrid(np.arange(side) + 0.5, np.arange(side) + 0.5)
    x, y = x.ravel(), y.ravel()
    return np.column_stack((x, y, 100.0 + 0.05 * x))


def _patch(xyz: np.ndarray, x0: float, y0: float, size: int) -> np.ndarray:
    return (xyz[:, 0] > x0) & (xyz[:, 0] < x0 + size) & (xyz[:, 1] > y0) & (xyz[:, 1] < y0 + size)


def test_one_point_raised_in_a_lattice_lifts_its_neighbour_cells_by_half():
    """Ground on a 1 m lattice, z = 0; the classification takes, instead of the point at (5, 5), one 1 m above
    it.  The cell centres nearest to it lie halfway along the triangles' edges from it: 0.5 m above."""
    xy = np.mgrid[0:11, 0:11].reshape(2, -1).T.astype(float)
    xyz = np.vstack((np.column_stack((xy, np.zeros(121))), [[5.0, 5.0, 1.0]]))
    reference = np.arange(122) < 121
    predicted = np.arange(122) != 60  # xy[60] is (5, 5)
    c = dtm_check(xyz, reference, predicted)
    assert (c.n, c.max_above, c.above_0_5) == (100, 0.5, 0.0)


def test_raised_and_lowered_patches_give_their_cells_and_rms():
    ground = _lattice()
    up, low, down = _patch(ground, 10, 10, 10), _patch(ground, 10, 40, 6), _patch(ground, 40, 30, 5)
    kept = ground.copy()
    kept[up, 2] += 3.0  # 100 cells: canopy left as ground, 3 m above the terrain
    kept[low, 2] += 1.0  # 36 cells: shrubs, 1 m up
    kept[down, 2] -= 1.0  # 25 cells: low noise left as ground
    changed = up | low | down
    xyz = np.vstack((ground, kept[changed]))
    reference = np.arange(len(xyz)) < len(ground)
    predicted = np.concatenate((~changed, np.ones(changed.sum(), bool)))
    c = dtm_check(xyz, reference, predicted)
    n = 3600
    assert (c.n, c.reference_cells, c.sparse_cells, c.missing_cells) == (n, n, 0, 0)
    assert c.above_2 == pytest.approx(100 / n) and c.above_0_5 == pytest.approx(136 / n)
    assert c.below_0_5 == pytest.approx(25 / n)
    assert c.rms == pytest.approx(np.sqrt((100 * 9 + 36 + 25) / n))
    assert c.mean == pytest.approx((300 + 36 - 25) / n)
    assert (c.max_above, c.max_below) == pytest.approx((3.0, -1.0))
    # the same ground everywhere: every figure zero
    same = dtm_check(ground, np.ones(n, bool), np.ones(n, bool))
    assert (same.rms, same.above_0_5, same.max_above, same.max_below) == (0.0, 0.0, 0.0, 0.0)


def test_cells_where_the_reference_has_no_ground_are_left_out():
    """A 26 m hole in the reference ground: no triangle of edges <= 20 m covers a point 11.6 m from every vertex.

    (A point inside a triangle sees its vertices under angles summing to 360 degrees, so one is at least
    120 degrees; its opposite edge is then at least sqrt(3) times the point's distance to the vertices.)
    """
    ground = _lattice()
    hole = _patch(ground, 17, 17, 26)  # 26 x 26 cells without reference ground
    xyz = np.vstack((ground[~hole], ground[hole] + [0.0, 0.0, 2.5]))  # the run finds ground there, 2.5 m up
    reference = np.arange(len(xyz)) < (~hole).sum()
    predicted = np.ones(len(xyz), bool)
    c = dtm_check(xyz, reference, predicted)
    far = cKDTree(ground[~hole, :2]).query(ground[hole, :2])[0] > 20.0 / np.sqrt(3.0)
    assert far.sum() <= c.sparse_cells <= hole.sum() + 28 * 28 - 26 * 26  # the hole, its rim's points at most
    assert c.n == 3600 - c.sparse_cells
    # the hole's compared cells are 2.5 m up (its edge cells are vertices: in a long triangle or not)
    assert hole.sum() - c.sparse_cells <= round(c.above_2 * c.n) <= hole.sum() - far.sum()
    every = dtm_check(xyz, reference, predicted, max_edge=np.inf)
    assert every.sparse_cells == 0 and every.max_above == pytest.approx(2.5)


def _write_lattice(path: Path, xyz: np.ndarray, classes: np.ndarray, *, feet: bool = False) -> Path:
    """A LAS in UTM 30N, or (*feet*) in Oregon Lambert, international feet (EPSG:2994), x, y and z in feet."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001] * 3)
    origin = np.array([636000.0, 849000.0, 0.0]) if feet else np.array([500000.0, 4000000.0, 0.0])
    header.offsets = origin
    header.add_crs(pyproj.CRS.from_epsg(2994 if feet else 32630))
    las = laspy.LasData(header)
    xyz = origin + (xyz / 0.3048 if feet else xyz)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.classification = classes.astype(np.uint8)
    las.write(str(path))
    return path


def test_evaluate_ground_reports_a_platform_kept_as_ground(tmp_path, capsys):
    """A 1 m platform the reference calls an object, kept as ground with a 2 m threshold: 100 cells 1 m up."""
    xyz = _lattice()
    platform = _patch(xyz, 25, 25, 10)
    xyz[platform, 2] += 1.0
    ref = _write_lattice(tmp_path / "ref.laz", xyz, np.where(platform, 1, 2))
    args = ["evaluate", "ground", str(ref), "--param", "elevation_threshold=2.0", "--json"]
    assert main(args) == 0
    row = json.loads(capsys.readouterr().out)[0]
    assert row["object_as_ground"] == 100 and row["ground_as_object"] == 0
    c = row["dtm_check"]
    n = 3600
    assert (c["n"], c["sparse_cells"], c["missing_cells"], c["cell"], c["max_edge"]) == (n, 0, 0, 1.0, 20.0)
    assert c["above_0_5"] == pytest.approx(100 / n) and c["above_2"] == 0.0 and c["below_0_5"] == 0.0
    assert c["rms"] == pytest.approx(np.sqrt(100 / n), abs=1e-4)
    assert c["max_above"] == pytest.approx(1.0, abs=1e-3)
    # the table, and the option's checks
    assert main(["evaluate", "ground", str(ref), "--param", "elevation_threshold=2.0", "--dtm-cell", "2"]) == 0
    text = capsys.readouterr().out
    assert "DTM check" in text and "2 m cells" in text
    assert main(["evaluate", "ground", str(ref), "--no-dtm-check", "--json"]) == 0
    assert "dtm_check" not in json.loads(capsys.readouterr().out)[0]
    assert main(["evaluate", "ground", str(ref), "--dtm-max-edge", "0"]) == 2
    assert "--dtm-max-edge 0: must be a positive number of metres (or inf)." in capsys.readouterr().err
    assert main(["evaluate", "ground", str(ref), "--dtm-cell", "nan"]) == 2
    classes = np.full(3600, 1)
    classes[:2] = 2
    two = _write_lattice(tmp_path / "two.laz", xyz, classes)
    assert main(["evaluate", "ground", str(two)]) == 3
    assert "2 point(s) of class 2: the DTM check needs at least 3" in capsys.readouterr().err


def test_a_survey_in_feet_is_checked_in_metres(tmp_path, capsys):
    """The same platform in a feet CRS: 1 m cells, a 1 m (3.28 ft) platform is 1 m up."""
    xyz = _lattice()
    xyz[:, :2] += [0.2, 0.8]  # on the centres of 1 m cells once the origin (636000, 849000 ft) is in metres
    platform = _patch(xyz, 25.2, 25.8, 10)
    xyz[platform, 2] += 1.0
    ref = _write_lattice(tmp_path / "ft.laz", xyz, np.where(platform, 1, 2), feet=True)
    assert main(["evaluate", "ground", str(ref), "--param", "elevation_threshold=2.0", "--json"]) == 0
    c = json.loads(capsys.readouterr().out)[0]["dtm_check"]
    # in feet it would be 38,750 cells and 3.28 up; the edge cells' centres are on the hull, or a
    # 0.1 mm rounding of the feet coordinates outside it
    assert 3400 <= c["n"] <= 3600
    assert c["above_0_5"] * c["n"] == pytest.approx(100, abs=0.5)
    assert c["max_above"] == pytest.approx(1.0, abs=2e-3)


@pytest.mark.slow
def test_megaplot_figures_match_an_independent_tin(need_data):
    """Real forest: the check's figures are those of SciPy's Qhull TINs of the same classes (any filter)."""
    need_data(MEGAPLOT, what="lidR's Megaplot.laz")
    rows, classes = evaluate_ground(MEGAPLOT, dtm_max_edge=np.inf)
    las = laspy.read(str(MEGAPLOT))
    xyz = np.column_stack((las.x, las.y, las.z))
    reference, predicted = np.asarray(las.classification) == 2, classes["smrf"] == 2
    grid = Grid.covering(*xyz[:, :2].min(axis=0), *xyz[:, :2].max(axis=0), 1.0)
    gx, gy = grid.centres()
    ref = LinearNDInterpolator(xyz[reference, :2], xyz[reference, 2])(gx, gy)
    run = LinearNDInterpolator(xyz[predicted, :2], xyz[predicted, 2])(gx, gy)
    d = (run - ref)[np.isfinite(run) & np.isfinite(ref)]
    c = rows[0]["dtm_check"]
    assert c["n"] == pytest.approx(d.size, rel=0.002)
    assert c["rms"] == pytest.approx(np.sqrt(np.mean(d**2)), abs=0.02)
    assert c["mean"] == pytest.approx(d.mean(), abs=0.02)
    assert c["above_2"] == pytest.approx(np.mean(d > 2.0), abs=0.003)
    assert c["above_0_5"] == pytest.approx(np.mean(d > 0.5), abs=0.003)
    assert c["max_above"] == pytest.approx(d.max(), abs=0.05)
