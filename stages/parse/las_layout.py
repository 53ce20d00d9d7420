"""The output point records that keep what every LAS/LAZ input holds (format 6, 7 or 8).

RGB is kept (format 7) when every input has it, NIR too (format 8) when
every input has it; an extra-byte dimension when every input has one of
that name, type, scale and offset; a (E)VLR when every input has the same.
What is dropped gets a note for the log.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import laspy
import numpy as np

from lidar.clouds import PointLayout
from pipeline.errors import InputDataError
from stages.parse.las_index import read_headers

if TYPE_CHECKING:
    from stages.parse.las_index import HeaderIndex

#: Dimensions read apart: coordinates (scaled, transformed), the scan angle (two encodings), the GPS time.
READ_APART = frozenset({"X", "Y", "Z", "scan_angle", "scan_angle_rank", "gps_time"})


def point_layout(paths: list[Path], index: HeaderIndex | None = None) -> tuple[PointLayout, list[str]]:
    """The output point records that keep what every input holds, and a note per thing dropped.

    Waveform packets are never kept (the waveform data is not carried).  The
    GPS time type is the inputs' (files without GPS time do not count).
    The headers are the *index*'s (:mod:`stages.parse.las_index`; read
    here when it is not given).

    Raises
    ------
    InputDataError
        When inputs with GPS time disagree on its type: week seconds cannot be
        turned into standard time without the week.
    """
    if index is None:
        index = read_headers(paths)
    headers = index.headers
    dims = [set(h.point_format.standard_dimension_names) for _, h in headers]
    rgb = all("red" in d for d in dims)
    nir = rgb and all("nir" in d for d in dims)
    point_format = 8 if nir else 7 if rgb else 6
    notes = _dropped_dimensions(headers, dims, point_format)
    extra, extra_notes = _shared_extra_bytes(headers)
    notes += extra_notes
    adjusted = _gps_time_types(headers)
    records, record_notes = _shared_records(headers)
    notes += record_notes
    layout = PointLayout(
        point_format=point_format,
        extra=tuple(extra),
        gps_adjusted=adjusted == {1},
        synthetic_returns=any(h.global_encoding.synthetic_return_numbers for _, h in headers),
        vlrs=tuple(records["vlrs"]),
        evlrs=tuple(records["evlrs"]),
    )
    return layout, notes


def copied_dimensions(layout: PointLayout) -> list[str]:
    """The standard dimensions of *layout*'s point format copied as they are."""
    return [n for n in laspy.PointFormat(layout.point_format).standard_dimension_names if n not in READ_APART]


def _dropped_dimensions(headers: list, dims: list[set[str]], point_format: int) -> list[str]:
    """A note per input file whose standard dimensions *point_format* does not hold."""
    out_dims = set(laspy.PointFormat(point_format).standard_dimension_names)
    notes = []
    for (path, _), d in zip(headers, dims, strict=True):
        lost = sorted(d - out_dims - READ_APART)
        if lost:
            why = "waveform data is not carried" if lost[0].startswith(("wave", "return_point", "x_t")) else ""
            why = why or "not in every input file"
            notes.append(f"{path}: {', '.join(lost)} dropped ({why})")
    return notes


def _shared_extra_bytes(headers: list) -> tuple[list, list[str]]:
    """The extra-byte dimensions every input has alike (laspy's parameters to write them), and a note per loss."""
    extra = []
    for dim in headers[0][1].point_format.extra_dimensions:
        same = all(
            any(_same_dimension(dim, other) for other in h.point_format.extra_dimensions) for _, h in headers[1:]
        )
        params = _extra_bytes_params(dim) if same else None
        if params is not None:
            extra.append(params)
    kept = {p.name for p in extra}
    notes = []
    for path, h in headers:
        lost = [dim.name for dim in h.point_format.extra_dimensions if dim.name not in kept]
        if lost:
            notes.append(f"{path}: extra bytes {', '.join(lost)} dropped (not in every input file with one type)")
    return extra, notes


