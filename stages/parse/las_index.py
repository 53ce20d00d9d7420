"""The header index of a LAS project: every input's header read once, in parallel.

:func:`read_headers` opens each input with the project's guarded opener
(:func:`lidar.las_guard.open_las`: the header's sizes checked against
the file first), keeps its header and closes it, on a pool of threads
(reading headers waits on the disk, not on Python).  The parse stage then
asks the index, not the files, for the point layout, the counts, the
bounds and the CRS (:func:`file_crs`, worked out once per file); each file
is opened once more, to read its points.
:func:`write_input_files_csv` publishes the index as ``qc/input_files.csv``
(:mod:`lidar.input_files`).
"""

from __future__ import annotations

import csv
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from lidar.crs import crs_problem, header_crs
from lidar.input_files import CSV_COLUMNS
from lidar.las_guard import header_mins_maxs, open_las
from pipeline.errors import InputDataError
from stages.parse.las_report import LasReadReport

if TYPE_CHECKING:
    import laspy
    import pyproj

#: Most threads reading headers at a time (the disk, not the cores, is the limit).
MAX_THREADS = 8


@dataclass
class InputHeader:
    """One input file as its header describes it."""

    path: Path
    bytes: int
    header: laspy.LasHeader

    @property
    def points(self) -> int:
        """The points the header announces."""
        return int(self.header.point_count)


@dataclass
class HeaderIndex:
    """The headers of the input files, in the order of ``input.paths``, and each file's CRS once read."""

    files: list[InputHeader]
    _crs: dict[tuple, tuple] = field(default_factory=dict, repr=False)
    _parsed: dict[tuple, tuple] = field(default_factory=dict, repr=False)
    _by_path: dict[Path, InputHeader] = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self._by_path = {f.path: f for f in self.files}

    @property
    def paths(self) -> list[Path]:
        return [f.path for f in self.files]

    @property
    def headers(self) -> list[tuple[Path, laspy.LasHeader]]:
        """``(path, header)`` of every file, in order."""
        return [(f.path, f.header) for f in self.files]

    def header(self, path: Path) -> laspy.LasHeader:
        """The header of the input *path*."""
        return self._by_path[Path(path)].header

    def total_points(self) -> int:
        """The points the headers announce, together."""
        return sum(f.points for f in self.files)

    def file_crs(
        self,
        path: Path,
        assign: pyproj.CRS | None,
        override: pyproj.CRS | None = None,
        report: LasReadReport | None = None,
    ) -> tuple[pyproj.CRS, str]:
        """:func:`file_crs` of the input *path*, worked out once per file and settings.

        Its notes (how the header CRS was read, why it was not used) go
        into *report* every time, as the function itself puts them.
        """
        key = (str(path), _crs_key(assign), _crs_key(override))
        if key not in self._crs:
            own = LasReadReport()
            crs, source = file_crs(Path(path), self.header(path), assign, override, own, self._header_crs)
            self._crs[key] = (crs, source, own.crs_read_as.get(str(path)), own.crs_notes.get(str(path)))
        crs, source, read_as, note = self._crs[key]
        if report is not None:
            if read_as is not None:
                report.crs_read_as[str(path)] = read_as
            if note is not None:
                report.crs_notes[str(path)] = note
        return crs, source

    def _header_crs(self, header) -> tuple:
        """:func:`lidar.crs.header_crs`, parsed once per distinct set of CRS records (pyproj: ~20 ms each)."""
        key = _crs_records(header)
        if key not in self._parsed:
            try:
                self._parsed[key] = (header_crs(header), None)
            except Exception as exc:  # what laspy raises for an unreadable CRS: raised for every file that has it
                self._parsed[key] = (None, exc)
        result, error = self._parsed[key]
        if error is not None:
            raise error
        return result


