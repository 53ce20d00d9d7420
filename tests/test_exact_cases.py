"""Exact cases of the conventions and parameters a plausible slip gets wrong (issue 54's six planted errors).

Each known answer comes from geometry or a textbook formula computed here,
not from the code it checks:

- hillshade: Burrough & McDonnell's shade of a plane of known slope and
  aspect (the formula ``gdaldem hillshade`` computes), for sun positions
  whose altitude is not 45 degrees (there altitude and zenith coincide);
- a cell in full shadow is a shade, not the hillshade raster's nodata;
- contours of a plane lie on their analytic lines;
- IDW's weights are 1 / d**power (Shepard 1968) for the configured power;
- CSF's ``class_threshold`` (hcc) decides which points near the cloth are ground;
- VVA's 95th percentile is of the absolute errors.
"""

from __future__ import annotations

import math

import laspy
import numpy as np
import pyproj
import pytest
import rasterio
from rasterio.transform import from_origin

from lidar.grid import Grid
from lidar.shading import hillshade
from stages.accuracy.vertical import vertical_accuracy
from stages.classify_ground.csf import csf
from stages.contours.lines import contour_lines
from stages.rasterize.interpolate import idw
from tests.conftest import run_until

SUNS = [(315.0, 45.0), (90.0, 30.0), (200.0, 60.0), (0.0, 10.0), (135.0, 75.0)]
PLANES = [(0.3, -0.2), (-0.5, 0.1), (0.05, 0.6), (1.2, 0.0)]  # dz/d(east), dz/d(north)


def _textbook_shade(p: float, q: float, azimuth: float, altitude: float) -> float:
    """255 (cos Z cos S + sin Z sin S cos(A - aspect)), clipped at 0 (Burrough & McDonnell 1998, ch. 8)."""
    zenith = math.radians(90.0 - altitude)
    slope = math.atan(math.hypot(p, q))
    aspect = math.atan2(-p, -q)  # the downhill direction, clockwise from north (east, north components)
    shade = math.cos(zenith) * math.cos(slope) + math.sin(zenith) * math.sin(slope) * math.cos(
        math.radians(azimuth) - aspect
    )
    return 255.0 * max(shade, 0.0)


@pytest.mark.parametrize("azimuth,altitude", SUNS)
@pytest.mark.parametrize("p,q", PLANES)
def test_a_plane_shades_to_the_textbook_value(p, q, azimuth, altitude):
    cell = 2.0
    rows, cols = np.indices((7, 9))
    east, north = cols * cell, -rows * cell  # row 0 is the north edge
    dem = 100.0 + p * east + q * north
    shade = hillshade(dem, cell, azimuth=azimuth, altitude=altitude)
    assert shade[3, 4] == pytest.approx(_textbook_shade(p, q, azimuth, altitude), abs=1.0)


def test_a_cell_in_full_shadow_is_a_shade_not_nodata(tmp_path):
    """A slope facing away from a low sun is in full shadow: hillshade.tif holds 1 there, never 0 (nodata)."""
    assert _textbook_shade(0.0, 1.0, 0.0, 10.0) == 0.0  # a 45-degree slope down to the south, sun in the north
    out = run_until(
        _steep_survey(tmp_path),
        "hillshade",
        tmp_path / "o",
        "stages.hillshade.altitude=10",
        "stages.hillshade.azimuth=0",
        cache=tmp_path / "c",
    )
    assert out["hillshade"]["status"] == "ran"
    with rasterio.open(tmp_path / "o" / "hillshade.tif") as ds, rasterio.open(tmp_path / "o" / "dtm.tif") as d:
        shade, dtm = ds.read(1), d.read(1, masked=True)
        assert ds.nodata == 0
    inner = ~dtm.mask
    inner[:3], inner[-3:], inner[:, :3], inner[:, -3:] = False, False, False, False
    assert inner.sum() > 100 and np.all(shade[inner] == 1)


def _steep_survey(tmp_path):
    rng = np.random.default_rng(7)
    x = rng.uniform(0, 60, 20000) + 440000
    y = rng.uniform(0, 60, 20000) + 4474000
    z = 700.0 + (y - 4474000)  # rises 1 m a metre to the north: faces south
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.offsets, header.scales = np.array([440000.0, 4474000.0, 0.0]), np.array([0.001] * 3)
    header.add_crs(pyproj.CRS.from_epsg(25830))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    las.classification = np.full(len(x), 2, np.uint8)
    las.return_number = np.ones(len(x), np.uint8)
    las.number_of_returns = np.ones(len(x), np.uint8)
    las.write(tmp_path / "steep.las")
    config = tmp_path / "steep.yaml"
    config.write_text(
        "input: {format: las, paths: [steep.las]}\nexecutor: {kind: local, workers: 1}\n"
        "stages:\n  denoise: {enabled: false}\n  classify_ground: {enabled: false}\n"
        "  classify_water: {enabled: false}\n  classify_objects: {enabled: false}\n"
        "  strip_adjust: {enabled: false}\n  rasterize: {resolution: 1.0}\n"
    )
    return config


