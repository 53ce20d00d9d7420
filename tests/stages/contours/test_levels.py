"""Contour levels: counted from the DTM's heights and the interval, capped before drawing."""

from __future__ import annotations

import numpy as np
import pytest
from affine import Affine

from pipeline.errors import ConfigError
from stages.contours.lines import contour_lines, levels_between
from stages.contours.stage import MAX_LEVELS, _check_levels
from tests.stages.rasterize.test_parameter_cost import run, small_survey


def test_levels_between_counts_what_contour_lines_draws():
    dem = np.add.outer(np.arange(10.0), np.arange(10.0)) * 0.7 + 3.2  # 3.2 .. 15.8
    lines = contour_lines(dem, Affine(1, 0, 0, 0, -1, 10), interval=2.0)
    assert levels_between(3.2, 15.8, 2.0) == len({level for level, _ in lines}) == 6
    assert levels_between(4.0, 4.0, 2.0) == 1 and levels_between(4.1, 5.9, 2.0) == 0
    assert levels_between(np.nan, 1.0, 1.0) == 0


def test_a_tiny_interval_is_refused_with_one_that_fits():
    dem = np.array([[647.132, 650.0], [np.nan, 666.726]])
    with pytest.raises(ConfigError) as refused:
        _check_levels(dem, 1e-9)
    message = str(refused.value)
    assert message.startswith(
        "stages.contours.interval: 1e-09 m between lines over the DTM's heights of 647.132 to 666.726 m make 19,59"
    )
    assert "more than the 10,000 a run draws; use an interval of at least 0.002 m." in message
    _check_levels(dem, 0.002)
    assert MAX_LEVELS == 10_000


def test_a_run_with_a_tiny_interval_exits_2_before_drawing(tmp_path, capsys):
    path = small_survey(tmp_path)
    assert run(tmp_path, path, "stages.contours.interval=1e-9") == 2
    err = capsys.readouterr().err
    assert "stages.contours.interval: 1e-09 m between lines" in err and "Traceback" not in err
    assert not (tmp_path / "out" / "contours.gpkg").exists()
