"""A LAS header's vertical CRS (``VerticalCSTypeGeoKey``) is kept, as GDAL reads it.

laspy builds a header's CRS from the projected or geographic GeoKey alone.
The known answers are the GeoTIFF 1.1 keys themselves (OGC 19-008r4,
§7.4 ``VerticalGeoKey``: 4096 the vertical CRS, 4099 its unit) and what GDAL
makes of them: the compound CRS horizontal + vertical, the vertical axis in
``VerticalUnitsGeoKey``'s unit.
"""

from __future__ import annotations

from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest

from lidar.clouds import cloud_crs
from lidar.units import Units
from stages.parse.read_las import convert_las_files


def _with_keys(path: Path, keys: list[tuple[int, int]]) -> Path:
    """A small LAS 1.2 file in UTM 10N whose GeoKeyDirectory holds *keys* (id, value) besides the projected ones."""
    header = laspy.LasHeader(point_format=1, version="1.2")
    header.offsets, header.scales = [500_000.0, 4_000_000.0, 0.0], [0.01, 0.01, 0.01]
    vlr = laspy.vlrs.known.GeoKeyDirectoryVlr()
    entries = [(1024, 1), (1025, 1), (3072, 26910), (3076, 9001), *keys]
    vlr.geo_keys_header.number_of_keys = len(entries)
    vlr.geo_keys = []
    for key_id, value in entries:
        entry = laspy.vlrs.geotiff.GeoKeyEntryStruct()
        entry.id, entry.tiff_tag_location, entry.count, entry.value_offset = key_id, 0, 1, value
        vlr.geo_keys.append(entry)
    header.vlrs.append(vlr)
    las = laspy.LasData(header)
    rng = np.random.default_rng(1)
    n = 2_000
    las.x = 500_000 + rng.uniform(0, 100, n)
    las.y = 4_000_000 + rng.uniform(0, 100, n)
    las.z = rng.uniform(10, 12, n)
    las.return_number = np.ones(n, np.uint8)
    las.number_of_returns = np.ones(n, np.uint8)
    las.gps_time = np.arange(n, dtype=float)
    las.write(str(path))
    return path


def _read(tmp_path: Path, keys: list[tuple[int, int]]):
    src = _with_keys(tmp_path / "in.las", keys)
    target, report, _ = convert_las_files(
        [src], tmp_path / "points.las", crs_setting="auto-utm", assign_crs=None, chunk_size=1_000
    )
    return target, report, cloud_crs(laspy.open(str(tmp_path / "points.las")))


def test_navd88_vertical_key_gives_the_compound_crs_in_the_intermediate(tmp_path):
    target, report, written = _read(tmp_path, [(4096, 5703), (4099, 9001)])
    for crs in (target, written):
        assert crs.is_compound
        horizontal, vertical = crs.sub_crs_list
        assert horizontal.to_epsg() == 26910
        assert vertical.to_epsg() == 5703  # NAVD88 height
    assert "NAVD88 height" in next(iter(report.crs_read_as.values()))


def test_vertical_units_key_sets_the_height_unit(tmp_path):
    """4099 = 9002 (international foot) on NAVD88: heights in feet, horizontal still metres."""
    target, _, written = _read(tmp_path, [(4096, 5703), (4099, 9002)])
    for crs in (target, written):
        units = Units.of(crs)
        assert units.horizontal == 1.0
        assert units.vertical == pytest.approx(0.3048)


def test_a_height_unit_without_vertical_crs_is_named_not_guessed(tmp_path):
    """4099 = 9003 (US survey foot) and no 4096: heights stay in the horizontal unit, and the log says so."""
    target, report, _ = _read(tmp_path, [(4099, 9003)])
    assert not target.is_compound and target.to_epsg() == 26910
    note = next(iter(report.crs_read_as.values()))
    assert "US survey foot" in note and "input.override_crs" in note


def test_matching_vertical_unit_and_no_vertical_crs_says_nothing(tmp_path):
    target, report, _ = _read(tmp_path, [(4099, 9001)])
    assert target.equals(pyproj.CRS.from_epsg(26910))
    assert report.crs_read_as == {}


def test_a_vertical_key_that_is_not_a_vertical_crs_is_ignored_with_a_note(tmp_path):
    target, report, _ = _read(tmp_path, [(4096, 4326)])
    assert not target.is_compound
    assert "is not an EPSG vertical CRS" in next(iter(report.crs_read_as.values()))