@pytest.mark.parametrize("a,b", [(0.5, 0.25), (-0.3, 0.8), (0.0, -1.0)])
def test_contours_of_a_plane_lie_on_their_analytic_lines(a, b):
    """z = a x + b y: the contour of level L is the line a x + b y = L, to within 1 mm (a half-cell shift is
    half a cell off along the gradient)."""
    cell = 2.0
    transform = from_origin(1000.0, 2000.0, cell, cell)
    rows, cols = np.indices((20, 30))
    x, y = 1000.0 + (cols + 0.5) * cell, 2000.0 - (rows + 0.5) * cell
    dem = a * (x - 1000.0) + b * (y - 2000.0)
    lines = contour_lines(dem, transform, interval=1.0)
    assert len(lines) > 5
    norm = math.hypot(a, b)
    for level, xy in lines:
        off = (a * (xy[:, 0] - 1000.0) + b * (xy[:, 1] - 2000.0) - level) / norm
        assert np.abs(off).max() < 1e-3


@pytest.mark.parametrize("power", [1.0, 2.0, 3.0])
def test_idw_weighs_by_the_configured_power(power):
    """One cell centre, two points at 1 m and 3 m with 10 and 20: (10 / 1**p + 20 / 3**p) / (1 + 1 / 3**p)."""
    grid = Grid(xmin=0.0, ymax=1.0, resolution=1.0, cols=1, rows=1, row0=0, col0=0)  # centre (0.5, 0.5)
    points = np.array([[1.5, 0.5, 10.0], [0.5, 3.5, 20.0]])
    value = idw(points, grid, nodata_distance=10.0, neighbors=2, power=power, margin=None)[0, 0]
    expected = (10.0 + 20.0 / 3**power) / (1.0 + 1.0 / 3**power)
    assert value == pytest.approx(expected, rel=1e-12)


def test_csf_class_threshold_decides_what_near_the_cloth_is_ground():
    """A flat field (0 m) with points 0.3 m and 0.8 m above it: hcc 0.5 takes the 0.3 m ones as ground, not the
    0.8 m ones; hcc 0.2 takes neither; hcc 1.0 both.  The cloth resolution (1 m here) must not stand in for it."""
    rng = np.random.default_rng(3)
    n = 4000
    xy = rng.uniform(0, 40, (n, 2))
    ground = np.column_stack((xy, rng.normal(0.0, 0.01, n)))
    low = np.column_stack((rng.uniform(10, 30, (200, 2)), np.full(200, 0.3)))
    high = np.column_stack((rng.uniform(10, 30, (200, 2)), np.full(200, 0.8)))
    xyz = np.vstack((ground, low, high))

    def ground_share(hcc):
        mask = csf(xyz, cloth_resolution=1.0, class_threshold=hcc, rigidness=3)
        return mask[n : n + 200].mean(), mask[n + 200 :].mean()

    assert ground_share(0.5)[0] > 0.95 and ground_share(0.5)[1] < 0.05
    assert ground_share(0.2)[0] < 0.05
    assert ground_share(1.0)[1] > 0.95


def test_vva_is_the_95th_percentile_of_absolute_errors():
    """Vegetated errors -1.0, 0.1, 0.2 m: |e| sorted 0.1, 0.2, 1.0; the 95th percentile (linear between
    order statistics, position 0.95 x 2 = 1.9) is 0.2 + 0.9 x 0.8 = 0.92 m; of the signed errors it would be
    0.19 m.  RMSEz over all: sqrt((1 + 0.01 + 0.04) / 3)."""
    errors = np.array([-1.0, 0.1, 0.2, 0.05, -0.05])
    cover = np.array(["vegetated", "vegetated", "vegetated", "open", "open"], dtype=object)
    r = vertical_accuracy(errors, cover)
    assert r["vva_95"] == pytest.approx(0.92, abs=1e-12)
    assert r["vva_rmse_z"] == pytest.approx(math.sqrt(1.05 / 3), abs=1e-12)
    assert r["nva_95"] == pytest.approx(1.96 * 0.05, abs=1e-12)
    assert r["n_vegetated"] == 3 and r["n_non_vegetated"] == 2
