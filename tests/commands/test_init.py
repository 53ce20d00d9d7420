"""``pipeline init FOLDER``: one's own LAS/LAZ folder to a run whose title, check points and products are its own.

And ``pipeline validate`` warns when the check points are not the survey's
(the README's sample configuration pointed at other files).
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import laspy
import numpy as np
import pytest

from pipeline.cli import main
from stages.parse.checks import checkpoints_outside

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "data_samples" / "las" / "sample.laz"
LAS_CONFIG = ROOT / "configs" / "las.yaml"


def _folder(tmp_path: Path, name: str = "Valle 2026") -> Path:
    folder = tmp_path / name
    folder.mkdir()
    shutil.copy(SAMPLE, folder / "tile_1.LAZ")  # an upper-case suffix is a LAZ file too
    (folder / "notes.txt").write_text("not a point cloud")
    return folder


def _no_crs_las(path: Path) -> None:
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.scales, header.offsets = np.array([0.01] * 3), np.array([440000.0, 4474000.0, 0.0])
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.array([440000.0, 440010.0]), np.array([4474000.0, 4474010.0]), np.array([1.0, 2.0])
    las.write(path)


def test_init_writes_a_configuration_of_the_folder_s_own(tmp_path, capsys):
    folder = _folder(tmp_path)
    assert main(["init", str(folder)]) == 0
    out = capsys.readouterr().out
    config = folder / "dtm-pipeline.yaml"
    assert f"wrote {config}: 1 LAS/LAZ files, " in out and "ETRS89 / UTM zone 30N (EPSG:25830)" in out
    text = config.read_text()
    assert 'name: "Valle 2026"' in text and 'paths: ["."]' in text and "output: dtm-out" in text
    assert "\n  # accuracy:" in text  # check points: a commented line, none of the sample's
    # EPSG:25830 names no vertical CRS: the key that states it, for this CRS, commented
    assert "# override_crs: EPSG:25830+<vertical EPSG code>" in text
    assert "heights' vertical datum is unknown" in out
    assert main(["validate", str(config)]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.slow
def test_the_initialised_run_has_its_own_title_products_and_no_check_points(tmp_path):
    folder = _folder(tmp_path)
    assert main(["init", str(folder), "-q"]) == 0
    assert main(["run", str(folder / "dtm-pipeline.yaml"), "-q"]) == 0
    products = folder / "dtm-out"
    run = json.loads((products / "run.json").read_text())
    assert run["name"] == "Valle 2026"
    assert {s["name"]: s["status"] for s in run["stages"]}["accuracy"] == "not applicable"  # no check points
    assert not (products / "accuracy.json").exists() and (products / "points.laz").exists()
    assert "<title>QC report — Valle 2026</title>" in (products / "report.html").read_text()
    assert (folder / ".dtm-cache").is_dir()  # the cache next to the configuration, not the clone's


def test_init_refuses_in_one_sentence(tmp_path, capsys):
    assert main(["init", str(tmp_path / "nowhere")]) == 2
    assert (
        capsys.readouterr().err.strip()
        == f"pipeline: error: {tmp_path / 'nowhere'}: not a folder; give the folder that holds the LAS/LAZ files."
    )
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "sub").mkdir()
    shutil.copy(SAMPLE, tmp_path / "empty" / "sub" / "a.laz")  # in a subfolder: not read
    assert main(["init", str(tmp_path / "empty")]) == 2
    assert "no .las or .laz file directly inside" in capsys.readouterr().err
    folder = _folder(tmp_path)
    config = folder / "dtm-pipeline.yaml"
    config.write_text("mine")
    assert main(["init", str(folder)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "exists" in err and "--force" in err
    assert config.read_text() == "mine"
    assert main(["init", str(folder), "--force", "--config", str(tmp_path / "elsewhere.yaml")]) == 0
    assert config.read_text() == "mine"  # --config wrote elsewhere
    assert 'paths: ["Valle 2026"]' in (tmp_path / "elsewhere.yaml").read_text()  # relative to the configuration
    assert main(["init", str(folder), "--force"]) == 0 and config.read_text().startswith("# Written by")


def test_a_header_without_crs_is_a_key_to_fill_never_a_guess(tmp_path, capsys):
    folder = tmp_path / "old"
    folder.mkdir()
    _no_crs_las(folder / "a.las")
    assert main(["init", str(folder)]) == 0
    captured = capsys.readouterr().out
    assert "CRS none in the headers" in captured and "1 file(s) name no CRS (a.las): set input.crs" in captured
    text = (folder / "dtm-pipeline.yaml").read_text()
    assert "\n  # crs: EPSG:XXXX" in text and "override_crs" not in text


def test_validate_warns_of_check_points_outside_the_survey(tmp_path, capsys):
    folder = _folder(tmp_path)
    far = tmp_path / "far.csv"
    far.write_text("x,y,z\n440100,4474100,650\n500000,4474100,650\n500000,4000000,650\n")
    sets = ["--set", f"input.paths=[{folder}]", "--set", f"stages.accuracy.checkpoints={far}"]
    assert main(["validate", str(LAS_CONFIG), *sets]) == 0
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"pipeline: warning: stages.accuracy.checkpoints {far}: 2 of 3 check points lie outside")
    assert "stages.accuracy.enabled=false" in err and len(err.splitlines()) == 1
    # the sample's own check points are inside its extent
    assert main(["validate", str(LAS_CONFIG), "--set", f"input.paths=[{folder}]"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_points_on_the_box_are_inside():
    xy = np.array([[0.0, 0.0], [10.0, 5.0], [10.01, 5.0], [5.0, -0.01]])
    said = checkpoints_outside(xy, np.array([0.0, 0.0]), np.array([10.0, 5.0]), Path("cp.csv"))
    assert said and "2 of 4 check points" in said[0] and "x 0.00 to 10.00, y 0.00 to 5.00" in said[0]
    assert checkpoints_outside(xy[:2], np.array([0.0, 0.0]), np.array([10.0, 5.0]), Path("cp.csv")) == []


@pytest.mark.slow
def test_a_run_warns_of_check_points_off_the_dtm(tmp_path, capsys):
    cps = tmp_path / "cp.csv"
    own = (ROOT / "data_samples" / "las" / "checkpoints.csv").read_text()
    cps.write_text(own.rstrip("\n") + "\nFAR,500000,4474100,650,open\n")
    sets = ["--set", f"output={tmp_path / 'o'}", "--set", f"cache={tmp_path / 'c'}"]
    assert (
        main(
            ["run", str(LAS_CONFIG), "-q", "--until", "accuracy", *sets, "--set", f"stages.accuracy.checkpoints={cps}"]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert f"WARNING [accuracy] 1 of 61 check points of {cps} fall outside the DTM's valid cells" in err
