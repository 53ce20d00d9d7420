"""``accuracy`` against a truth raster: known answers from rasters with known offsets.

A flat truth makes GDAL's bilinear resampling exact everywhere (any weighted
mean of one height is that height), so the offsets written into the DTM are
the errors; a sloped truth checks that the resampling is bilinear from cell
centres (nearest would be off by slope x a quarter cell).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pyproj
import pytest
from affine import Affine

from lidar.rasters import write_cog
from pipeline.cli import main
from pipeline.errors import InputDataError
from stages.accuracy.stage import Accuracy, AccuracyParams
from stages.accuracy.vertical import land_cover_on_dtm_cells, truth_accuracy, truth_on_dtm_cells
from stages.report.sections import accuracy_section

ROOT = Path(__file__).resolve().parents[3]
CRS = pyproj.CRS.from_epsg(32630)
X0, Y1 = 440000.0, 4470000.0


def _rasters(tmp_path: Path, slope: float = 0.0) -> tuple[Path, Path, np.ndarray]:
    """A truth of 1 m cells over 60 m x 40 m, and a 0.5 m DTM over its west 50 m x 30 m + 3 m beyond its east edge."""
    tx, ty = np.meshgrid(np.arange(60) + 0.5, np.arange(40) + 0.5)
    truth = 100.0 + slope * tx
    write_cog(tmp_path / "truth.tif", truth.astype(np.float32), transform=Affine(1.0, 0.0, X0, 0.0, -1.0, Y1), crs=CRS)
    # DTM from x = 10 m to 63 m (the truth ends at 60 m), y = 5 m to 35 m below the top
    dx, _ = np.meshgrid(10.0 + (np.arange(106) + 0.5) * 0.5, np.arange(60))
    dtm = 100.0 + slope * dx
    return tmp_path / "truth.tif", tmp_path / "dtm.tif", dtm


def _write_dtm(path: Path, dtm: np.ndarray) -> None:
    write_cog(path, dtm.astype(np.float32), transform=Affine(0.5, 0.0, X0 + 10.0, 0.0, -0.5, Y1 - 5.0), crs=CRS)


def test_known_offsets_give_known_cells_rms_and_extremes(tmp_path):
    truth, path, dtm = _rasters(tmp_path)
    dtm[10:20, 10:20] += 2.0  # 100 cells 2 m above: a building left as ground
    dtm[30:34, 40:45] -= 6.0  # 20 cells 6 m below
    dtm[50:55, 0:6] = np.nan  # 30 cells without a value (nodata)
    _write_dtm(path, dtm)
    r = truth_accuracy(*truth_on_dtm_cells(path, truth))
    beyond = 6 * 60  # the 6 columns whose centres lie east of the truth's edge (60.25 ... 62.75 m)
    cells = 106 * 60 - 30
    n = cells - beyond
    assert (r["cells"], r["no_truth"], r["n"]) == (cells, beyond, n)
    assert r["off_1m"] == pytest.approx(120 / n) and r["off_5m"] == pytest.approx(20 / n)
    assert r["rmse"] == pytest.approx(np.sqrt((100 * 4 + 20 * 36) / n), rel=1e-6)
    assert r["mean"] == pytest.approx((200 - 120) / n, rel=1e-6)
    assert (r["max_above"], r["max_below"], r["max_abs"]) == pytest.approx((2.0, -6.0, 6.0))


def test_figures_by_land_cover(tmp_path):
    """A land-cover raster on the truth's 1 m cells: its building cells are the DTM's 100 raised 0.5 m cells."""
    truth, path, dtm = _rasters(tmp_path)
    dtm[10:20, 10:20] += 2.0  # x 15-20 m, y 10-15 m below the top: truth cells [10:15, 15:20]
    _write_dtm(path, dtm)
    cover = np.full((40, 60), 2, dtype=np.float32)
    cover[10:15, 15:20] = 6
    cover[20:40, 0:10] = 9  # water, west of the DTM (which starts at x = 10 m): no DTM cell
    write_cog(tmp_path / "cover.tif", cover, transform=Affine(1.0, 0.0, X0, 0.0, -1.0, Y1), crs=CRS, unit=None)

    r = truth_accuracy(*truth_on_dtm_cells(path, truth), land_cover_on_dtm_cells(path, tmp_path / "cover.tif"))
    by = r["by_land_cover"]
    assert set(by) == {"2", "6"} and by["6"]["name"] == "building"
    assert (by["6"]["n"], by["6"]["rmse"], by["6"]["off_1m"]) == (100, pytest.approx(2.0), 1.0)
    assert (by["2"]["n"], by["2"]["rmse"], by["2"]["off_1m"]) == (r["n"] - 100, pytest.approx(0.0), 0.0)
    with pytest.raises(ValueError, match="set truth_dtm too"):
        AccuracyParams(truth_land_cover=tmp_path / "cover.tif")


def test_truth_is_resampled_bilinearly_from_cell_centres(tmp_path):
    """A 10 % slope on 1 m truth cells: a 0.5 m DTM of the same plane matches it exactly inside the truth."""
    truth, path, dtm = _rasters(tmp_path, slope=0.1)
    _write_dtm(path, dtm[:, :96])  # x = 10 ... 58 m: every DTM centre between two truth centres
    r = truth_accuracy(*truth_on_dtm_cells(path, truth))
    assert r["n"] == 96 * 60 and r["no_truth"] == 0
    assert r["max_abs"] < 1e-4  # nearest would be 0.025 m off everywhere


def test_a_wall_in_the_truth_is_counted_apart(tmp_path):
    """A 5 m wall between two flat halves of a 1 m truth, and a perfect 0.5 m DTM (each cell the true height at its
    centre): the truth resampled bilinearly blurs the wall over a metre, so the two columns of DTM cells beside it
    are 1.25 m off (centres 0.25 m from the wall: a quarter of the way to the next truth centre).  Those, and only
    those, are cells where the truth varies by 2 m or more over 3 x 3 cells."""
    tx, _ = np.meshgrid(np.arange(60) + 0.5, np.arange(40) + 0.5)
    write_cog(
        tmp_path / "truth.tif",
        np.where(tx < 30, 100.0, 105.0).astype(np.float32),
        transform=Affine(1.0, 0.0, X0, 0.0, -1.0, Y1),
        crs=CRS,
    )
    dx, _ = np.meshgrid(10.0 + (np.arange(96) + 0.5) * 0.5, np.arange(60))
    _write_dtm(tmp_path / "dtm.tif", np.where(dx < 30, 100.0, 105.0))
    r = truth_accuracy(*truth_on_dtm_cells(tmp_path / "dtm.tif", tmp_path / "truth.tif"))
    steep, flat = r["by_relief"]["2m_or_more"], r["by_relief"]["under_2m"]
    assert (steep["n"], flat["n"]) == (2 * 60, 94 * 60)
    assert steep["off_1m"] == 1.0 and steep["max_abs"] == pytest.approx(1.25)
    assert flat["max_abs"] < 1e-4 and r["off_1m"] == pytest.approx(120 / (96 * 60))


def test_evaluate_dtm_prints_the_truth_figures(tmp_path, capsys):
    truth, path, dtm = _rasters(tmp_path)
    dtm[10:20, 10:20] += 2.0
    _write_dtm(path, dtm)
    assert main(["evaluate", "dtm", str(path), "--truth", str(truth), "--json"]) == 0
    t = json.loads(capsys.readouterr().out)["truth"]
    assert t["resampling"] == "bilinear" and t["off_1m"] == pytest.approx(100 / (106 * 60 - 360))
    assert main(["evaluate", "dtm", str(path), "--truth", str(truth)]) == 0
    out = capsys.readouterr().out
    assert "cells > 1 m off (%)" in out and "truth relief >= 2 m" in out


def test_accuracy_stage_reports_the_truth_raster(tmp_path):
    """The stage runs on truth_dtm alone; accuracy.json's 'truth' holds the figures; bad truth: exit 3."""
    truth, path, dtm = _rasters(tmp_path)
    dtm[10:20, 10:20] += 2.0
    _write_dtm(path, dtm)
    params = AccuracyParams(truth_dtm=truth)
    assert Accuracy().is_enabled(params, None) and Accuracy().external_files(params, None) == [truth]
    assert not Accuracy().is_enabled(AccuracyParams(), None)

    ctx = SimpleNamespace(
        params=params,
        inputs={"dtm": path},
        outputs={"accuracy": tmp_path / "accuracy.json"},
        metrics={},
        log=logging.getLogger("test"),
    )
    Accuracy().run(ctx)
    written = json.loads((tmp_path / "accuracy.json").read_text())
    assert set(written) == {"truth"} and written["truth"]["file"] == "truth.tif"
    assert written["truth"]["max_above"] == pytest.approx(2.0) and ctx.metrics["truth"] == written["truth"]
    (tmp_path / "bad.tif").write_bytes(b"not a raster")
    ctx.params = AccuracyParams(truth_dtm=tmp_path / "bad.tif")
    with pytest.raises(InputDataError, match="bad.tif: cannot be read as a raster"):
        Accuracy().run(ctx)


