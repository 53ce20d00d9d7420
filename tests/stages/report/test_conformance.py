"""Deliverable conformance under the USGS LBS: class 0, the DEM's format and nodata, and how far the check points
can be trusted (too few, bunched, contradicted by the true terrain).  Each rule broken on purpose."""

from __future__ import annotations

import laspy
import numpy as np
import pyproj
import pytest
from affine import Affine

from lidar.rasters import LBS_NODATA, NODATA, dem_nodata, write_cog
from stages.report.acceptance import MIN_CHECKPOINTS, checkpoint_warnings, decks_in_dem, evaluate, truth_disagreement
from stages.report.stage import dem_format
from tests.stages.report.test_report import _check, _dtm, _report, _survey, _text


def _with_class_0(path, n: int, withheld: bool):
    """The survey at *path* with its first *n* points put back in class 0 (withheld or not)."""
    las = laspy.read(str(path))
    cls = np.asarray(las.classification).copy()
    cls[:n] = 0
    las.classification = cls
    flags = np.zeros(len(cls), dtype=bool)
    flags[:n] = withheld
    las.withheld = flags
    las.write(str(path))
    return path


def test_a_point_left_in_class_0_fails_the_lbs(tmp_path):
    las = _with_class_0(_survey(tmp_path), 5, withheld=False)
    page, verdict, *_ = _report(tmp_path, las, _dtm())
    row = _check(verdict, "class_0")
    assert (row["measured"], row["status"]) == (5, "FAIL")
    assert "class 0" in _text(page)


def test_class_0_flagged_withheld_is_allowed(tmp_path):
    """LBS Appendix 1: a withheld point may carry any class, class 0 included."""
    las = _with_class_0(_survey(tmp_path), 5, withheld=True)
    _, verdict, *_ = _report(tmp_path, las, _dtm())
    assert (_check(verdict, "class_0")["measured"], _check(verdict, "class_0")["status"]) == (0, "PASS")


@pytest.mark.parametrize(
    ("bits", "nodata", "status"),
    [(32, LBS_NODATA, "PASS"), (32, NODATA, "FAIL"), (64, LBS_NODATA, "FAIL"), (0, LBS_NODATA, "FAIL")],
)
def test_the_dem_must_be_32_bit_float_with_nodata_minus_999999(bits, nodata, status):
    verdict = evaluate("usgs-lbs-ql2", {"dem_float_bits": bits, "dem_nodata": nodata})
    states = {_check(verdict, "dem_float_bits")["status"], _check(verdict, "dem_nodata")["status"]}
    assert ("FAIL" in states) == (status == "FAIL")


def test_dem_format_is_read_from_the_geotiff_tags(tmp_path):
    path = tmp_path / "dtm.tif"
    write_cog(path, np.full((4, 4), NODATA), transform=Affine(1, 0, 0, 0, -1, 4), crs=pyproj.CRS.from_epsg(25830))
    assert dem_format(path) == (32, NODATA)
    write_cog(
        path,
        np.zeros((4, 4)),
        transform=Affine(1, 0, 0, 0, -1, 4),
        crs=pyproj.CRS.from_epsg(25830),
        dtype="uint8",
        nodata=0,
    )
    assert dem_format(path) == (0, 0.0)


def test_only_lbs_levels_change_the_dem_nodata():
    assert dem_nodata("usgs-lbs-ql1") == dem_nodata("usgs-lbs-ql2") == -999999.0
    assert dem_nodata("asprs-2023-10cm") == dem_nodata("none") == -9999.0


