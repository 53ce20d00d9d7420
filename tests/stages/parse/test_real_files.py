"""Real LAS/LAZ files of other projects (issue 22): true metadata, true errors, cost that follows the points.

The files are in ``../shared/data/real/`` (see its README); they are read from
there, never copied.  A missing file fails the test: nothing here skips.
"""

from __future__ import annotations

import json
import math
import shutil
import struct
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
import rasterio

from lidar.clouds import PointLayout, cloud_info
from lidar.grid import Grid, check_grid_size
from lidar.units import METRE
from pipeline.cli import main
from pipeline.errors import ConfigError, InputDataError
from stages.classify_ground.ground_classes import for_spacing, nominal_spacing
from stages.classify_ground.smrf import SmrfParams
from stages.parse.isolated import IsolationGrid, withhold_isolated
from stages.parse.las_index import file_crs
from stages.parse.las_report import LasReadReport
from stages.parse.read_las import convert_las_files, copy_records, read_las_files
from tests.shared_data import REAL

ROOT = Path(__file__).resolve().parents[3]


def real(name: str) -> Path:
    """A shared real file; its absence is a failure (CI must have the data)."""
    path = REAL / name
    assert path.exists(), f"{path} is missing: the real-data tests need ../shared/data/real beside the clone"
    return path


def _read(path: Path, **kw):
    return read_las_files([path], crs_setting="auto-utm", assign_crs=kw.pop("assign", None), chunk_size=50_000, **kw)


def _write_las(path: Path, x, y, z, *, scale: float = 0.01, point_format: int = 6, version: str = "1.4", **fields):
    """A synthetic LAS in EPSG:25830: single returns unless *fields* say otherwise."""
    header = laspy.LasHeader(point_format=point_format, version=version)
    header.offsets = [float(np.floor(np.min(x))), float(np.floor(np.min(y))), 0.0]
    header.scales = [scale, scale, scale]
    header.add_crs(pyproj.CRS.from_epsg(25830))
    las = laspy.LasData(header)
    las.x, las.y, las.z = x, y, z
    ones = np.ones(len(x), dtype=np.uint8)
    fields = {"return_number": ones, "number_of_returns": ones, **fields}
    for name, values in fields.items():
        setattr(las, name, values)
    las.write(str(path))
    return path


def test_header_crs_that_contradicts_the_coordinates_names_the_override():
    """lone-star.laz says WGS 84 over UTM metres: the true cause and the key, not "damaged scale"."""
    path = real("pdal/lone-star.laz")
    with pytest.raises(InputDataError) as err:
        _read(path)
    msg = str(err.value)
    assert str(path) in msg and "not longitudes and latitudes" in msg and "input.override_crs" in msg
    assert "damaged" not in msg
    with laspy.open(path) as reader:  # the override is taken before any point is read
        header = reader.header

    crs, source = file_crs(path, header, None, pyproj.CRS.from_epsg(26912))
    assert crs.to_epsg() == 26912 and source == "input.override_crs"


def test_empty_wkt_takes_input_crs_or_the_override():
    """warsaw_small.las has an empty WKT: input.crs (PDAL's default_srs) or input.override_crs is used."""
    path = real("pdal/warsaw_small.las")
    with pytest.raises(InputDataError, match="cannot be read.*set input.override_crs"):
        _read(path)
    las, report = _read(path, assign=pyproj.CRS.from_epsg(2180))
    assert len(las.points) == 3000 and report.crs_source[str(path)] == "input.crs"
    assert "unreadable" in report.crs_notes[str(path)]
    las, report = _read(path, override_crs=pyproj.CRS.from_epsg(2180))
    assert report.crs_source[str(path)] == "input.override_crs" and las.header.parse_crs().to_epsg() == 2180


def test_geographic_crs_on_local_coordinates_is_the_cause():
    """simple1_4.las: y up to 100 under a geographic CRS — said as such, not "not finite"."""
    path = real("laspy/simple1_4.las")
    with pytest.raises(InputDataError, match="not longitudes and latitudes") as err:
        _read(path)
    assert "not finite" not in str(err.value)