def file_crs(
    path: Path,
    header: laspy.LasHeader,
    assign: pyproj.CRS | None,
    override: pyproj.CRS | None = None,
    report: LasReadReport | None = None,
    read_crs=header_crs,
) -> tuple[pyproj.CRS, str]:
    """The CRS of one file's coordinates and where it came from, checked against them.

    ``input.override_crs`` (*override*) replaces whatever the header says;
    otherwise the header's CRS, and ``input.crs`` (*assign*) for a header
    without one — or with one that cannot be read (an empty WKT), noted in
    the *report*.  The coordinates the header's bounds announce must be possible
    in that CRS (:func:`lidar.crs.crs_problem`), or the file is refused
    with the key that fixes it.  *read_crs* reads the header's CRS
    (:func:`lidar.crs.header_crs`; the header index passes one that
    reads each distinct CRS record once).
    """
    if override is not None:
        crs, source = override, "input.override_crs"
    else:
        try:
            crs, note = read_crs(header)
            source = "header"
            if note is not None and report is not None:
                report.crs_read_as[str(path)] = note
        except Exception as exc:
            if assign is None:
                raise InputDataError(
                    f"{path}: the CRS in the LAS header cannot be read ({exc}); set input.override_crs "
                    "to the CRS of its coordinates (for example EPSG:2180)."
                ) from None
            crs, source = None, "input.crs"
            if report is not None:
                report.crs_notes[str(path)] = f"header CRS unreadable ({exc}); input.crs used"
        if crs is None:
            if assign is None:
                raise InputDataError(
                    f"{path}: the LAS header has no CRS; set input.crs in the configuration (for example EPSG:25830)."
                )
            crs, source = assign, "input.crs"
    _check_fits(path, header, crs, source)
    return crs, source


def _check_fits(path: Path, header, crs, source: str) -> None:
    """Refuse a file whose header bounds cannot be coordinates in *crs* (one sentence with the way out)."""
    if int(header.point_count) == 0:
        return
    problem = crs_problem(crs, *header_mins_maxs(header))
    if problem is None:
        return
    if source == "header":
        way = "the header's CRS is wrong: set input.override_crs to the CRS the coordinates are in"
    else:
        way = f"the CRS given in {source} does not fit them: set {source} to the CRS the coordinates are in"
    raise InputDataError(f"{path}: {problem}; {way}.")


def _crs_records(header) -> tuple:
    """What a header's CRS is read from: its ``LASF_Projection`` (E)VLRs, as bytes."""
    out = []
    for v in [*header.vlrs, *(header.evlrs or [])]:
        if str(v.user_id).strip("\0 ") == "LASF_Projection":
            data = v.record_data_bytes() if hasattr(v, "record_data_bytes") else bytes(v.record_data)
            out.append((type(v).__name__, int(v.record_id), bytes(data)))
    return tuple(out)


def _crs_key(crs) -> str | None:
    return None if crs is None else crs.to_wkt()


def _read_one(path: Path) -> InputHeader:
    with open_las(path) as reader:
        return InputHeader(Path(path), Path(path).stat().st_size, reader.header)


def read_headers(paths: list[Path], threads: int = MAX_THREADS) -> HeaderIndex:
    """Read the header of every file of *paths* once, *threads* at a time; the index in the order of *paths*.

    Raises the :class:`~pipeline.errors.InputDataError` of the first
    unreadable file in the order of *paths* (:func:`~lidar.las_guard.open_las`).
    """
    if len(paths) <= 1 or threads <= 1:
        return HeaderIndex([_read_one(p) for p in paths])
    with ThreadPoolExecutor(max_workers=min(threads, len(paths)), thread_name_prefix="las-header") as pool:
        return HeaderIndex(list(pool.map(_read_one, paths)))


def gps_time_type_name(header) -> str:
    """``standard``, ``week`` (global encoding bit 0) or ``none`` (the point format has no GPS time)."""
    if "gps_time" not in header.point_format.dimension_names:
        return "none"
    return "standard" if int(header.global_encoding.gps_time_type) else "week"


def write_input_files_csv(
    dst: Path,
    index: HeaderIndex,
    points: dict[str, int],
    kept: dict[str, int],
    crs_names: dict[str, str],
) -> None:
    """``qc/input_files.csv``: one row per input file (:data:`CSV_COLUMNS`), in the order of the points.

    *points*: records read per file (the header's count, or more when it
    announces fewer than the file holds); *kept*: those parse kept (the
    points it left out are the strays outside the header's bounds);
    *crs_names*: the CRS each file's coordinates were read in.  Bounds are
    the header's, in the file's own CRS.
    """
    with open(dst, "w", newline="", encoding="utf-8") as fh:
        out = csv.writer(fh, lineterminator="\n")
        out.writerow(CSV_COLUMNS)
        for f in index.files:
            key = str(f.path)
            mins, maxs = header_mins_maxs(f.header)
            bounds = [repr(float(v)) for v in (*mins, *maxs)]
            out.writerow(
                [
                    key,
                    f.bytes,
                    points.get(key, f.points),
                    kept.get(key, 0),
                    *bounds,
                    f.header.point_format.id,
                    gps_time_type_name(f.header),
                    crs_names.get(key, ""),
                ]
            )
