"""SMRF's tile buffer must reach the far bank of a river that starts in the tile (issue 19).

SMRF fills the cells of its provisional DEM that hold no ground (empty
cells, object cells) with the harmonic interpolant of the cells around them
(Pingel et al. 2013, doi:10.1016/j.isprsjprs.2012.12.002;
:func:`stages.classify_ground.surface.inpaint`), so the DEM at a river's near bank
depends on its far bank; and the point test ``|z - DEM| <= et + es slope``
reads the DEM's slope there.  A tile whose buffer stops short of the far
bank sees the river as the end of the survey: a flat DEM at the bank,
no slope, a smaller threshold.

The survey is built so that the answer follows from its geometry.  A strip
200 m x 30 m, one point per square metre at the cell centres, ground at
0 m up to x = 97 m, a river without returns from there to x = 154 m
(3 w_max = 54 m past the tile edge x = 100 m: beyond a buffer of
2 w_max + 2 c = 38 m, within the first pass's 4 w_max + 2 c = 74 m), and a
terrace 20 m high beyond it.  Every line of the grid along x is the same, so
the inpainted river is a straight ramp from the last bank cell (column 96,
0 m) to the first terrace cell (column 154, 20 m): 20/58 per metre.  A low
point (a kerb, a bush) 0.6 m up at x = 96.75 m, in the last bank cell:

- untiled (and in a tile that sees the far bank): the DEM there is
  0.25 x 20/58 = 0.086 m and its slope 0.625 x 20/58 = 0.216 (central
  differences, read bilinearly), so the threshold is
  0.5 + 1.25 x 0.216 = 0.77 m > 0.6 - 0.086 m: ground;
- in a tile that ends at the near bank: DEM 0 m, slope 0 (one-sided
  difference on flat ground), threshold 0.5 m < 0.6 m: not ground.

So a tiled run with the buffer the stage declares must classify every point
as the untiled run does, and one with 38 m must not: the test fails when the
declared buffer is too small for a river the declared reach claims to cover
(docs/stages/classify_ground.md: a gap wider than the buffer may differ).

Since SMRF's second look at the low cells (issue 16: the object filter runs
again around cells the first pass decided) the declared reach is
8 w_max + 2 c = 146 m.  A second river, 6 w_max = 108 m past the edge (the
survey 300 m long, the ramp 20/112 per metre: DEM 0.045 m, slope 0.112,
threshold 0.64 m > 0.6 - 0.045 m), tells the declared buffer from the first
pass's 4 w_max + 2 c = 74 m the same way.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pytest

from tests.conftest import run_until
from tests.stages.denoise.test_noise_classes import X0, Y0, write_las

assert X0 % 100 == 0 and Y0 % 100 == 0  # the origin on whole tiles: the tile edge at local x = 100 m
W_MAX, CELL = 18.0, 1.0  # SMRF's published window radius and cell (the stage's defaults)
EDGE = 100.0  # the edge between the two tiles of 100 m
NEAR = 97.0  # the river: no returns for NEAR < x < far
TERRACE = 20.0  # height of the far bank (m)
BANK_X, BANK_Z = 96.75, 0.6  # the low points in the last cell of the near bank
ROWS = 30
#: (far bank x, survey length, the too-short buffer): 38 m = 2 w_max + 2 c, 74 m = 4 w_max + 2 c
RIVERS = {
    "54 m": (EDGE + 3 * W_MAX, 200.0, 2 * W_MAX + 2 * CELL),
    "108 m": (EDGE + 6 * W_MAX, 300.0, 4 * W_MAX + 2 * CELL),
}


def _survey(path: Path, far: float, length: float) -> np.ndarray:
    """Write the survey; return which of its points are the low bank points."""
    g = np.arange(0.5, length, CELL)
    x, y = (a.ravel() for a in np.meshgrid(g, np.arange(0.5, ROWS, CELL)))
    dry = (x < NEAR) | (x > far)
    x, y = x[dry], y[dry]
    ground = np.column_stack((x, y, np.where(x > far, TERRACE, 0.0)))
    rows = np.arange(0.5, ROWS, CELL)
    bank = np.column_stack((np.full(ROWS, BANK_X), rows, np.full(ROWS, BANK_Z)))
    write_las(path, np.vstack((ground, bank)))
    return np.r_[np.zeros(len(ground), bool), np.ones(ROWS, bool)]


#: SMRF filters a grid this small whole (no tile, no buffer); these runs make it cut the survey into tiles.
TILES = ("stages.classify_ground.one_grid_cells=0",)


@pytest.fixture(scope="module", params=list(RIVERS))
def river(request, tmp_path_factory):
    far, length, short = RIVERS[request.param]
    root = tmp_path_factory.mktemp("river")
    bank = _survey(root / "river.las", far, length)
    (root / "river.yaml").write_text(
        "name: river\ninput: {format: las, paths: [river.las]}\noutput: out\ncache: cache\n"
        "executor: {kind: local, workers: 1}\n"
        "stages:\n  denoise: {enabled: false}\n  classify_ground: {algorithm: {name: smrf}}\n"
    )
    runs = {}
    for name, sets in (
        ("untiled", ["tiling.enabled=false"]),
        ("declared", ["tiling.size=100", *TILES]),  # the buffer the stage declares
        ("short", ["tiling.size=100", f"tiling.buffer={short:g}", *TILES]),
    ):
        stage = run_until(root / "river.yaml", "classify_ground", root / name, *sets)["classify_ground"]
        runs[name] = (stage, np.asarray(laspy.read(stage["outputs"]["points_classified"]["file"]).classification))
    return bank, runs, far, short


def test_the_river_crosses_the_tile_edge_between_the_short_and_the_declared_buffer(river):
    _, runs, far, short = river
    assert runs["untiled"][0]["metrics"]["tiling"]["tiles"] == 1
    assert runs["declared"][0]["metrics"]["tiling"]["tiles"] >= 2
    assert runs["short"][0]["metrics"]["tiling"]["buffer"] == short < far - EDGE
    assert runs["declared"][0]["metrics"]["tiling"]["buffer"] > far - EDGE


def test_untiled_smrf_keeps_the_low_bank_points_as_ground(river):
    bank, runs, _, _ = river
    cls = runs["untiled"][1]
    assert (cls[bank] == 2).all()  # within 0.77 m of the DEM that ramps to the far bank
    assert (cls == 2).all()  # flat ground and terrace: nothing else to remove


def test_a_buffer_short_of_the_far_bank_changes_the_bank_points(river):
    """The survey tells buffers apart: a tile that ends at the near bank rejects the 0.6 m points."""
    bank, runs, _, _ = river
    cls = runs["short"][1]
    assert (cls[bank] == 1).all()
    assert (cls[~bank] == 2).all()


def test_tiled_smrf_with_the_declared_buffer_equals_untiled(river):
    _, runs, _, _ = river
    np.testing.assert_array_equal(runs["declared"][1], runs["untiled"][1])
