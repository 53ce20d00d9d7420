"""``qc/input_files.csv``: the table of a LAS project's input files, one row per file, in the order of the points.

The parse stage writes it from its header index
(:func:`stages.parse.las_index.write_input_files_csv`); ``export_las``
reads it back to cut the classified cloud into its input files
(``files: per_input``: each file's kept points), and the dry run's tile
plan (:mod:`stages.tile_plan`) for the bounds each file had in the last run.
"""

from __future__ import annotations

import csv
from pathlib import Path

#: The columns of ``qc/input_files.csv``, in order.
CSV_COLUMNS = (
    "path",
    "bytes",
    "points",
    "points_kept",
    "xmin",
    "ymin",
    "zmin",
    "xmax",
    "ymax",
    "zmax",
    "point_format",
    "gps_time_type",
    "crs",
)


def read_input_files_csv(src: Path) -> list[dict[str, str]]:
    """The rows of a ``qc/input_files.csv`` (:func:`stages.parse.las_index.write_input_files_csv`), in order."""
    with open(src, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))
