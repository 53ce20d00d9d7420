"""Format 3.D: already georeferenced LAS/LAZ (LAS 1.2 to 1.4, any point format).

Files are read in chunks and normalised to LAS 1.4 in the output CRS, in
the point records of :func:`stages.parse.las_layout.point_layout`
(format 6, 7 or 8, the extra bytes every input has).  The CRS of each file
(:func:`stages.parse.las_index.file_crs`) is checked against its coordinates; what is
repaired or assumed is counted in a :class:`~stages.parse.las_report.LasReadReport`
(what cannot be kept is named in its ``dropped``).  :func:`convert_las_files` writes
the stage's ``points.las``, copying one file already in the output's form
record for record (:func:`copy_records`).  The rules: ``docs/stages/parse.md``.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import laspy
import numpy as np
import pyproj

from lidar.clouds import PointLayout, open_las_writer, point_header, progress_chunk
from lidar.crs import output_crs
from lidar.las_guard import check_strays, header_box, header_mins_maxs, open_las, read_chunks
from lidar.units import Units
from pipeline.errors import InputDataError
from pipeline.log import Progress
from stages.parse.isolated import IsolationGrid, Withheld, withhold_isolated
from stages.parse.las_index import HeaderIndex, file_crs, read_headers
from stages.parse.las_layout import READ_APART, copied_dimensions, point_layout
from stages.parse.las_report import LasReadReport

#: Largest extent accepted in any axis (m): twice the Earth's diameter.
MAX_SPAN_M = 2.6e7
#: Scan-angle unit of point formats 6-10 (LAS 1.4: 0.006 degree).
SCAN_ANGLE_UNIT_DEG = 0.006


def count_points(paths: list[Path]) -> int:
    """Number of points the headers of *paths* announce (for progress only)."""
    total = 0
    for path in paths:
        with open_las(path) as reader:
            total += int(reader.header.point_count)
    return total


def las_chunks(
    paths: list[Path],
    *,
    crs_setting: str,
    assign_crs: pyproj.CRS | None,
    chunk_size: int,
    report: LasReadReport,
    progress: Progress | None = None,
    layout: PointLayout | None = None,
    override_crs: pyproj.CRS | None = None,
    index: HeaderIndex | None = None,
) -> Iterator[tuple[pyproj.CRS, dict[str, np.ndarray]]]:
    """Read LAS/LAZ files chunk by chunk, in the output CRS; the *report* is filled as they are read.

    Yields
    ------
    crs : pyproj.CRS
        The output CRS (the same for every chunk).
    columns : dict
        ``x``, ``y``, ``z`` (float64, output CRS), ``scan_angle`` (degrees), ``gps_time`` and the attributes
        the *layout* (default: :func:`point_layout`) holds, repaired (:func:`_repair`); extra bytes unscaled.

    Raises
    ------
    InputDataError
        When a file is not LAS/LAZ, is truncated, or has no usable CRS.

    The headers and CRSs are the *index*'s (:mod:`stages.parse.las_index`;
    read here when it is not given): each file is opened once, for its points.
    """

    if index is None:
        index = read_headers(paths)
    if layout is None:
        layout, report.dropped = point_layout(paths, index)
    target = None
    for path in paths:
        with open_las(path, check=False) as reader:  # the index checked its header
            header = reader.header
            src_crs, source = index.file_crs(path, assign_crs, override_crs, report)
            report.crs_source[str(path)] = source
            _read_all_records(path, header, report)
            if target is None:
                target = output_crs_of(crs_setting, src_crs, header)
            for cols in _file_chunks(path, reader, src_crs, target, layout, chunk_size, report, progress):
                yield target, cols


def output_crs_of(crs_setting: str, src_crs, header):
    """The output CRS for a first file in *src_crs* (the centre of its bounds picks a UTM zone)."""
    centre = None
    if not src_crs.is_projected:
        centre = (float((header.mins[0] + header.maxs[0]) / 2), float((header.mins[1] + header.maxs[1]) / 2))
    return output_crs(crs_setting, src_crs, centre)


def _file_chunks(
    path: Path, reader, src_crs, target, layout: PointLayout, chunk_size: int, report: LasReadReport, progress
) -> Iterator[dict[str, np.ndarray]]:
    """The columns of one file's chunks (see :func:`las_chunks`), repaired; its points counted in *report*."""
    header = reader.header
    bounds = header_box(header)
    transformer = None
    if not src_crs.equals(target):
        transformer = pyproj.Transformer.from_crs(src_crs, target, always_xy=True)
    dims = set(header.point_format.dimension_names)
    if "gps_time" not in dims:
        report.gps_time_missing.append(str(path))
    copied = copied_dimensions(layout)
    n_read = n_kept = 0
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for chunk in read_chunks(path, reader, chunk_size):
        x, y, z = np.asarray(chunk.x), np.asarray(chunk.y), np.asarray(chunk.z)
        n = len(chunk)
        keep = ~_strays(path, header, bounds, (x, y, z), n_read, report)
        n_kept += int(keep.sum())
        cols = _coordinates(path, (x[keep], y[keep], z[keep]), transformer, n_read, src_crs, target)
        if keep.any():
            xyz = (cols["x"], cols["y"], cols["z"])
            lo, hi = _extend(path, lo, hi, [v.min() for v in xyz], [v.max() for v in xyz], target)
        cols.update({k: v[keep] for k, v in _attributes(chunk, dims, copied, layout).items()})
        _repair(path, cols, report)
        _grow_box(report, cols["x"], cols["y"])
        n_read += n
        if progress is not None:
            progress.update(n)
        yield cols
    report.points[str(path)] = n_read
    report.kept[str(path)] = n_kept