def _gps_time_types(headers: list) -> set[int]:
    """The GPS time types (global encoding bit 0) of the inputs with GPS time; two types are an error."""
    with_time = [(path, h) for path, h in headers if "gps_time" in h.point_format.dimension_names]
    adjusted = {int(h.global_encoding.gps_time_type) for _, h in with_time}
    if len(adjusted) > 1:
        week = next(path for path, h in with_time if int(h.global_encoding.gps_time_type) == 0)
        standard = next(path for path, h in with_time if int(h.global_encoding.gps_time_type) == 1)
        raise InputDataError(
            f"{standard} has adjusted standard GPS time but {week} GPS week seconds (global encoding bit 0); "
            "process them in separate runs or convert one of them."
        )
    return adjusted


def _shared_records(headers: list) -> tuple[dict[str, list], list[str]]:
    """The VLRs and EVLRs carried (:func:`_carried`) that every input has the same, and a note per loss."""
    records = {}
    notes = []
    for kind in ("vlrs", "evlrs"):
        own = [[v for v in (getattr(h, kind) or []) if _carried(v)] for _, h in headers]
        for path, h in headers:
            damaged = [f"{v.user_id!r} {v.record_id}" for v in (getattr(h, kind) or []) if not _ascii(v)]
            if damaged:
                notes.append(f"{path}: {kind[:-1].upper()} {', '.join(damaged)} dropped (not ASCII: damaged)")
        shared = set.intersection(*({_vlr_key(v) for v in vs} for vs in own))
        records[kind] = [v for v in own[0] if _vlr_key(v) in shared]
        for (path, _), vs in zip(headers, own, strict=True):
            lost = [f"{v.user_id} {v.record_id}" for v in vs if _vlr_key(v) not in shared]
            if lost:
                notes.append(
                    f"{path}: {kind[:-1].upper()} {', '.join(lost)} dropped (not the same in every input file)"
                )
    return records, notes


def _carried(vlr) -> bool:
    """Whether a (E)VLR of the input is carried to the output as it is.

    Not: the CRS (``LASF_Projection``, liblas' WKT; the writer adds the output
    CRS), extra-byte descriptions (``LASF_Spec`` 4; made from the layout),
    LASzip's record, waveform packet descriptors (``LASF_Spec`` 100-354), a
    COPC file's info VLR and octree hierarchy EVLR (``copc``: they describe
    where that file's points lie in it, not ours; our COPC product writes
    its own).
    """
    if not _ascii(vlr):
        return False  # a damaged name or description: it could not be written
    user = vlr.user_id.strip("\0 ")
    if user in ("LASF_Projection", "laszip encoded", "copc") or (user == "liblas" and vlr.record_id == 2112):
        return False
    return not (user == "LASF_Spec" and (vlr.record_id == 4 or 100 <= vlr.record_id <= 354))


def _ascii(vlr) -> bool:
    """Whether a (E)VLR's user id and description are ASCII (LAS: char fields; laspy writes nothing else)."""
    fields = (vlr.user_id, vlr.description or "")
    return all(f.isascii() if isinstance(f, str) else bytes(f).isascii() for f in fields)


def _vlr_key(vlr) -> tuple:
    data = vlr.record_data_bytes() if hasattr(vlr, "record_data_bytes") else bytes(vlr.record_data)
    return vlr.user_id, vlr.record_id, data


def _same_dimension(a, b) -> bool:
    """Whether two extra-byte dimensions have the same name, type, scale and offset."""

    def arr(v):
        return None if v is None else np.asarray(v).tolist()

    return (a.name, a.type_str(), arr(a.scales), arr(a.offsets)) == (
        b.name,
        b.type_str(),
        arr(b.scales),
        arr(b.offsets),
    )


def _extra_bytes_params(dim):
    """laspy's description of an extra-byte dimension to write, or None when it has no usable type."""
    try:
        return laspy.ExtraBytesParams(
            name=dim.name,
            type=dim.type_str(),
            description=dim.description or "",
            offsets=dim.offsets,
            scales=dim.scales,
            no_data=dim.no_data,
        )
    except (TypeError, ValueError, laspy.LaspyException):
        return None
