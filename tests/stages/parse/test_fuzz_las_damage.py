"""Seeded damage to two real files (one LAS, one LAZ): a clean read of the true survey, or one sentence naming the file.

Each case overwrites a few bytes of the file at a seeded offset in one of its
parts (the header, the VLRs, the point records, the LAZ chunk table) and runs
the parse stage's conversion on it.  Allowed outcomes: the points written lie
within the intact file's range and every point read is written or counted
(``clean``/``withheld``), or an InputDataError naming the file (``refused``);
never another exception; a time bound proportional to the file's size.  50
cases here, 500 in the slow suite, ``FUZZ_LAS_CASES=2000`` for a campaign
(``pytest -m slow tests/stages/parse/test_fuzz_las_damage.py``).  A handful
run through the CLI (slow suite): exit 0 with a DTM within the survey's
heights, or exit 3 naming the file.
"""

from __future__ import annotations

import collections
import os
import subprocess
import sys
import time
from pathlib import Path

import laspy
import numpy as np
import pyproj
import pytest
import rasterio

from pipeline.errors import InputDataError
from stages.parse.read_las import convert_las_files
from tests.shared_data import REAL

ROOT = Path(__file__).resolve().parents[3]
SOURCES = {"las": REAL / "pdal" / "autzen_trim.las", "laz": REAL / "lidR" / "Topography.laz"}
#: Points kept of each file, read in chunks of ``CHUNK`` (four chunks, as the 4,000 points in chunks of
#: 1,000 this campaign used before: a case's cost is the reader's per-file work, not its points).
POINTS, CHUNK = 1000, 250
#: Seconds a case may take: generous, and proportional to the file's size.
BASE_SECONDS, SECONDS_PER_BYTE = 3.0, 2e-5
CAMPAIGN = int(os.environ.get("FUZZ_LAS_CASES", "500"))


class Intact:
    """A real file cut to ``POINTS`` points, its parts' byte ranges and its points' range."""

    def __init__(self, path: Path):
        self.path = path
        self.blob = path.read_bytes()
        las = laspy.read(path)
        h = las.header
        xyz = np.column_stack((las.x, las.y, las.z))
        scales = np.abs(np.asarray(h.scales))
        self.lo, self.hi = xyz.min(axis=0) - 100 * scales, xyz.max(axis=0) + 100 * scales
        self.tol = 0.01 * (self.hi - self.lo) + 100 * scales  # the reader's tolerance for the header's bounds
        start = int(h.offset_to_point_data)
        self.parts = {"header": (0, 227), "vlrs": (227, start)}
        if h.are_points_compressed:
            table = int.from_bytes(self.blob[start : start + 8], "little")
            self.parts.update(records=(start + 8, table), chunk_table=(table, len(self.blob)))
        else:
            self.parts["records"] = (start, start + len(las) * h.point_format.size)

    def damaged(self, seed: int, folder: Path) -> tuple[Path, str]:
        """The file with 1-16 bytes overwritten at a seeded offset of a seeded part."""
        rng = np.random.default_rng(seed)
        part = str(rng.choice(list(self.parts)))
        a, b = self.parts[part]
        n = int(rng.integers(1, 17))
        at = int(rng.integers(a, max(a + 1, b - n)))
        blob = bytearray(self.blob)
        blob[at : at + n] = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        path = folder / f"{self.path.stem}-{seed}{self.path.suffix}"
        path.write_bytes(bytes(blob))
        return path, part


@pytest.fixture(scope="session")
def intact(tmp_path_factory) -> dict[str, Intact]:
    """The two real files cut to ``POINTS`` points (laspy keeps their records as they are)."""
    folder = tmp_path_factory.mktemp("fuzz-las")
    out = {}
    for kind, src in SOURCES.items():
        las = laspy.read(src)
        cut = laspy.LasData(las.header)
        cut.points = las.points[:POINTS].copy()
        cut.update_header()
        cut.write(folder / f"cut{src.suffix}")
        out[kind] = Intact(folder / f"cut{src.suffix}")
    return out