def _coordinates(path: Path, xyz: tuple, transformer, first: int, src_crs, target) -> dict[str, np.ndarray]:
    """A chunk's coordinates in the output CRS (float64); one that is not finite there is an error.

    *first* is the number of the chunk's first point in the file, for the message.
    """
    x, y, z = xyz
    raw_ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    if transformer is not None:
        x, y, z = transformer.transform(x, y, z)
    bad = ~(np.isfinite(x) & np.isfinite(y) & np.isfinite(z))
    if bad.any():
        i = int(np.argmax(bad))
        why = (
            f"cannot be transformed from {src_crs.name} to {target.name} (outside the area of either?)"
            if raw_ok[i]
            else "are not finite numbers (damaged scale or offset in the header?)"
        )
        raise InputDataError(f"{path}: the coordinates of point {first + i} {why}.")
    return {
        "x": np.asarray(x, dtype=np.float64),
        "y": np.asarray(y, dtype=np.float64),
        "z": np.asarray(z, dtype=np.float64),
    }


def _attributes(chunk, dims: set[str], copied: list[str], layout: PointLayout) -> dict[str, np.ndarray]:
    """A chunk's scan angle (degrees), GPS time (0 when the file has none), copied dimensions and extra bytes."""
    n = len(chunk)
    cols = {}
    if "scan_angle" in dims:  # formats 6-10: int16 in 0.006 degree
        cols["scan_angle"] = np.asarray(chunk.scan_angle, dtype=np.float64) * SCAN_ANGLE_UNIT_DEG
    else:  # formats 0-5: scan angle rank, whole degrees
        cols["scan_angle"] = np.asarray(chunk.scan_angle_rank, dtype=np.float64)
    cols["gps_time"] = np.asarray(chunk.gps_time, dtype=np.float64) if "gps_time" in dims else np.zeros(n)
    for name in copied:
        cols[name] = np.asarray(chunk[name]) if name in dims else np.zeros(n, np.uint8)
    for extra in layout.extra:
        cols[extra.name] = np.asarray(chunk.array[extra.name])
    return cols


def _strays(path: Path, header, box, xyz: tuple, first: int, report: LasReadReport) -> np.ndarray:
    """A chunk's points outside the header's bounds (:func:`~lidar.las_guard.check_strays`), counted in *report*."""
    key = str(path)
    stray, report.outside_header_bounds[key] = check_strays(
        path, header, box, xyz, first, report.outside_header_bounds.get(key, 0)
    )
    if not report.outside_header_bounds[key]:
        del report.outside_header_bounds[key]
    return stray


