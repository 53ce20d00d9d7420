"""Adding a ground filter: its module and one registration, and every part of the product knows it.

The filter of ``lowest_filter.py`` (the lowest point of each cell and those
within a tolerance of it) is registered as a product's filter would be.
Then the configuration's schema takes it and its parameters, the stage's
tile buffer is its reach, ``pipeline evaluate ground`` runs it (on worker
processes, which import the module that declared it), the generated
configuration reference lists it, and an unknown name is a configuration
error naming the registered ones.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from pydantic import ValidationError

from commands.configdoc import render
from pipeline.cli import main
from stages.classify_ground.filters import GROUND_FILTERS
from stages.classify_ground.params import ClassifyGroundParams
from stages.classify_ground.stage import ClassifyGround
from tests.commands.test_evaluate_ground import labelled_block
from tests.stages.parse.test_real_files import ROOT


@pytest.fixture
def registered():
    """The filter's module, registered for one test and forgotten after it.

    Imported here, not at the top: importing it registers the filter, which
    must not outlive these tests (others render the configuration reference).
    """
    from tests.stages.classify_ground import lowest_filter

    lowest_filter.register()
    try:
        yield lowest_filter
    finally:
        GROUND_FILTERS.unregister("lowest")


def test_the_schema_takes_the_filter_and_its_parameters(registered):
    params = ClassifyGroundParams.model_validate({"algorithm": {"name": "lowest", "tolerance": 0.25}})
    assert isinstance(params.algorithm, registered.LowestParams) and params.algorithm.tolerance == 0.25
    assert params.model_dump(mode="json")["algorithm"] == {"name": "lowest", "cell_size": 2.0, "tolerance": 0.25}
    with pytest.raises(ValidationError) as err:  # its parameters are checked by its own model
        ClassifyGroundParams.model_validate({"algorithm": {"name": "lowest", "tolerance": -1}})
    assert err.value.errors()[0]["loc"] == ("algorithm", "tolerance")


def test_the_tile_buffer_is_the_filters_reach(registered):
    params = ClassifyGroundParams.model_validate({"algorithm": {"name": "lowest", "cell_size": 7.5}})
    assert ClassifyGround().tile_buffer(params) == 7.5
    smrf = ClassifyGroundParams()
    assert ClassifyGround().tile_buffer(smrf) == 8 * smrf.algorithm.max_window_size + 2 * smrf.algorithm.cell_size


def test_evaluate_ground_runs_it(registered, tmp_path, capsys):
    """On a plane with a flat-roofed block: the lowest points of 2 m cells take the roof as ground, and
    the objects stage takes it back: the block is dense enough (0.47 m spacing) for cells that see its walls
    (classify_objects' FACE_CELL; on wider cells the filter's ground would stand)."""
    ref = labelled_block(tmp_path / "ref.laz", n=16000)
    config = tmp_path / "run.yaml"  # 30 m tiles on two worker processes, however light the work
    config.write_text(
        "input: {format: las, paths: [ref.laz]}\noutput: out\n"
        "executor: {kind: local, workers: 2, in_process_below: 0}\ntiling: {size: 30}\n"
    )
    args = ["evaluate", "ground", str(ref), "--config", str(config), "--algorithm", "lowest"]
    args += ["--param", "tolerance=0.3", "--json", "--compare", "smrf", "--no-dtm-check"]
    assert main(args) == 0
    rows = {r["algorithm"]: r for r in json.loads(capsys.readouterr().out)}
    assert set(rows) == {"lowest", "smrf"} and rows["lowest"]["params"]["tolerance"] == 0.3
    assert rows["lowest"]["type_1"] < 0.01 and rows["lowest"]["type_2"] < 0.01  # the roof is off the ground
    # a tolerance of none keeps one point a cell: most ground is lost, which the scores show
    assert main(["evaluate", "ground", str(ref), "--algorithm", "lowest", "--param", "tolerance=0", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)[0]["type_1"] > 0.5


def test_the_config_reference_lists_it(registered):
    doc = render()
    assert "| `stages.classify_ground.algorithm.(lowest)` | | | the lowest point of each cell" in doc
    assert "`stages.classify_ground.algorithm.(lowest).tolerance` | float | `0.1` |" in doc
    assert "`name`: csf \\| lowest \\| pmf \\| smrf" in doc


def test_an_unknown_name_is_a_configuration_error_naming_the_known_ones(registered, tmp_path, capsys):
    config = ROOT / "configs" / "las.yaml"
    code = main(["validate", str(config), "--set", "stages.classify_ground.algorithm.name=kriging"])
    err = capsys.readouterr().err
    assert code == 2 and "stages.classify_ground.algorithm" in err
    assert "unknown ground algorithm 'kriging'; known: csf, lowest, pmf, smrf" in err and "Traceback" not in err
    ref = labelled_block(tmp_path / "ref.laz")
    assert main(["evaluate", "ground", str(ref), "--algorithm", "kriging"]) == 2
    assert "known: csf, lowest, pmf, smrf" in capsys.readouterr().err


def test_forgotten_it_is_unknown_again(registered):
    GROUND_FILTERS.unregister("lowest")
    with pytest.raises(ValidationError, match="known: csf, pmf, smrf"):
        ClassifyGroundParams.model_validate({"algorithm": {"name": "lowest"}})
    registered.register()  # for the fixture's teardown
    assert np.all(registered.lowest(np.zeros((3, 3)), cell_size=1.0, tolerance=0.0))
