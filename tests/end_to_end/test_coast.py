"""A coast: the sea's third of the survey, 20 m below a cliff, never pulls the land's DTM down.

The scene is :func:`tests.synthetic.make_coast` (the sample scene with its
east third turned to sea, one pulse in five returning from the water).  On
a kept-back coastal project the sea was taken as the ground and the land
above the cliff as objects: the DTM lay 19 m below the land.  This checks
the land, the sea's echoes out of the ground (water seen through dropouts,
docs/stages/classify_water.md), and the DTM over the sea at the sea's level.
"""

from __future__ import annotations

import laspy
import numpy as np
import pytest

from pipeline.cli import main
from tests.synthetic import (
    COAST,
    SAMPLE_ORIGIN,
    coast_line,
    dtm_at_cell_centres,
    make_coast,
    make_scene,
    sea_level,
    terrain,
    write_scene_las,
)

pytestmark = pytest.mark.slow


def test_the_simulated_coast_is_what_it_says():
    """Sea echoes at the sea's level within the waves, none ground, from about one pulse in five; the land
    is the scene's own."""
    width, height = 300.0, 200.0
    coast, scene = make_coast(width=width, height=height), make_scene(width=width, height=height)
    line, level = coast_line(width), sea_level(width, height)
    assert line == pytest.approx(200.0)
    assert level == pytest.approx(terrain(np.full(400, line), np.linspace(0, height, 400)).min() - 20.0)
    sea = coast.x > line
    assert np.abs(coast.z[sea] - level).max() < 6 * COAST["waves"]
    assert not coast.true_ground[sea].any() and (coast.number_of_returns[sea] == 1).all()
    pulses = np.count_nonzero((scene.x > line) & (scene.return_number == scene.number_of_returns))
    share = sea.sum() / pulses
    assert abs(share - COAST["echoes"]) < 4 * np.sqrt(COAST["echoes"] * (1 - COAST["echoes"]) / pulses)
    land = scene.x <= line
    np.testing.assert_array_equal(coast.x[~sea], scene.x[land])
    np.testing.assert_array_equal(coast.z[~sea], scene.z[land])


def test_the_land_above_a_cliff_keeps_its_dtm(tmp_path):
    width, height = 512.0, 384.0
    laz = tmp_path / "coast.laz"
    write_scene_las(make_coast(width=width, height=height), laz)
    out = tmp_path / "out"
    config = tmp_path / "coast.yaml"
    config.write_text(
        f"input: {{format: las, paths: [{laz}]}}\noutput: {out}\ncache: {tmp_path / 'cache'}\n"
        "stages:\n  strip_adjust: {enabled: false}\n  report: {enabled: false}\n"
    )
    assert main(["run", str(config), "-q"]) == 0
    las = laspy.read(str(out / "points.laz"))
    offshore = np.asarray(las.x) - SAMPLE_ORIGIN[0] > coast_line(width)
    classes = np.asarray(las.classification)[offshore]
    assert np.mean(classes == 9) > 0.99, "the sea is not water"
    assert not np.isin(classes, (2, 20)).any(), "the sea is in the ground"  # the bar: no sea echo
    dtm, cx, cy = dtm_at_cell_centres(out / "dtm.tif")
    line = coast_line(width)
    land = (cx < line - 2.0) & np.isfinite(dtm)
    e = dtm[land] - terrain(cx[land], cy[land])
    assert abs(np.median(e)) < 0.05, "the land's DTM is not on the land"
    assert np.mean(np.abs(e) > 0.5) < 0.01
    sea = (cx > line + 2.0) & np.isfinite(dtm)
    assert sea.sum() > 0.95 * np.count_nonzero(cx > line + 2.0)
    assert abs(np.median(dtm[sea]) - sea_level(width, height)) < 0.1