def test_projected_linear_units_geokey_is_honoured():
    """mvk-thin.las: EPSG:26995 (metres) with ProjLinearUnitsGeoKey = US survey foot, read as GDAL reads it."""
    path = real("pdal/mvk-thin.las")
    las, report = _read(path)
    crs = las.header.parse_crs()
    # auto-utm keeps the projected input CRS: its axes must now be in US survey feet
    assert crs.axis_info[0].unit_name == "US survey foot"
    lon, lat = pyproj.Transformer.from_crs(crs, 4326, always_xy=True).transform(np.asarray(las.x), np.asarray(las.y))
    # Mississippi West's area of use (EPSG): lon -91.65..-89.37, lat 31.0..35.01
    assert (-91.65 <= lon).all() and (lon <= -89.37).all() and (31.0 <= lat).all() and (lat <= 35.01).all()
    assert "US survey foot" in report.crs_read_as[str(path)]


def test_a_stray_point_outside_the_header_bounds_is_left_out():
    """spurious.las: one point 80 km outside the header's bounds is counted and left out of the points."""
    path = real("pdal/spurious.las")
    las, report = _read(path)
    assert report.outside_header_bounds == {str(path): 1} and report.points == {str(path): 1065}
    assert len(las) == 1064 and not np.asarray(las.withheld, dtype=bool).any()
    assert np.ptp(np.asarray(las.x)) < 2_000 and np.ptp(np.asarray(las.y)) < 2_000


def test_a_stray_point_inside_the_header_bounds_is_withheld(tmp_path):
    """Header bounds computed with the stray point: it is found far from the survey's dense core instead."""

    rng = np.random.default_rng(1)
    n = 50_000
    x, y = 440_000 + rng.uniform(0, 300, n), 4_474_000 + rng.uniform(0, 300, n)
    x[7], y[7] = 520_000.0, 4_474_100.0  # 80 km east
    src = _write_las(tmp_path / "in.las", x, y, rng.uniform(600, 610, n), point_format=3, version="1.2")
    _, report, _ = convert_las_files(
        [src], tmp_path / "out.las", crs_setting="auto-utm", assign_crs=None, chunk_size=10_000
    )
    out = laspy.read(tmp_path / "out.las")
    assert report.far_from_survey == 1 and np.flatnonzero(np.asarray(out.withheld)).tolist() == [7]
    assert report.usable_box[2] < 440_301 and report.outside_header_bounds == {}


def _survey_with_a_far_point(tmp_path, name="in.las"):
    """50,000 points on 300 m x 300 m and point 7 80 km east, LAS 1.4 format 6 in EPSG:25830 (copied as delivered)."""
    rng = np.random.default_rng(1)
    n = 50_000
    x, y = 440_000 + rng.uniform(0, 300, n), 4_474_000 + rng.uniform(0, 300, n)
    x[7], y[7] = 520_000.0, 4_474_100.0
    return _write_las(tmp_path / name, x, y, rng.uniform(600, 610, n))


def _set_header_bounds(path: Path, mins, maxs) -> None:
    """Overwrite a LAS header's bounds (bytes 179-226: max x, min x, max y, min y, max z, min z)."""
    with open(path, "r+b") as fh:
        fh.seek(179)
        fh.write(struct.pack("<6d", maxs[0], mins[0], maxs[1], mins[1], maxs[2], mins[2]))


def test_the_copy_counts_the_isolation_grid_of_the_file_it_writes(tmp_path):
    """A LAS 1.4 copied as delivered: the points counted while copying are those of the file written, cell by cell."""

    src = _survey_with_a_far_point(tmp_path)
    target, layout = pyproj.CRS.from_epsg(25830), PointLayout(point_format=6)
    _, grid = copy_records(src, tmp_path / "out.las", target, LasReadReport(), set(), 10_000, None, layout)
    out = laspy.read(tmp_path / "out.las")
    expected = IsolationGrid(out.header.mins, out.header.maxs)
    expected.add(np.asarray(out.x), np.asarray(out.y))
    assert grid is not None and grid.is_over(out.header.mins, out.header.maxs)
    assert np.array_equal(grid.counts, expected.counts) and grid.counts.sum() == 50_000


