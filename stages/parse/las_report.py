"""What reading the LAS/LAZ inputs counted, repaired and assumed: :class:`LasReadReport`.

Filled by :mod:`stages.parse.read_las` (and by the header index,
:meth:`stages.parse.las_index.HeaderIndex.file_crs`, with how each file's
CRS was read); the parse stage logs it and puts it in its metrics.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class LasReadReport:
    """Counters of one read: points per file and what was assumed."""

    points: dict[str, int] = field(default_factory=dict)
    crs_source: dict[str, str] = field(default_factory=dict)
    gps_time_missing: list[str] = field(default_factory=list)
    #: Per file: points whose return number was 0 (invalid in LAS), read as 1.
    return_number_zero: dict[str, int] = field(default_factory=dict)
    #: Per file: the points kept in points.las (those read less those outside the header's bounds).
    kept: dict[str, int] = field(default_factory=dict)
    #: Per file: points outside the header's bounds (damaged records or strays), left out of points.las.
    outside_header_bounds: dict[str, int] = field(default_factory=dict)
    #: Per file: (points the header announces, records the file holds) when it holds more; all are read.
    header_count_short: dict[str, tuple[int, int]] = field(default_factory=dict)
    #: Points far from the survey's dense core (inside the header's bounds), flagged withheld.
    far_from_survey: int = 0
    #: Horizontal box (xmin, ymin, xmax, ymax, output CRS units) of the points not withheld as stray.
    usable_box: list[float] | None = None
    #: Per file: why its header CRS was not used (unreadable: input.crs used instead).
    crs_notes: dict[str, str] = field(default_factory=dict)
    #: Per file: how its header CRS was read (GeoKey units honoured, as GDAL reads them).
    crs_read_as: dict[str, str] = field(default_factory=dict)
    dropped: list[str] = field(default_factory=list)
