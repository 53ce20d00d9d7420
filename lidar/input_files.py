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


def not_a_configuration(path: Path) -> str | None:
    """What to say when a LAS/LAZ file (signature ``LASF``) is given where a configuration is read; else None."""
    try:
        if not path.is_file():  # a FIFO or a device is the engine's to refuse, without opening it
            return None
        with open(path, "rb") as fh:
            signature = fh.read(4)
    except OSError:
        return None
    if signature != b"LASF":
        return None
    return (
        "a LAS/LAZ point cloud, not a configuration; to run the LAS job on it (without the sample's check "
        f"points, into ./out): pipeline run configs/las.yaml --set 'input.paths=[{path.resolve()}]' "
        f"--set output={Path.cwd() / 'out'} --set stages.accuracy.enabled=false."
    )