def _repair(path: Path, cols: dict[str, np.ndarray], report: LasReadReport) -> bool:
    """Return number 0 read as 1, counted in *report*.  True if *cols* changed."""
    key = str(path)
    zero = cols["return_number"] == 0
    if zero.any():
        cols["return_number"] = np.where(zero, 1, cols["return_number"]).astype(cols["return_number"].dtype)
        cols["number_of_returns"] = np.maximum(cols["number_of_returns"], 1).astype(cols["number_of_returns"].dtype)
        report.return_number_zero[key] = report.return_number_zero.get(key, 0) + int(zero.sum())
    return bool(zero.any())


def _grow_box(report: LasReadReport, x: np.ndarray, y: np.ndarray) -> None:
    """Grow the report's box of usable points by a chunk's."""
    if len(x) == 0:
        return
    box = [float(x.min()), float(y.min()), float(x.max()), float(y.max())]
    old = report.usable_box
    report.usable_box = box if old is None else [*np.minimum(old[:2], box[:2]), *np.maximum(old[2:], box[2:])]


def _records_held(path: Path, header) -> int | None:
    """How many point records an uncompressed LAS holds (None for LAZ: not known without decompressing).

    The records are the bytes between the point data's offset and the end of
    the file (or the first extended VLR), over the record length.
    """
    if header.point_format.id > 10 or header.are_points_compressed:
        return None
    size = path.stat().st_size
    end = min(int(getattr(header, "start_of_first_evlr", 0) or 0) or size, size)
    record = int(header.point_format.size)
    return max(0, end - int(header.offset_to_point_data)) // record if record else None


def _read_all_records(path: Path, header, report: LasReadReport) -> None:
    """Read every record of an uncompressed LAS even when its header announces fewer (counted in *report*)."""
    held, announced = _records_held(path, header), int(header.point_count)
    if held is not None and held > announced:
        report.header_count_short[str(path)] = (announced, held)
        header.point_count = held


def read_las_files(
    paths: list[Path],
    *,
    crs_setting: str,
    assign_crs: pyproj.CRS | None,
    chunk_size: int,
    progress: Progress | None = None,
    override_crs: pyproj.CRS | None = None,
) -> tuple[laspy.LasData, LasReadReport]:
    """Read LAS/LAZ files into one LasData (LAS 1.4, the layout's point format) in the output CRS.

    Parameters
    ----------
    paths : list of Path
        Input files; their points are concatenated in order.
    crs_setting : str
        The configured output CRS (``auto-utm`` or a pyproj user input).
    assign_crs, override_crs : pyproj.CRS or None
        CRS of files whose header has none; CRS of every file, replacing whatever its header says.
    chunk_size, progress
        Points per read; a Progress advanced by the number of points read (optional).

    Returns the LasData and its :class:`LasReadReport`; InputDataError as :func:`las_chunks`.
    """
    report = LasReadReport()
    layout, report.dropped = point_layout(paths)
    parts: list[dict[str, np.ndarray]] = []
    target = None
    for crs, cols in las_chunks(
        paths,
        crs_setting=crs_setting,
        assign_crs=assign_crs,
        chunk_size=chunk_size,
        report=report,
        progress=progress,
        layout=layout,
        override_crs=override_crs,
    ):
        target = crs
        parts.append(cols)
    if target is None:  # no point at all: still resolve the CRS from the first header
        with open_las(paths[0]) as reader:
            src_crs, _ = file_crs(paths[0], reader.header, assign_crs, override_crs)
            target = output_crs_of(crs_setting, src_crs, reader.header)
    names = ("x", "y", "z", "scan_angle", "gps_time", *copied_dimensions(layout), *(e.name for e in layout.extra))
    merged = {k: (np.concatenate([p[k] for p in parts]) if parts else np.zeros(0)) for k in names}
    return _build(merged, target, layout), report