@pytest.mark.slow
def test_main_job_reports_its_dtm_against_the_simulator_truth(tmp_path):
    """configs/flight.yaml sets truth_dtm and truth_land_cover: the DTM against truth/terrain.tif, all and by cover."""
    sets = [f"output={tmp_path / 'out'}", f"cache={tmp_path / 'cache'}"]
    args = ["run", str(ROOT / "configs" / "flight.yaml"), "--until", "accuracy", "-q"]
    assert main(args + [a for s in sets for a in ("--set", s)]) == 0
    acc = json.loads((tmp_path / "out" / "accuracy.json").read_text())
    assert acc["n"] == 30 and acc["outside"] == 0  # every check point on the DTM (the simulator places them there)
    direct = truth_accuracy(
        *truth_on_dtm_cells(
            tmp_path / "out" / "dtm.tif", ROOT / "data_samples" / "flight_ldmrs" / "truth" / "terrain.tif"
        )
    )
    by_cover = acc["truth"].pop("by_land_cover")
    assert acc["truth"] == {
        "file": "terrain.tif",
        "resampling": "bilinear",
        "land_cover_file": "land_cover.tif",
        **direct,
    }
    assert acc["truth"]["n"] > 80_000 and acc["truth"]["no_truth"] == 0
    # the simulator's land cover (truth/land_cover.tif) splits every compared cell by what covers the ground
    assert set(by_cover) == {"2", "5", "6", "9", "17"}
    assert sum(v["n"] for v in by_cover.values()) == acc["truth"]["n"]