def test_counts_of_another_grid_or_of_too_few_points_are_not_trusted(tmp_path):
    """withhold_isolated counts the points itself unless the counts given are of its grid and hold every point."""

    path = _survey_with_a_far_point(tmp_path)
    with laspy.open(path) as reader:
        mins, maxs = reader.header.mins, reader.header.maxs
    other = IsolationGrid(mins - 1.0, maxs)  # another grid, every point in one cell: nothing would be far
    other.counts[0] = 50_000
    short = IsolationGrid(mins, maxs)  # the right grid without the points
    for counted in (other, short, None):
        far = withhold_isolated(path, counted=counted)
        assert np.flatnonzero(np.asarray(laspy.read(path).withheld)).tolist() == [7]
        assert far.count == 1 and far.usable_box[2] < 440_301
        _write_las_flags_clear(path)


def _write_las_flags_clear(path: Path) -> None:
    las = laspy.read(path)
    las.withheld = np.zeros(len(las.x), dtype=bool)
    las.write(str(path))


@pytest.mark.parametrize("shift", [-400.0, 400.0], ids=["bounds-too-narrow", "bounds-too-wide"])
def test_a_copied_file_whose_header_bounds_are_not_its_points_still_finds_the_far_point(tmp_path, shift):
    """Header x bounds 400 m inside or outside the points (more than a cell of the isolation grid, within the
    stray tolerance of 1 % of 80 km): same points withheld."""

    src = _survey_with_a_far_point(tmp_path)
    with laspy.open(src) as reader:
        mins, maxs = np.asarray(reader.header.mins), np.asarray(reader.header.maxs)
    _set_header_bounds(src, mins - [shift, 0, 0], maxs + [shift, 0, 0])
    _, report, _ = convert_las_files(
        [src], tmp_path / "out.las", crs_setting="auto-utm", assign_crs=None, chunk_size=10_000
    )
    out = laspy.read(tmp_path / "out.las")
    assert report.far_from_survey == 1 and np.flatnonzero(np.asarray(out.withheld)).tolist() == [7]
    assert report.outside_header_bounds == {} and np.array_equal(out.header.mins, mins)


def test_return_number_zero_is_read_as_one():
    path = real("pdal/utm17.las")
    las, report = _read(path)
    assert (np.asarray(las.return_number) == 1).all() and report.return_number_zero == {str(path): 10}


def test_a_header_announcing_fewer_points_than_the_file_holds(tmp_path):
    """Every record is read, and both numbers are reported."""
    path = tmp_path / "short.las"
    shutil.copy(real("pdal/utm17.las"), path)
    with open(path, "r+b") as fh:  # LAS 1.2: legacy point count at byte 107
        fh.seek(107)
        fh.write(struct.pack("<I", 6))
    las, report = _read(path)
    assert len(las.points) == 10 and report.header_count_short == {str(path): (6, 10)}


def test_grid_size_is_checked_against_memory_before_allocating():

    grid = Grid.covering(0.0, 0.0, 50_000.0, 50_000.0, 1.0)
    with pytest.raises(ConfigError, match=r"^stages.rasterize.resolution: 1 m cells .* make 2,500,100,001 cells"):
        check_grid_size(grid, (0.0, 0.0, 50_000.0, 50_000.0), METRE, memory=24 * 2**30)
    check_grid_size(Grid.covering(0.0, 0.0, 5_000.0, 5_000.0, 1.0), (0, 0, 5e3, 5e3), METRE, memory=24 * 2**30)


def test_sparse_surveys_filter_on_cells_of_their_spacing(tmp_path):
    """A 20 m lattice: the nominal spacing is measured over the occupied area, the SMRF cell follows it."""

    g = np.arange(0.0, 1000.0, 20.0)
    x, y = (v.ravel() for v in np.meshgrid(g, g))
    x, y = np.append(x, 30_000.0) + 440_000.0, np.append(y, 0.0) + 4_000_000.0
    stray = np.arange(len(x)) == len(x) - 1  # a stray point 30 km away counts neither as area nor as a point
    path = _write_las(tmp_path / "lattice.las", x, y, np.full(len(x), 100.0), scale=0.001, withheld=stray)
    spacing = nominal_spacing(path, 1.0, cloud_info(path))
    assert spacing == pytest.approx(20.0, rel=0.1)
    assert for_spacing(SmrfParams(name="smrf"), spacing).cell_size == math.ceil(spacing)
    coarse = SmrfParams(name="smrf", cell_size=50.0)  # a 20 m spacing is dense for 50 m cells
    assert for_spacing(coarse, nominal_spacing(path, 50.0, cloud_info(path))) is coarse


