"""Noise classes through the pipeline, on surveys where each rule decides (issue 19).

A small LAS (a 1 m grid of ground, with designed outliers) run to ``denoise``
or ``rasterize``; answers from the definitions in docs/CONFIG.md: the
extended local minimum test (when enabled) flags every point of a cell's low
cluster (not only the lowest), the isolated-point test flags exactly the
points farther from their neighbours in 3-D than 10 local spacings (computed
here with scipy), and the DSM and density ignore noise classes 7 and 18.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
from scipy.spatial import cKDTree

from lidar.rasters import read_raster
from pipeline.cli import main
from stages.denoise import outliers
from tests.conftest import run_stages

X0, Y0 = 440_000.0, 4_474_000.0


def write_las(path: Path, xyz: np.ndarray, cls=None, returns=None) -> Path:
    """A LAS 1.4 in EPSG:25830 of local coordinates (origin X0, Y0); *returns*: (return number, count)."""
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([0.001] * 3)
    header.offsets = np.array([X0, Y0, 0.0])
    header.add_crs(pyproj.CRS.from_epsg(25830))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0] + X0, xyz[:, 1] + Y0, xyz[:, 2]
    ones = np.ones(len(xyz), np.uint8)
    las.return_number, las.number_of_returns = returns if returns is not None else (ones, ones)
    las.classification = np.zeros(len(xyz), np.uint8) if cls is None else cls
    las.write(str(path))
    return path


def _run(tmp: Path, las: Path, until: str, stages: str) -> dict:
    config = tmp / "noise.yaml"
    config.write_text(
        f"name: noise\ninput: {{format: las, paths: [{las}]}}\noutput: out\ncache: cache\n"
        f"tiling: {{enabled: false}}\nstages:\n{stages}"
    )
    assert main(["run", str(config), "-q", "--until", until]) == 0
    return run_stages(tmp / "out")


def _ground(size: int = 60, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    g = np.arange(0.5, size, 1.0)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    return np.column_stack((x, y, 600.0 + 0.02 * x + rng.normal(0, 0.02, x.size)))


def _classes(stage: dict) -> np.ndarray:
    return np.asarray(laspy.read(stage["outputs"]["points_denoised"]["file"]).classification)


def test_every_point_of_a_low_cluster_is_low_noise(tmp_path):
    """ELM (Chen et al. 2012), 10 m cells, 1 m threshold: three echoes 9, 7.5 and 6 m below the ground.

    Gaps from the bottom of the cell up: 1.5, 1.5 and 6 m, all big, so all three are low noise, not
    only the lowest; the ground above them is not."""
    pts = _ground()
    low = np.array([[15.2, 15.3, 600.3 - 9.0], [15.6, 15.1, 600.3 - 7.5], [15.9, 15.8, 600.3 - 6.0]])
    cloud = np.vstack((pts, low))
    stages = _run(
        tmp_path,
        write_las(tmp_path / "in.las", cloud),
        "denoise",
        "  denoise: {isolated: {enabled: false}, low: {enabled: true, cell_size: 10.0, elevation_threshold: 1.0}}\n",
    )
    cls = _classes(stages["denoise"])
    assert cls[-3:].tolist() == [7, 7, 7]
    assert (cls[:-3] == 0).all()
    assert stages["denoise"]["metrics"]["low_noise"] == 3


def test_isolated_points_are_those_far_from_their_neighbours_at_the_local_spacing(tmp_path):
    """Birds 0.5-45 m above a 1 m grid: the test flags exactly those whose 2nd nearest point in 3-D is
    farther than 10 local spacings (plan distance to the 8th nearest point) and 2 m, both counted up to
    30 m (the definition in stages/denoise/outliers.py, computed here with scipy alone)."""
    rng = np.random.default_rng(4)
    pts = _ground()
    birds = np.column_stack((rng.uniform(5, 55, 20), rng.uniform(5, 55, 20), 600.0 + rng.uniform(0.5, 45.0, 20)))
    cloud = np.vstack((pts, birds))
    centred = cloud - np.floor(cloud.min(axis=0))
    far = np.minimum(cKDTree(centred).query(centred, k=3, distance_upper_bound=30.0)[0][:, 2], 30.0)
    spacing = np.minimum(cKDTree(centred[:, :2]).query(centred[:, :2], k=9, distance_upper_bound=30.0)[0][:, 8], 30.0)
    expect = (far > 2.0) & (far > 10.0 * spacing)
    # the survey must tell the rule from looser ones: birds beyond 2 m but within 10 spacings, and beyond
    assert ((far > 2.0) & ~expect).sum() >= 3 and expect.sum() >= 3
    isolated = "{neighbors: 2, spacing_neighbors: 8, multiplier: 10.0, min_distance: 2.0, radius: 30.0}"
    stages = _run(
        tmp_path,
        write_las(tmp_path / "in.las", cloud),
        "denoise",
        f"  denoise: {{low: {{enabled: false}}, isolated: {isolated}}}\n",
    )
    cls = _classes(stages["denoise"])
    np.testing.assert_array_equal(np.isin(cls, (7, 18)), expect)
    assert (cls[expect] == 18).all()  # above the ground around them: high noise


def test_dsm_and_density_ignore_noise_classes(tmp_path):
    """A bird (18) 80 m up and a multipath echo (7) 30 m down, already classified: not in the DSM, not counted."""
    pts = _ground(40)
    noise = np.array([[20.3, 20.2, 680.0], [10.6, 30.4, 570.0]])
    cls = np.r_[np.zeros(len(pts), np.uint8), np.array([18, 7], np.uint8)]
    stages = _run(
        tmp_path,
        write_las(tmp_path / "in.las", np.vstack((pts, noise)), cls),
        "rasterize",
        "  denoise: {enabled: false}\n  rasterize: {resolution: 1.0, method: tin}\n",
    )
    out = tmp_path / "out"
    dsm, *_ = read_raster(out / "dsm.tif")
    density, *_ = read_raster(out / "density.tif")
    assert np.nanmax(dsm) < 602.0 and np.nanmin(dsm) > 599.0
    assert np.nansum(density) == len(pts)
    assert stages["rasterize"]["metrics"]["ndsm_max"] < 0.5


@pytest.mark.parametrize("dense", [True, False])
def test_isolated_points_equal_their_definition_however_the_cubes_are_counted(monkeypatch, dense):
    """Ground, a sparse crown (points that share no cube with two others, yet are not isolated) and birds:
    the points flagged are exactly those of the definition (scipy over every point), whether the cubes are
    counted in one array with the trees asked about the points near the candidates only, or by sorting."""
    monkeypatch.setattr(outliers, "DENSE_CUBES", 1 << 24 if dense else 0)
    rng = np.random.default_rng(11)
    crown = rng.normal(0, 2.0, (60, 3)) + (30.0, 30.0, 612.0)
    birds = np.column_stack((rng.uniform(2, 58, 12), rng.uniform(2, 58, 12), 600.0 + rng.uniform(0.5, 45.0, 12)))
    cloud = np.vstack((_ground(), crown, birds))
    centred = cloud - np.floor(cloud.min(axis=0))
    far = np.minimum(cKDTree(centred).query(centred, k=3, distance_upper_bound=30.0)[0][:, 2], 30.0)
    spacing = np.minimum(cKDTree(centred[:, :2]).query(centred[:, :2], k=9, distance_upper_bound=30.0)[0][:, 8], 30.0)
    expect = (far > 2.0) & (far > 10.0 * spacing)
    cand, near = outliers._crowded_cubes(centred, 2.0 / np.sqrt(3.0), 2)
    assert (near is None) != dense  # the way asked for is the way taken
    assert len(cand) > 60 and expect.sum() >= 3  # the crown's points are candidates; some birds are isolated
    got = outliers.isolated_points(cloud, neighbors=2, spacing_neighbors=8, multiplier=10.0, min_distance=2.0)
    np.testing.assert_array_equal(got, expect)


def test_a_survey_with_no_noise_is_its_input_linked_not_rewritten(tmp_path):
    """No tile changes a class: the stage's points are the file it was given (one file, two names)."""
    stages = _run(tmp_path, write_las(tmp_path / "in.las", _ground()), "denoise", "  denoise: {}\n")
    assert (_classes(stages["denoise"]) == 0).all()
    given = Path(stages["strip_adjust"]["outputs"]["points_adjusted"]["file"])
    assert Path(stages["denoise"]["outputs"]["points_denoised"]["file"]).samefile(given)
