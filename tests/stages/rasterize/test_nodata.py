"""The rasters' nodata follows the specification the survey is accepted against (the USGS LBS asks -999999)."""

from __future__ import annotations

import numpy as np
import pytest
import rasterio

from tests.stages.rasterize.test_parameter_cost import run, small_survey


@pytest.mark.parametrize(
    ("sets", "nodata"),
    [
        ((), -999999.0),  # the default specification, USGS LBS QL2, even with the report off
        (("stages.report.specification=asprs-2023-10cm",), -9999.0),
        (("stages.rasterize.nodata=-32767",), -32767.0),  # the user's word over the specification's
    ],
)
def test_nodata_of_the_rasters(tmp_path, sets, nodata):
    path = small_survey(tmp_path)
    assert run(tmp_path, path, "stages.report.enabled=false", *sets) == 0
    for name in ("dtm", "dsm", "ndsm", "density"):
        with rasterio.open(tmp_path / "out" / f"{name}.tif") as ds:
            assert ds.nodata == nodata and ds.dtypes[0] == "float32"
    with rasterio.open(tmp_path / "out" / "dtm.tif") as ds:
        band = ds.read(1)
    empty = band == nodata  # the corners outside the points' hull
    assert empty.any() and np.isfinite(band).all() and (band[~empty] > 600).all()