def _run_las(tmp_path: Path, path: Path | list[Path], *sets: str) -> tuple[int, Path]:
    out = tmp_path / "out"
    paths = ",".join(str(p) for p in (path if isinstance(path, list) else [path]))
    args = ["run", str(ROOT / "configs" / "las.yaml"), "-q", "--set", f"input.paths=[{paths}]"]
    for s in (f"output={out}", f"cache={tmp_path / 'cache'}", "stages.accuracy.enabled=false", *sets):
        args += ["--set", s]
    return main(args), out


def test_a_wide_sparse_survey_is_refused_at_once(tmp_path, capsys):
    """100 points over 50 x 50 km: one sentence right after reading, not a MemoryError hours later."""
    rng = np.random.default_rng(3)
    x, y = 400_000 + rng.uniform(0, 50_000, 100), 4_400_000 + rng.uniform(0, 50_000, 100)
    path = _write_las(tmp_path / "wide.las", x, y, rng.uniform(600, 700, 100))
    code, out = _run_las(tmp_path, path)
    err = capsys.readouterr().err
    assert code == 2 and "stages.rasterize.resolution: 1 m cells" in err and str(path) in err
    run = json.loads((out / "run.json").read_text())
    assert [s["name"] for s in run["stages"] if s.get("status") == "ran"] == []  # refused in parse


def test_a_dtm_without_a_valid_cell_is_an_error(tmp_path, capsys):
    """utm17.las with last_returns off: 10 collinear ground points make no surface — exit 3, not an "ok" run."""
    path = real("pdal/utm17.las")
    code, out = _run_las(tmp_path, path, "stages.classify_ground.last_returns=false", "executor.workers=1")
    err = capsys.readouterr().err
    assert code == 3 and "the DTM has no valid cell" in err and str(path) in err
    assert json.loads((out / "run.json").read_text())["status"] == "failed" and not (out / "dtm.tif").exists()


def test_empty_strip_difference_maps_are_not_published(tmp_path):
    """One strip, no overlap: no all-nodata strip_difference_*.tif in the output folder, and run.json says so."""
    rng = np.random.default_rng(5)
    n = 20_000
    x, y = 440_000 + rng.uniform(0, 100, n), 4_474_000 + rng.uniform(0, 100, n)
    z = 600 + 0.05 * (x - 440_000) + rng.normal(0, 0.02, n)
    path = _write_las(tmp_path / "one_strip.las", x, y, z, scale=0.001, point_source_id=np.full(n, 7, np.uint16))
    code, out = _run_las(tmp_path, path, "executor.workers=1", "stages.report.enabled=false")
    assert code == 0
    products = json.loads((out / "run.json").read_text())["products"]
    assert "dtm.tif" in products and not any(name.startswith("strip_difference") for name in products)
    assert not list(out.glob("strip_difference*"))


def test_an_empty_file_is_named(tmp_path, capsys):
    path = real("pdal/no-points.las")
    code, out = _run_las(tmp_path, path)
    err = capsys.readouterr().err
    assert code == 3 and str(path) in err and "no point" in err and "Traceback" not in err
    assert not (out / "dtm.tif").exists()


