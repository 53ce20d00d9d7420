"""What ``pipeline validate`` warns of in a valid LAS configuration: check points that are not the survey's.

A configuration copied from another survey (the README's sample, say)
keeps that survey's check points; the run would then measure nothing
and say so only in its report.  Here the check points are compared with
the extent the files' headers announce, in the output CRS, before
anything runs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pyproj

from lidar.checkpoints import read_checkpoints
from pipeline.errors import InputDataError
from stages.parse.las_index import read_headers
from stages.parse.read_las import header_bounds, output_crs_of


def configuration_warnings(config) -> list[str]:
    """The sentences ``validate`` prints as warnings for *config* (a valid configuration); [] for none.

    Only the LAS format is checked (a raw flight's extent is known once it
    is georeferenced); files or check points that cannot be read are the
    run's to refuse, in its own words.
    """
    inp, acc = config.input, getattr(config.stages, "accuracy", None)
    if inp.format != "las" or acc is None or not acc.enabled or acc.checkpoints is None:
        return []
    try:
        points, _ = read_checkpoints(acc.checkpoints, acc.land_cover_column)
        index = read_headers(list(inp.paths))
        assign = pyproj.CRS.from_user_input(inp.crs) if inp.crs else None
        override = pyproj.CRS.from_user_input(inp.override_crs) if inp.override_crs else None
        first = inp.paths[0]
        target = output_crs_of(config.crs, index.file_crs(first, assign, override)[0], index.header(first))
        lo, hi = header_bounds(list(inp.paths), target, assign, override, index)
    except InputDataError:
        return []
    return checkpoints_outside(points[:, :2], lo[:2], hi[:2], Path(acc.checkpoints))


def checkpoints_outside(xy: np.ndarray, lo, hi, path: Path) -> list[str]:
    """The warning when check points *xy* lie outside the box *lo*..*hi* (the survey's, same CRS); else []."""
    outside = ~np.all((xy >= lo) & (xy <= hi), axis=1)
    n = int(outside.sum())
    if n == 0:
        return []
    return [
        f"stages.accuracy.checkpoints {path}: {n} of {len(xy)} check points lie outside the survey's extent "
        f"(x {lo[0]:,.2f} to {hi[0]:,.2f}, y {lo[1]:,.2f} to {hi[1]:,.2f}), so they measure nothing there; "
        "give this survey's check points, or set stages.accuracy.enabled=false."
    ]