def header_bounds(
    paths: list[Path],
    target: pyproj.CRS,
    assign_crs: pyproj.CRS | None,
    override_crs: pyproj.CRS | None = None,
    index: HeaderIndex | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The bounds the headers of *paths* announce, in the CRS *target* (for a writer's offsets).

    Horizontal bounds of a file in another CRS are transformed with the
    edges densified (pyproj ``transform_bounds``).  Bounds no survey has (a
    damaged header: :func:`_plausible_bounds`) are left out, lest they make
    the writer's scale coarse; the points are checked against the writer's
    range as they are written (:func:`convert_las_files`).
    """
    if index is None:
        index = read_headers(paths)
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    transformers: dict[str, pyproj.Transformer] = {}
    for path in paths:
        h = index.header(path)
        mins, maxs = header_mins_maxs(h)
        if h.point_count == 0 or not _plausible_bounds(mins, maxs):
            continue
        crs, _ = index.file_crs(path, assign_crs, override_crs)
        if not crs.equals(target):
            wkt = crs.to_wkt()
            if wkt not in transformers:
                transformers[wkt] = pyproj.Transformer.from_crs(crs, target, always_xy=True)
            x0, y0, x1, y1 = transformers[wkt].transform_bounds(mins[0], mins[1], maxs[0], maxs[1], densify_pts=21)
            mins, maxs = np.array([x0, y0, mins[2]]), np.array([x1, y1, maxs[2]])
        lo, hi = np.minimum(lo, mins), np.maximum(hi, maxs)
    return lo, hi


def _plausible_bounds(mins: np.ndarray, maxs: np.ndarray) -> bool:
    """Whether header bounds can be a survey's: finite, not inverted, spanning less than ``MAX_SPAN_M``."""
    if not (np.isfinite(mins).all() and np.isfinite(maxs).all()) or (mins > maxs).any():
        return False
    return float(np.max(maxs - mins)) <= MAX_SPAN_M


def convert_las_files(
    paths: list[Path],
    dst: Path,
    *,
    crs_setting: str,
    assign_crs: pyproj.CRS | None,
    chunk_size: int,
    progress: Progress | None = None,
    override_crs: pyproj.CRS | None = None,
    index: HeaderIndex | None = None,
) -> tuple[pyproj.CRS, LasReadReport, set[int]]:
    """Convert LAS/LAZ files to one uncompressed LAS 1.4 file in the output CRS, chunk by chunk.

    Memory holds one chunk, whatever the survey's size.  The writer's offsets
    and scale come from the headers' bounds (:func:`header_bounds`; from the
    first chunk when no header has usable bounds); a point outside the range
    they allow is an error naming the file.  One file already in the
    output's form is copied record for record (:func:`copy_records`).  The
    points far from the survey are then withheld (:func:`withhold_isolated`).
    The inputs' headers are the *index*'s (read here when it is not given).

    Returns
    -------
    crs, report, strips
        The output CRS, the :class:`LasReadReport`, the point source ids met.
    """

    if index is None:
        index = read_headers(paths)
    report = LasReadReport()
    layout, report.dropped = point_layout(paths, index)
    strips: set[int] = set()
    same = _copyable(paths, crs_setting, assign_crs, layout, override_crs, index)
    if same is not None:
        read = progress_chunk(index.total_points(), chunk_size)  # chunks the progress moves by
        target, grid = copy_records(paths[0], dst, same, report, strips, read, progress, layout)
        _record_withheld(report, withhold_isolated(dst, counted=grid))
        return target, report, strips
    writer = None
    target = None
    try:
        for target, cols in las_chunks(
            paths,
            crs_setting=crs_setting,
            assign_crs=assign_crs,
            chunk_size=_read_chunk(paths, crs_setting, assign_crs, override_crs, index, chunk_size),
            report=report,
            progress=progress,
            layout=layout,
            override_crs=override_crs,
            index=index,
        ):
            if writer is None:
                header = _output_header(paths, target, cols, layout, assign_crs, override_crs, index)
                writer = open_las_writer(dst, header)
            if not len(cols["x"]):
                continue
            _check_range(cols, header, paths)
            writer.write_points(_record(cols, header))
            strips.update(int(v) for v in np.unique(cols["point_source_id"]))
        if writer is None:  # no point at all: an empty file with the output CRS
            las, _ = read_las_files(
                paths, crs_setting=crs_setting, assign_crs=assign_crs, chunk_size=chunk_size, override_crs=override_crs
            )
            target = las.header.parse_crs()
            writer = open_las_writer(dst, point_header(target, layout=layout))
    finally:
        if writer is not None:
            writer.close()
    _record_withheld(report, withhold_isolated(dst))
    return target, report, strips


def _read_chunk(
    paths: list[Path], crs_setting: str, assign_crs, override_crs, index: HeaderIndex, chunk_size: int
) -> int:
    """Points converted at a time: chunks the progress moves by (:func:`~lidar.clouds.progress_chunk`), unless the
    output's header comes from the first chunk (no input header has usable bounds: :func:`_output_header`)."""
    crs, _ = index.file_crs(paths[0], assign_crs, override_crs)
    lo, _ = header_bounds(
        paths, output_crs_of(crs_setting, crs, index.header(paths[0])), assign_crs, override_crs, index
    )
    return progress_chunk(index.total_points(), chunk_size) if np.isfinite(lo).all() else chunk_size


def _output_header(
    paths: list[Path], target, cols: dict[str, np.ndarray], layout: PointLayout, assign_crs, override_crs, index
):
    """The converted file's header: offsets and scale from the inputs' header bounds, else from the first chunk."""
    n = len(cols["x"])
    lo, hi = header_bounds(paths, target, assign_crs, override_crs, index)
    if not np.isfinite(lo).all():
        lo = np.array([cols[k].min() for k in "xyz"]) if n else None
        hi = np.array([cols[k].max() for k in "xyz"]) if n else None
    return point_header(target, lo, hi, layout=layout)


def _check_range(cols: dict[str, np.ndarray], header, paths: list[Path]) -> None:
    """Refuse points the header's scale and offsets cannot store (int32): the input headers' bounds are wrong."""
    for k, axis in zip("xyz", range(3), strict=True):
        units = (cols[k] - header.offsets[axis]) / header.scales[axis]
        if units.min() < -(2.0**31) or units.max() >= 2.0**31:
            raise InputDataError(
                f"the points of {', '.join(str(p) for p in paths)} reach {k} = "
                f"{float(cols[k][np.argmax(np.abs(units))]):.3f}, outside the bounds their LAS headers "
                "announce (a damaged header: bytes 179-226)."
            )


def _record_withheld(report: LasReadReport, far: Withheld | None) -> None:
    """Count the points far from the survey in *report*, with the usable points' new box."""
    if far is not None:
        report.far_from_survey = report.far_from_survey + far.count
        report.usable_box = far.usable_box


def _extend(path: Path, lo, hi, mins, maxs, crs) -> tuple[np.ndarray, np.ndarray]:
    """The running bounds *lo*, *hi* of a file's points grown by a chunk's extremes.

    Extremes that are not finite (a huge scale overflows) or a span beyond
    any survey are errors naming the file.
    """
    if not (np.isfinite(mins).all() and np.isfinite(maxs).all()):
        raise InputDataError(
            f"{path}: points have coordinates that are not finite numbers (damaged scale or offset in the header?)."
        )
    lo, hi = np.minimum(lo, mins), np.maximum(hi, maxs)
    span = Units.of(crs).horizontal * float(np.max(hi - lo))
    if span > MAX_SPAN_M:
        raise InputDataError(
            f"{path}: the points span {span:.3g} m, more than any survey on Earth "
            "(damaged scale or offset in the header?)."
        )
    return lo, hi


def _copyable(paths: list[Path], crs_setting: str, assign_crs, layout: PointLayout, override_crs, index: HeaderIndex):
    """The output CRS when the input can be copied record for record, else None.

    That is one LAS 1.4 file whose records are those of *layout* (point
    format 6, 7 or 8 with its extra bytes), already in the output CRS: its points, scale and offsets are kept as delivered
    (no re-quantisation, nothing recomputed), which is also the fastest.
    """
    if len(paths) != 1:
        return None
    h = index.header(paths[0])
    if str(h.version) != "1.4" or h.point_format.id != layout.point_format:
        return None
    if [e.name for e in layout.extra] != list(h.point_format.extra_dimension_names):
        return None
    if not (np.isfinite(h.mins).all() and np.isfinite(h.maxs).all()) or h.point_count == 0:
        return None
    if (np.asarray(h.scales) < 0).any():
        return None  # a negative scale (allowed by LAS 1.4): converted to the output's positive scales
    if override_crs is not None or (_records_held(paths[0], h) or 0) > h.point_count:
        return None  # the header's CRS or count is not the file's: convert, which handles both
    src_crs, source = index.file_crs(paths[0], assign_crs)
    if source != "header" or not src_crs.is_projected:
        return None
    target = output_crs(crs_setting, src_crs, None)
    return target if target.equals(src_crs) else None


def copy_records(
    path: Path,
    dst: Path,
    target: pyproj.CRS,
    report: LasReadReport,
    strips: set[int],
    chunk_size: int,
    progress: Progress | None,
    layout: PointLayout,
) -> tuple[pyproj.CRS, IsolationGrid | None]:
    """Copy one LAS/LAZ file's records as they are to an uncompressed LAS (see :func:`_copyable`).

    Returns the output CRS and the points counted on the isolation grid over
    the input header's bounds (:class:`IsolationGrid`; None when those bounds
    are unusable or a point lies outside them): the output's bounds are its
    points' extremes, so when the header's were right the count is the one
    :func:`withhold_isolated` needs, without a pass of its own.
    """

    n_read = n_kept = 0
    with open_las(path, check=False) as reader:  # the header index checked its header
        h = reader.header
        report.crs_source[str(path)] = "header"
        box = header_box(h)
        header = point_header(target, layout=layout)
        header.offsets, header.scales = h.offsets, h.scales
        lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
        seen = np.zeros(65536, dtype=bool)
        spans = np.asarray(h.maxs[:2], dtype=np.float64) - np.asarray(h.mins[:2], dtype=np.float64)
        usable = box is not None and spans.min() >= 0 and spans.max() > 0 and (np.asarray(h.scales[:2]) > 0).all()
        grid = IsolationGrid(h.mins, h.maxs) if usable else None
        with open_las_writer(dst, header) as writer:
            for chunk in read_chunks(path, reader, chunk_size):
                n = len(chunk)
                x, y = np.asarray(chunk.x), np.asarray(chunk.y)
                stray = _strays(path, h, box, (x, y, np.asarray(chunk.z)), n_read, report)
                if stray.any():
                    chunk, x, y = chunk[~stray], x[~stray], y[~stray]
                n_kept += len(chunk)
                if len(chunk):
                    seen |= np.bincount(np.asarray(chunk.point_source_id), minlength=65536) > 0
                    cols = {k: np.asarray(chunk[k]) for k in ("return_number", "number_of_returns")}
                    if _repair(path, cols, report):
                        for k, v in cols.items():
                            chunk[k] = v
                    _grow_box(report, x, y)
                    writer.write_points(chunk)
                    # the writer's header holds the extremes of the points written so far
                    lo, hi = _extend(path, lo, hi, writer.header.mins, writer.header.maxs, target)
                    if grid is not None and grid.covers((lo[0], hi[0]), (lo[1], hi[1])):
                        grid.add(x, y)
                    else:
                        grid = None
                n_read += n
                if progress is not None:
                    progress.update(n)
    report.points[str(path)] = n_read
    report.kept[str(path)] = n_kept
    strips.update(int(v) for v in np.flatnonzero(seen))
    return target, grid


def _record(cols: dict[str, np.ndarray], header):
    """A chunk of columns as a point record for *header* (format 6-8, extra bytes as stored)."""
    n = len(cols["x"])
    rec = laspy.ScaleAwarePointRecord.zeros(n, header=header)
    rec.x, rec.y, rec.z = cols["x"], cols["y"], cols["z"]
    rec.scan_angle = np.clip(np.round(cols["scan_angle"] / SCAN_ANGLE_UNIT_DEG), -30000, 30000).astype(np.int16)
    rec.gps_time = cols["gps_time"]
    standard = set(header.point_format.standard_dimension_names)
    for name, values in cols.items():
        if name in standard and name not in READ_APART:
            rec[name] = values
        elif name not in standard and name not in ("x", "y", "z", "scan_angle", "gps_time"):
            rec.array[name] = values  # an extra-byte dimension, unscaled
    return rec


def _build(cols: dict[str, np.ndarray], crs, layout: PointLayout):
    n = len(cols["x"])
    if n:
        xyz = np.column_stack((cols["x"], cols["y"], cols["z"]))
        header = point_header(crs, xyz.min(axis=0), xyz.max(axis=0), layout=layout)
    else:
        header = point_header(crs, layout=layout)
    las = laspy.LasData(header)
    las.points = _record(cols, header)
    return las