#: What every real file must give: exit 0 (with these keys where the file needs them), or exit 3 and the cause.
EXPECTED = {
    "laspy/fullwave.laz": (0, []),
    "laspy/simple1_4.las": (3, ["not longitudes and latitudes"]),
    "lidR/Megaplot.laz": (0, []),
    "lidR/MixedConifer.laz": (0, []),
    "lidR/Topography.laz": (0, []),
    "pdal/1.2-with-color.las": (0, ["input.crs=EPSG:2992"]),
    "pdal/autzen_trim.las": (0, []),
    "pdal/epsg_4326.las": (0, []),
    "pdal/gps-time-nan.las": (3, ["has no CRS"]),
    "pdal/lone-star.laz": (0, ["input.override_crs=EPSG:26912"]),
    "pdal/mvk-thin.las": (0, []),
    "pdal/no-points.las": (3, ["no point"]),
    "pdal/sample_c.las": (0, ["input.crs=EPSG:2994"]),
    "pdal/spurious.las": (0, []),
    "pdal/utm17.las": (3, ["last or single return"]),
    "pdal/warsaw_small.las": (0, ["input.override_crs=EPSG:2180"]),
    "ign/pont.laz": (0, []),
    "ign/bat.laz": (0, []),
    "ign/crop_1.laz": (0, []),
    "ign/crop_2.laz": (0, []),
    "ahn/AHN3.laz": (0, ["input.crs=EPSG:28992"]),  # no CRS in the header: RD New (+ NAP heights)
    "lasR/bcts_1.laz": (0, []),
    "lasR/bcts_2.laz": (0, []),
    "lasR/bcts_3.laz": (0, []),
    "lasR/bcts_4.laz": (0, []),
}

#: The vertical CRS a file's header names (the others name none).
VERTICAL = {"lasR/bcts_1.laz": "CGVD28 height (EPSG:5713)"}

#: Files that are tiles of one project: run once, together, in the slow test (the first file names the run).
PROJECTS = {"lasR/bcts_1.laz": ["lasR/bcts_1.laz", "lasR/bcts_2.laz", "lasR/bcts_3.laz", "lasR/bcts_4.laz"]}
_IN_A_PROJECT = {name for files in PROJECTS.values() for name in files[1:]}


def test_the_table_covers_every_real_file():
    files = {f"{p.parent.name}/{p.name}" for p in REAL.rglob("*") if p.suffix.lower() in (".las", ".laz")}
    assert files == set(EXPECTED)
    assert all(EXPECTED[f] == EXPECTED[files[0]] for files in PROJECTS.values() for f in files)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(EXPECTED) - _IN_A_PROJECT))
def test_every_real_file_runs_or_says_why(tmp_path, capsys, name):
    """Exit 0 with a DTM sized by the points, or exit 3 with one sentence naming the file and the cause."""

    code_wanted, extra = EXPECTED[name]
    paths = [real(f) for f in PROJECTS.get(name, [name])]
    sets = [s for s in extra if "=" in s]
    cheap = ["executor.workers=1", "stages.hillshade.enabled=false", "stages.contours.enabled=false"]
    code, out = _run_las(tmp_path, paths, *sets, *cheap, "stages.report.enabled=false")
    err = capsys.readouterr().err
    assert code == code_wanted, err
    assert "Traceback" not in err
    if code == 3:
        lines = [ln for ln in err.splitlines() if "error" in ln]
        assert len(lines) == 1 and str(paths[0].name) in lines[0], err
        assert all(s in lines[0] for s in extra if "=" not in s), lines[0]
        return
    run = json.loads((out / "run.json").read_text())
    assert run["status"] == "ok"
    las = laspy.read(out / "points.laz")
    usable = ~np.asarray(las.withheld, dtype=bool) & ~np.isin(np.asarray(las.classification), (7, 18))
    with rasterio.open(out / "dtm.tif") as dtm:
        b = dtm.bounds
        cell = dtm.res[0]
        assert dtm.read(1, masked=True).count() > 0
        datum = dtm.tags()["VERTICAL_DATUM"]
    # the vertical CRS the file's GeoKeys name (bcts: CGVD28 in VerticalCSTypeGeoKey), else unknown, with
    # a warning naming the key that states it
    assert datum == VERTICAL.get(name, "unknown: the input names no vertical CRS")
    assert ("names no vertical CRS" in err) == (name not in VERTICAL)
    x, y = np.asarray(las.x)[usable], np.asarray(las.y)[usable]
    # the grid covers the usable points and no more than a cell beyond them
    assert b.left <= x.min() and x.max() <= b.right and b.bottom <= y.min() and y.max() <= b.top
    assert b.left > x.min() - cell and b.right < x.max() + 2 * cell
    assert b.bottom > y.min() - 2 * cell and b.top < y.max() + cell