def _grid_points(n: int, side: float) -> tuple[np.ndarray, np.ndarray]:
    cols = int(np.ceil(np.sqrt(n)))
    x, y = np.meshgrid(np.linspace(0.0, side, cols), np.linspace(0.0, side, -(-n // cols)))
    return x.ravel()[:n], y.ravel()[:n]


def test_thirty_check_points_over_the_survey_raise_no_warning():
    x, y = _grid_points(MIN_CHECKPOINTS, 100.0)
    assert checkpoint_warnings(x, y, covered_m2=100.0 * 100.0) == []


def test_fewer_check_points_than_the_asprs_minimum_are_named():
    x, y = _grid_points(MIN_CHECKPOINTS - 1, 100.0)
    (warning,) = checkpoint_warnings(x, y, covered_m2=100.0 * 100.0)
    assert warning.startswith(f"Only {MIN_CHECKPOINTS - 1} check points") and "ASPRS" in warning


def test_check_points_in_one_corner_are_named():
    """30 points spread over 45 m x 45 m of a 100 m x 100 m survey: their hull is 20 % of it."""
    x, y = _grid_points(MIN_CHECKPOINTS, 45.0)
    (warning,) = checkpoint_warnings(x, y, covered_m2=100.0 * 100.0)
    assert "convex hull covers 20 %" in warning


def _nva_verdict(rmse_z_nv: float) -> dict:
    return evaluate("usgs-lbs-ql2", {"rmse_z_nv": rmse_z_nv})


def test_truth_that_fails_where_check_points_pass_is_said():
    """LBS 2024 rev. A's NVA is the RMSEz (limit 0.10 m): the truth's open ground is judged by its RMSE alone."""
    truth = {"file": "terrain.tif", "by_land_cover": {"2": {"name": "ground", "n": 1000, "rmse": 0.7}}}
    sentence = truth_disagreement(_nva_verdict(0.055), truth)
    assert "pass the NVA (0.055 m against 0.1 m)" in sentence
    assert "gives RMSE = 0.700 m on its 1,000 open-ground cells, which fails" in sentence


def test_truth_against_an_edition_1_nva_row_is_scaled_by_1_96():
    """A verdict with an Edition 1 row (nva_95, 1.96 x RMSEz against 0.196 m): the truth's RMSE is scaled alike."""
    verdict = {"checks": [{"measure": "nva_95", "status": "PASS", "measured": 0.055, "limit": 0.196}]}
    truth = {"by_land_cover": {"2": {"name": "ground", "n": 1000, "rmse": 0.7}}}
    assert "gives 1.96 × RMSE = 1.372 m" in truth_disagreement(verdict, truth)
    truth["by_land_cover"]["2"]["rmse"] = 0.09  # 1.96 x 0.09 = 0.176 m <= 0.196 m: both pass
    assert truth_disagreement(verdict, truth) is None


def test_truth_that_agrees_says_nothing():
    truth = {"by_land_cover": {"2": {"name": "ground", "n": 1000, "rmse": 0.05}}}
    assert truth_disagreement(_nva_verdict(0.055), truth) is None
    assert (
        truth_disagreement(_nva_verdict(0.5), {"by_land_cover": {"2": {"name": "ground", "n": 10, "rmse": 0.5}}})
        is None
    )


def test_truth_that_passes_where_check_points_fail_is_said():
    truth = {"file": "t.tif", "by_land_cover": {"2": {"name": "ground", "n": 50, "rmse": 0.05}}}
    assert "fail the NVA" in truth_disagreement(_nva_verdict(0.3), truth)


def test_the_report_lists_the_warnings_beside_the_verdict(tmp_path):
    """Three check points in a corner of the plain survey: both warnings on the page and in acceptance.json."""
    cp = {
        "id": ["1", "2", "3"],
        "land_cover": ["open"] * 3,
        "x": np.array([1001.0, 1005.0, 1001.0]),
        "y": np.array([2001.0, 2001.0, 2005.0]),
        "z": np.full(3, 650.0),
        "dtm": np.full(3, 650.0),
        "error": np.zeros(3),
    }
    page, verdict, *_ = _report(tmp_path, _survey(tmp_path), _dtm(), checkpoints=cp)
    assert len(verdict["warnings"]) == 2
    text = _text(page)
    assert "Only 3 check points lie on the DTM" in text and "convex hull covers 0 %" in text


def _raise_block(path, x0: float, x1: float, y0: float, y1: float, cls: int, dz: float) -> np.ndarray:
    """The survey at *path* with its points in x0 <= x < x1, y0 <= y < y1 (from its corner) *dz* up, class *cls*."""
    las = laspy.read(str(path))
    x, y = np.asarray(las.x) - 1000.0, np.asarray(las.y) - 2000.0
    block = (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
    classes = np.asarray(las.classification).copy()
    classes[block] = cls
    las.classification = classes
    las.z = np.asarray(las.z) + np.where(block, dz, 0.0)
    las.write(str(path))
    return block


def test_classes_per_strip_and_the_class_of_the_highest_point(tmp_path):
    """Three strips of ground; a 10 m x 10 m block of strip 2 raised 5 m and called building (6)."""
    path = _survey(tmp_path, strips=(1, 2, 3))
    roof = _raise_block(path, 25, 35, 25, 35, 6, 5.0)
    page, verdict, data, _ = _report(tmp_path, path, _dtm())
    by_strip = data.cloud.class_by_strip
    assert sorted(by_strip) == [1, 2, 3]
    assert by_strip[2][6] == int(roof.sum()) and by_strip[1][6] == by_strip[3][6] == 0
    assert sum(int(c[2]) for c in by_strip.values()) == int((~roof).sum())
    assert "Per strip (points)" in page and "6 building" in page
    grid = data.cloud.class_grid
    assert (grid == 6).sum() == 100 and set(np.unique(grid)) == {2, 6}  # 1-m cells: the block's 100


def _lake(level: float) -> list:
    """One flattened water body: a 20 m x 20 m square at x 1010-1030, y 2010-2030, at *level* (metres)."""
    ring = np.array([[1010.0, 2010.0], [1030.0, 2010.0], [1030.0, 2030.0], [1010.0, 2030.0], [1010.0, 2010.0]])
    return [([ring], level)]


def test_a_flattened_lake_on_its_level_passes(tmp_path):
    dtm = _dtm()
    dtm[30:50, 10:30] = 650.2  # rows 30-49 are y 2030-2010: the lake's cells at its level
    _, verdict, *_ = _report(tmp_path, _survey(tmp_path), dtm, water_bodies=_lake(650.2))
    assert (_check(verdict, "unflat_water")["measured"], _check(verdict, "unflat_water")["status"]) == (0, "PASS")


def test_a_lake_with_a_tilt_fails(tmp_path):
    """The plain DTM rises 1 cm a metre: a lake left on it spans 20 cm."""
    _, verdict, *_ = _report(tmp_path, _survey(tmp_path), _dtm(), water_bodies=_lake(650.2))
    assert (_check(verdict, "unflat_water")["measured"], _check(verdict, "unflat_water")["status"]) == (1, "FAIL")


def test_without_water_bodies_flatness_is_not_measured(tmp_path):
    _, verdict, *_ = _report(tmp_path, _survey(tmp_path), _dtm())
    row = _check(verdict, "unflat_water")
    assert row["status"] == "NOT MEASURED" and "classify_water" in row["note"]


def _deck_survey(tmp_path):
    """The plain survey with a 6 m x 20 m bridge deck (class 17) 8 m above the ground at x 1020-1026, y 2010-2030."""
    path = _survey(tmp_path)
    _raise_block(path, 20, 26, 10, 30, 17, 8.0)
    return path, (slice(30, 50), slice(20, 26))  # the deck's DTM cells: rows 30-49 are y 2030-2010


def test_a_deck_removed_from_the_dem_passes(tmp_path):
    path, _ = _deck_survey(tmp_path)
    _, verdict, *_ = _report(tmp_path, path, _dtm())  # the DTM runs under the deck, on the ground
    assert (_check(verdict, "decks_in_dem")["measured"], _check(verdict, "decks_in_dem")["status"]) == (0, "PASS")


def test_a_deck_left_in_the_dem_fails(tmp_path):
    path, cells = _deck_survey(tmp_path)
    dtm = _dtm()
    dtm[cells] += 8.0  # the deck taken for ground
    _, verdict, *_ = _report(tmp_path, path, dtm)
    assert (_check(verdict, "decks_in_dem")["measured"], _check(verdict, "decks_in_dem")["status"]) == (1, "FAIL")


def test_without_decks_the_bridges_are_not_measured(tmp_path):
    row = _check(_report(tmp_path, _survey(tmp_path), _dtm())[1], "decks_in_dem")
    assert row["status"] == "NOT MEASURED" and "class 17" in row["note"]


def test_a_sparse_decks_cells_are_one_deck_its_ends_on_the_ground_included():
    """A deck of 20 x 3 cells, every other cell holding a deck point (a sparse survey on a fine grid); its end
    cells meet the ground (the deck's top within 1 m of the DEM there), the rest stand 8 m above it."""
    cls = np.full((30, 9), 2)
    cls[5:25:2, 3:6:2] = 17
    ground = np.full(cls.shape, 10.0)
    top = np.where(cls == 17, 18.0, 10.0)
    top[5, 3:6:2] = top[23, 3:6:2] = 10.5  # the abutments
    assert decks_in_dem(ground, cls, top) == 0  # removed: the ends alone are no deck
    assert decks_in_dem(top - 0.1, cls, top) == 1  # left in the DEM: one deck
