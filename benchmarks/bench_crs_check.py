"""The CRS check of a LAS header (``lidar.crs.crs_problem``), ten files' worth, in one process.

    python benchmarks/bench_crs_check.py TREE

*TREE* is the checkout whose ``dtm`` is timed (run it on two checkouts with
the timing tool's pairing, the older one as the baseline).  The CRS is that
of ``../shared/data/real/pdal/autzen_trim.las`` (NAD83 / Oregon GIC Lambert,
international feet, a WKT with no EPSG code), read anew for each file as a
LAS header gives it: pyproj's ``to_epsg()`` searches the EPSG database for
such a CRS (about 0.1 s).  The interpreter's start and imports are the
floor both pay.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, sys.argv[1])

import laspy  # noqa: E402
import pyproj  # noqa: E402

from lidar.crs import crs_problem  # noqa: E402

sys.path.append(str(Path(__file__).resolve().parents[1]))  # after the tree measured: only for the data's place
from tests.shared_data import REAL as SHARED_REAL  # noqa: E402

SOURCE = SHARED_REAL / "pdal" / "autzen_trim.las"

with laspy.open(SOURCE) as reader:
    wkt, lo, hi = reader.header.parse_crs().to_wkt(), reader.header.mins, reader.header.maxs
for _ in range(10):  # a new CRS object a file, as each LAS header gives
    crs_problem(pyproj.CRS.from_wkt(wkt), lo, hi)