def test_report_splits_the_truth_figures_by_land_cover():
    truth = {"file": "terrain.tif", "resampling": "bilinear", "n": 1000, "rmse": 0.7, "mean": -0.06}
    truth |= {"off_1m": 0.046, "off_5m": 0.0033, "max_above": 10.4, "max_below": -14.4}
    cover = {"n": 672, "rmse": 1.81, "mean": 1.15, "off_1m": 0.47, "off_5m": 0.018, "max_above": 9.07}
    truth |= {
        "land_cover_file": "land_cover.tif",
        "by_land_cover": {"17": {"name": "bridge deck", **cover, "max_below": -2.7}},
    }
    flat = {"n": 900, "rmse": 0.2, "off_1m": 0.01, "off_5m": 0.0}
    truth |= {"by_relief": {"under_2m": flat, "2m_or_more": {"n": 100, "rmse": 2.0, "off_1m": 0.37, "off_5m": 0.0}}}
    page = accuracy_section({"truth": truth}, None)
    assert "2 m or more (walls, banks, steps)</td><td>100</td><td>2</td><td>37</td>" in page
    assert "By what covers the ground (land_cover.tif" in page
    assert "17 bridge deck" in page and "<td>672</td>" in page and "<td>47</td>" in page and "+9.070 / -2.700" in page


def test_report_shows_the_truth_figures_apart_from_the_check_points():
    truth = {"file": "terrain.tif", "resampling": "bilinear", "n": 1000, "rmse": 0.7, "mean": -0.06}
    truth |= {"off_1m": 0.046, "off_5m": 0.0033, "max_above": 10.4, "max_below": -14.4}
    alone = accuracy_section({"truth": truth}, None)
    assert "DTM against the true terrain (terrain.tif" in alone and "4.6" in alone and "+10.400 / -14.400" in alone
    assert "No check points were configured" in alone and "RMSEz" not in alone
    assert "DTM against the true terrain" not in accuracy_section({"n": 3, "rmse_z": 0.1}, None)
    both = accuracy_section({"n": 3, "rmse_z": 0.1, "truth": truth}, None)
    assert "RMSEz, all 3 check points" in both and "DTM against the true terrain" in both
