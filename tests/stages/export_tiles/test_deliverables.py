"""The ecosystem deliverables end to end on configs/las.yaml: points.copc.laz, DTM tiles and dtm.vrt."""

from __future__ import annotations

import json
from pathlib import Path

import laspy
import numpy as np
import pytest
import rasterio

from pipeline.cli import main

CONFIG = Path(__file__).resolve().parents[3] / "configs" / "las.yaml"

pytestmark = pytest.mark.slow


def test_copc_tiles_and_vrt_published_with_the_run(tmp_path):
    out = tmp_path / "out"
    args = ["run", str(CONFIG), "-q", "--set", f"output={out}", "--set", f"cache={tmp_path / 'cache'}"]
    args += ["--set", "stages.export_las.copc=true", "--set", "stages.export_tiles.tile_size=200"]
    assert main([*args, "--set", "stages.export_tiles.rasters=[dtm,ndsm]"]) == 0
    products = json.loads((out / "run.json").read_text())["products"]
    assert {"points.copc.laz", "dtm.vrt", "ndsm.vrt"} <= set(products)
    # the sample's 512 m x 384 m grid at 440000, 4474000: 3 x 2 tiles of 200 m
    names = sorted(p.name for p in (out / "tiles" / "dtm").glob("*.tif"))
    assert names == [f"dtm_{x}_{y}.tif" for x in (440000, 440200, 440400) for y in (4474000, 4474200)]
    for raster in ("dtm", "ndsm"):
        with rasterio.open(out / f"{raster}.tif") as a, rasterio.open(out / f"{raster}.vrt") as b:
            assert np.array_equal(a.read(1), b.read(1)) and a.transform == b.transform and a.crs == b.crs
            # what the raster says of its band and heights, the VRT and every tile say too
            tile = next((out / "tiles" / raster).glob("*.tif"))
            with rasterio.open(tile) as t:
                for ds in (b, t):
                    assert ds.descriptions == a.descriptions and ds.units == a.units
                    assert ds.tags().get("VERTICAL_DATUM") == a.tags().get("VERTICAL_DATUM")
    with rasterio.open(out / "dtm.vrt") as b:
        assert b.tags()["VERTICAL_DATUM"].startswith("unknown") and b.descriptions[0].startswith("bare-earth")
    delivered, copc = laspy.read(str(out / "points.laz")), laspy.read(str(out / "points.copc.laz"))

    def records(las):
        a = las.points.array
        return np.sort(a.view(np.dtype((np.void, a.dtype.itemsize))))

    assert np.array_equal(records(delivered), records(copc))
    with laspy.CopcReader.open(str(out / "points.copc.laz")) as reader:
        assert len(reader.query()) == len(delivered.points)
        assert reader.header.parse_crs().to_epsg() == 25830
    # switched off again: the products of the previous run are removed
    assert main(args[:7]) == 0
    assert not (out / "points.copc.laz").exists() and not (out / "dtm.vrt").exists()