def _case(intact: Intact, seed: int, folder: Path) -> str:
    """One damaged file through the parse stage's conversion; its outcome, or an AssertionError."""
    path, part = intact.damaged(seed, folder)
    started = time.monotonic()
    try:
        _, report, _ = convert_las_files(
            [path], folder / "points.las", crs_setting="auto-utm", assign_crs=None, chunk_size=CHUNK
        )
    except InputDataError as exc:
        assert path.name in str(exc), f"seed {seed} ({part}): {exc}"
        outcome = "refused"
    else:
        out = laspy.read(folder / "points.las")
        xyz = np.column_stack((out.x, out.y, out.z)) if len(out) else np.zeros((0, 3))
        inside = (xyz >= intact.lo - intact.tol) & (xyz <= intact.hi + intact.tol)
        assert inside.all(), f"seed {seed} ({part}): points outside the survey {xyz[~inside.all(axis=1)][:3]}"
        strays = sum(report.outside_header_bounds.values())
        assert len(out) + strays == sum(report.points.values()), f"seed {seed} ({part}): points not counted"
        outcome = "withheld" if strays or report.far_from_survey else "clean"
    seconds = time.monotonic() - started
    assert seconds < BASE_SECONDS + SECONDS_PER_BYTE * len(intact.blob), f"seed {seed} ({part}): {seconds:.1f} s"
    return outcome


@pytest.fixture
def crs_lookups_once(monkeypatch):
    """pyproj's EPSG lookup (``CRS.to_epsg``) answered once per CRS definition and remembered.

    The lookup searches the whole EPSG database (about 0.1 s) and is a pure function of the CRS's
    definition (``srs``) and the confidence asked; most damaged copies keep the intact CRS, so the
    campaign asked the same question hundreds of times.  The reader's code runs unchanged; a lookup
    that raises is not remembered and raises again.
    """
    lookup, known = pyproj.CRS.to_epsg, {}

    def to_epsg(self, min_confidence=70):
        key = (self.srs, min_confidence)
        if key not in known:
            known[key] = lookup(self, min_confidence)
        return known[key]

    monkeypatch.setattr(pyproj.CRS, "to_epsg", to_epsg)


def _campaign(intact: dict[str, Intact], seeds: range, folder: Path) -> collections.Counter:
    counts: collections.Counter = collections.Counter()
    for seed in seeds:
        for kind in ("las", "laz"):
            counts[kind, _case(intact[kind], seed, folder)] += 1
    return counts


def test_damaged_real_files_read_true_or_are_refused(intact, tmp_path):
    _campaign(intact, range(25), tmp_path)  # 50 cases


@pytest.mark.slow
def test_damaged_real_files_campaign(intact, tmp_path, crs_lookups_once):
    started = time.monotonic()
    counts = _campaign(intact, range(1000, 1000 + CAMPAIGN // 2), tmp_path)
    print(f"\n{sum(counts.values())} cases in {time.monotonic() - started:.0f} s: {dict(sorted(counts.items()))}")


@pytest.mark.slow
@pytest.mark.parametrize("seed", [3, 17, 21])  # LAS: clean, strays, refused; LAZ: clean, refused x2
@pytest.mark.parametrize("kind", ["las", "laz"])
def test_damaged_real_files_through_the_cli(intact, tmp_path, kind, seed):
    """The LAS job up to the DTM: exit 0 with heights within the survey's, or exit 3 naming the file."""
    path, part = intact[kind].damaged(seed, tmp_path)
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "pipeline", "run", str(ROOT / "configs" / "las.yaml"), "--until", "rasterize"]
    for key, value in (("input.paths", f"[{path}]"), ("output", out), ("cache", tmp_path / "cache")):
        cmd += ["--set", f"{key}={value}"]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode in (0, 3), f"{part}: {proc.stderr[-2000:]}"
    if proc.returncode == 3:
        assert path.name in proc.stderr and "Traceback" not in proc.stderr
        return
    with rasterio.open(out / "dtm.tif") as dtm:
        z = dtm.read(1, masked=True).compressed()
    lo, hi = intact[kind].lo[2] - intact[kind].tol[2], intact[kind].hi[2] + intact[kind].tol[2]
    assert z.size and lo <= z.min() and z.max() <= hi, f"{part}: DTM heights {z.min():g} to {z.max():g}"
