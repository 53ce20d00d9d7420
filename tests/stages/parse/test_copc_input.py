"""A COPC file as input (issue 36): read as the LAZ it is, its octree records left behind.

COPC 1.0 is LAS 1.4 LAZ with variable-size chunks in octree order, an info VLR
(``copc``/1) and a hierarchy EVLR (``copc``/1000) that say where each node's
points lie in that file.  The same points given as COPC and as plain LAZ must
give the same DTM, byte for byte (the order of the points does not matter to
it), and the COPC records must not be carried: they would describe the wrong
file.  Before, reading one stopped with an internal error (laspy cannot write
the info VLR back, issue 36).
"""

from __future__ import annotations

from pathlib import Path

import laspy

from stages.export_las.copc import write_copc
from tests.conftest import run_until
from tests.stages.export_las.test_copc import _survey


def _run(tmp_path: Path, name: str, source: Path) -> dict:
    config = tmp_path / f"{name}.yaml"
    config.write_text(f"input: {{format: las, paths: [{source}]}}\noutput: out\n")
    return run_until(config, "rasterize", tmp_path / name)


def test_a_copc_input_gives_the_dtm_of_the_same_points_as_laz(tmp_path):
    laz = _survey(tmp_path / "survey.laz", n=20_000)
    copc = tmp_path / "survey.copc.laz"
    write_copc(laz, copc, max_node_points=2_000)  # several nodes: chunks of different sizes
    with laspy.open(copc) as f:
        assert any(v.user_id == "copc" for v in f.header.vlrs)
    runs = {name: _run(tmp_path, name, source) for name, source in (("laz", laz), ("copc", copc))}
    dtm = {name: Path(run["rasterize"]["outputs"]["dtm"]["file"]).read_bytes() for name, run in runs.items()}
    assert dtm["copc"] == dtm["laz"]
    points = laspy.read(runs["copc"]["parse"]["outputs"]["points_georef"]["file"])
    assert len(points.x) == 20_000
    assert not any(v.user_id == "copc" for v in [*points.header.vlrs, *(points.header.evlrs or [])])
    assert any(v.user_id == "survey-co" for v in points.header.vlrs)  # the user's own records are kept
