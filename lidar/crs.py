"""The CRS of LAS headers and of the output: read as GDAL reads them, checked, resolved.

:func:`header_crs` reads a header's CRS with the GeoKeys laspy leaves out
(the linear unit, the vertical CRS); :func:`crs_problem` tells whether a
file's coordinates can be in the CRS it claims (a LAS header's CRS is often
wrong), generously: it must never refuse a valid survey; :func:`output_crs`
resolves the configured output CRS.  The rules and why:
``docs/stages/parse.md``.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pyproj

from lidar.units import Units
from pipeline.errors import InputDataError

if TYPE_CHECKING:
    import laspy

#: Longitudes accepted by the geographic test (degrees): some software writes 0..360.
MAX_LONGITUDE = 360.0
MAX_LATITUDE = 90.0


def _extent(lo, hi) -> str:
    return f"x {lo[0]:,.6g} to {hi[0]:,.6g}, y {lo[1]:,.6g} to {hi[1]:,.6g}"


def crs_problem(crs: pyproj.CRS, mins: Sequence[float], maxs: Sequence[float]) -> str | None:
    """Why the horizontal bounds *mins*..*maxs* cannot be coordinates in *crs* (None when they can).

    *crs* is the CRS the file claims (a compound CRS is checked by its
    horizontal part); *mins*, *maxs* the file's lowest and highest x, y (z
    ignored).  The answer is a phrase for a message ("its coordinates (x ... )
    are not longitudes and latitudes, which WGS 84 (EPSG:4326) needs").

    >>> import pyproj
    >>> crs_problem(pyproj.CRS("EPSG:4326"), (515368.6, 4918340.4), (515401.0, 4918381.1)) is not None
    True
    >>> crs_problem(pyproj.CRS("EPSG:26912"), (515368.6, 4918340.4), (515401.0, 4918381.1)) is None
    True
    """
    lo = np.asarray(mins, dtype=np.float64)[:2]
    hi = np.asarray(maxs, dtype=np.float64)[:2]
    if not (np.isfinite(lo).all() and np.isfinite(hi).all()):
        return None  # unusable bounds: the point checks report the file
    horizontal = crs.sub_crs_list[0] if crs.is_compound and crs.sub_crs_list else crs
    if horizontal.is_geographic:
        if max(abs(lo[0]), abs(hi[0])) > MAX_LONGITUDE or max(abs(lo[1]), abs(hi[1])) > MAX_LATITUDE:
            return (
                f"its coordinates ({_extent(lo, hi)}) are not longitudes and latitudes in degrees, "
                f"which its CRS {_name(horizontal)} needs"
            )
        return None
    if not horizontal.is_projected:
        return None
    area = horizontal.area_of_use
    if area is None:
        return None
    try:
        to_crs = pyproj.Transformer.from_crs("EPSG:4326", horizontal, always_xy=True)
        x0, y0, x1, y1 = to_crs.transform_bounds(*area.bounds, densify_pts=21)
    except pyproj.exceptions.ProjError:
        return None
    if not np.isfinite([x0, y0, x1, y1]).all():
        return None
    w, h = x1 - x0, y1 - y0
    inside = x0 - w <= lo[0] and hi[0] <= x1 + w and y0 - h <= lo[1] and hi[1] <= y1 + h
    degrees_box = (-180.0, -90.0, 180.0, 90.0)
    looks_like_degrees = (
        lo[0] >= degrees_box[0]
        and hi[0] <= degrees_box[2]
        and lo[1] >= degrees_box[1]
        and hi[1] <= degrees_box[3]
        and (hi - lo < 1.0).all()  # a survey under one unit across, near the origin: degrees, not metres
    )
    area_near_origin = x0 <= degrees_box[2] and x1 >= degrees_box[0] and y0 <= degrees_box[3] and y1 >= degrees_box[1]
    if looks_like_degrees and not area_near_origin:
        unit = _unit(horizontal)
        return f"its coordinates ({_extent(lo, hi)}) look like degrees, not the {unit} of its CRS {_name(horizontal)}"
    if not inside:
        return (
            f"its coordinates ({_extent(lo, hi)}) lie far outside the area where its CRS {_name(horizontal)} is used "
            f"({area.name}: x {x0:,.0f} to {x1:,.0f}, y {y0:,.0f} to {y1:,.0f})"
        )
    return None


def _name(crs) -> str:
    # named only in a message: to_epsg() searches the EPSG database (about 28 ms), too slow for every file
    epsg = crs.to_epsg()
    return f"{crs.name} (EPSG:{epsg})" if epsg else crs.name


def _unit(crs) -> str:
    try:
        return f"{crs.axis_info[0].unit_name}s"
    except (IndexError, AttributeError):  # pragma: no cover - every projected CRS has axes
        return "units"


#: The GeoKey that gives a projected CRS's linear unit (an EPSG unit code), which laspy does not read.
_PROJ_LINEAR_UNITS_KEY = 3076

#: GeoKeys of a LAS GeoKeyDirectory that laspy does not read: the vertical CRS and the heights' unit.
_VERTICAL_CS_KEY = 4096
_VERTICAL_UNITS_KEY = 4099


def geo_keys(header: laspy.LasHeader) -> list:
    """The keys of the header's GeoKeyDirectory VLR (empty when it has none)."""
    for vlr in header.vlrs:
        if type(vlr).__name__ == "GeoKeyDirectoryVlr":
            return list(vlr.geo_keys)
    return []


def _key(keys, key_id: int) -> int | None:
    """The value of GeoKey *key_id*, or None when absent, 0 (undefined) or 32767 (user-defined)."""
    code = next((int(k.value_offset) for k in keys if int(k.id) == key_id), None)
    return None if code in (None, 0, 32767) else code


def _axis_in(crs, code: int) -> bool:
    """Whether *crs*'s first axis is already in the EPSG linear unit *code*."""
    axis = crs.axis_info[0]
    return axis.unit_auth_code == "EPSG" and axis.unit_code == str(code)


def _linear_unit(code: int):
    """The EPSG linear unit *code* as pyproj's unit info, or None when PROJ does not know it."""
    units = pyproj.database.get_units_map(auth_name="EPSG", category="linear")
    return next((u for u in units.values() if u.code == str(code)), None)


def _in_unit(crs, unit, code: int) -> dict:
    """PROJJSON of *crs* with every axis in the EPSG linear *unit* (its parameters keep their own units)."""
    data = crs.to_json_dict()
    data.pop("id", None)
    data["name"] = f"{crs.name} ({unit.name})"
    for axis in data["coordinate_system"]["axis"]:
        axis["unit"] = {
            "type": "LinearUnit",
            "name": unit.name,
            "conversion_factor": unit.conv_factor,
            "id": {"authority": "EPSG", "code": code},
        }
    return data


def honour_linear_units(crs: pyproj.CRS | None, geo_keys: Iterable) -> tuple[pyproj.CRS | None, str | None]:
    """The projected *crs* with its axes in the unit ``ProjLinearUnitsGeoKey`` names, when that differs.

    GDAL (so PDAL and QGIS) reads an EPSG projected CRS beside
    ``ProjLinearUnitsGeoKey`` = 9003 with its axes in US survey feet; laspy
    keeps the EPSG code's metres (why it matters: ``docs/stages/parse.md``).
    The projection's parameters keep their own units.

    Parameters
    ----------
    crs : pyproj.CRS or None
        What laspy parsed.
    geo_keys : iterable
        The GeoKeyDirectory's keys (objects with ``id`` and ``value_offset``), or empty.

    Returns the CRS and what was changed, for the log (or None).
    """
    if crs is None or not crs.is_projected or crs.is_compound:
        return crs, None
    code = _key(geo_keys, _PROJ_LINEAR_UNITS_KEY)
    if code is None or _axis_in(crs, code):
        return crs, None
    info = _linear_unit(code)
    if info is None:
        return crs, None
    new = pyproj.CRS.from_json_dict(_in_unit(crs, info, code))
    return new, (
        f"its GeoKeys give {crs.name} (EPSG:{crs.to_epsg()}) with ProjLinearUnitsGeoKey = {info.name}: "
        f"read as {new.name}, as GDAL does"
    )


def honour_vertical_keys(crs: pyproj.CRS | None, geo_keys: Iterable) -> tuple[pyproj.CRS | None, str | None]:
    """The CRS with the vertical CRS ``VerticalCSTypeGeoKey`` names added, as GDAL reads a LAS header.

    GDAL (so PDAL and QGIS) reads the compound CRS horizontal + vertical, the
    vertical axis in ``VerticalUnitsGeoKey``'s unit when given; laspy drops the
    vertical datum.  Without the key the heights are in the horizontal unit,
    and a contradicting ``VerticalUnitsGeoKey`` gets a note (``docs/stages/parse.md``).

    Parameters
    ----------
    crs : pyproj.CRS or None
        The horizontal CRS as read so far.
    geo_keys : iterable
        The GeoKeyDirectory's keys (objects with ``id`` and ``value_offset``), or empty.

    Returns the CRS and what was read or assumed, for the log (or None).
    """
    if crs is None or crs.is_compound or crs.is_vertical:
        return crs, None
    keys = list(geo_keys)
    vertical_code, unit_code = _key(keys, _VERTICAL_CS_KEY), _key(keys, _VERTICAL_UNITS_KEY)
    unit = _linear_unit(unit_code) if unit_code is not None else None
    if vertical_code is None:
        if unit is None or crs.is_geographic:
            return crs, None
        if _axis_in(crs, unit_code):
            return crs, None
        return crs, (
            f"its VerticalUnitsGeoKey gives heights in {unit.name} but no vertical CRS: heights are read in "
            f"{crs.axis_info[0].unit_name}, the unit of {crs.name}; if they are in {unit.name}, set input.override_crs to "
            "a compound CRS that says so (for example EPSG:26915+6360)"
        )
    try:
        vertical = pyproj.CRS.from_epsg(vertical_code)
    except pyproj.exceptions.CRSError:
        vertical = None
    if vertical is None or not vertical.is_vertical:
        return crs, (
            f"its VerticalCSTypeGeoKey = {vertical_code} is not an EPSG vertical CRS: ignored, heights read in "
            f"the unit of {crs.name}; set input.override_crs to a compound CRS to state their datum"
        )
    data = vertical.to_json_dict()
    if unit is not None and not _axis_in(vertical, unit_code):
        data = _in_unit(vertical, unit, unit_code)
    horizontal = crs.to_json_dict()
    compound = pyproj.CRS.from_json_dict(
        {
            "type": "CompoundCRS",
            "name": f"{crs.name} + {data['name']}",
            "components": [horizontal, data],
        }
    )
    return compound, (
        f"its GeoKeys give the vertical CRS {data['name']} (VerticalCSTypeGeoKey = {vertical_code}) beside "
        f"{crs.name}: read as the compound CRS {compound.name}, as GDAL does"
    )


def header_crs(header: laspy.LasHeader) -> tuple[pyproj.CRS | None, str | None]:
    """The CRS of a LAS header as GDAL reads it, and what was read beyond laspy (notes for the log).

    laspy's ``parse_crs``, then the GeoKeys it does not read:
    ``ProjLinearUnitsGeoKey`` (:func:`honour_linear_units`) and the vertical
    CRS (:func:`honour_vertical_keys`).  Raises what laspy raises for a
    header whose CRS cannot be read.
    """
    keys = geo_keys(header)
    crs, linear = honour_linear_units(header.parse_crs(), keys)
    crs, vertical = honour_vertical_keys(crs, keys)
    notes = [n for n in (linear, vertical) if n]
    return crs, ("; ".join(notes) or None)


def output_crs(setting: str, first_crs: pyproj.CRS | None, lon_lat_centre: tuple[float, float] | None) -> pyproj.CRS:
    """Resolve the configured output CRS.

    ``auto-utm`` keeps a projected input CRS and otherwise picks the WGS 84 /
    UTM zone of *lon_lat_centre*.  Any other value is a pyproj user input
    (``EPSG:25830``, WKT, ...).  The CRS must be projected; its linear unit
    may be any (metre, foot, US survey foot: see :mod:`lidar.units`).
    """
    if setting == "auto-utm":
        if first_crs is not None and first_crs.is_projected:
            crs = first_crs
        else:
            lon, lat = lon_lat_centre
            zone = int((lon + 180.0) // 6.0) % 60 + 1
            crs = pyproj.CRS.from_epsg((32600 if lat >= 0 else 32700) + zone)
    else:
        crs = pyproj.CRS.from_user_input(setting)
    horizontal = crs.sub_crs_list[0] if crs.is_compound else crs
    if not horizontal.is_projected:
        raise InputDataError(f"output CRS {crs.name} is not projected; choose a projected CRS for crs.")

    try:
        Units.of(crs)
    except ValueError as exc:
        raise InputDataError(f"output CRS {crs.name}: {exc}; choose a projected CRS for crs.") from None
    return crs


def check_crs_setting(value: str | None) -> str | None:
    """A configured CRS (``auto-utm`` or what pyproj reads), unchanged; ValueError for one pyproj does not know."""
    if value is None or value == "auto-utm":
        return value

    try:
        pyproj.CRS.from_user_input(value)
    except pyproj.exceptions.CRSError:
        raise ValueError(f"'{value}' is not a CRS pyproj knows (use e.g. EPSG:25830 or auto-utm)") from None
    return value


def horizontal_crs_matches(layer_crs: str | None, points_crs: pyproj.CRS | None) -> str | None:
    """Why a vector layer's CRS does not fit the points' (their horizontal parts compared); None when it does."""
    if points_crs is None:
        return None  # points without a CRS: nothing to compare with
    if not layer_crs:
        return f"the layer has no CRS; write it in the points' CRS ({points_crs.name})"
    try:
        layer = pyproj.CRS.from_user_input(layer_crs)
    except pyproj.exceptions.CRSError:
        return f"its CRS ({layer_crs[:60]}) cannot be read"

    def horizontal(crs):
        return crs.sub_crs_list[0] if crs.is_compound else crs

    if horizontal(layer).equals(horizontal(points_crs), ignore_axis_order=True):
        return None
    return f"its CRS is {layer.name}, the points' {horizontal(points_crs).name}; reproject the layer"


#: Configuration keys :func:`heights_of_run` reads: a stage using it lists them in its ``config_keys``.
HEIGHTS_KEYS = ("input.format", "stages.georeference.geoid", "stages.georeference.frame")

#: The kinds of height a survey's products carry (:class:`Heights`).
VERTICAL_CRS, ELLIPSOIDAL, GEOID_GRID, UNKNOWN = "vertical CRS", "ellipsoidal", "geoid grid", "unknown"


@dataclass(frozen=True)
class Heights:
    """What the heights of a survey's products are measured from: its vertical datum, said in words.

    ``kind`` is one of :data:`VERTICAL_CRS` (a named vertical CRS: the
    output CRS is compound), :data:`ELLIPSOIDAL` (a raw flight georeferenced
    without a geoid), :data:`GEOID_GRID` (with a geoid grid that names no
    vertical CRS) and :data:`UNKNOWN` (LAS/LAZ whose CRS names no vertical
    CRS: never assumed ellipsoidal).  ``datum`` is the phrase products carry
    (the GeoTIFFs' ``VERTICAL_DATUM`` tag, ``run.json``, the report);
    ``warning`` the sentence the log and the report give, or None.
    """

    kind: str
    datum: str
    warning: str | None = None


def heights_of(crs: pyproj.CRS | None, *, georeferenced: bool, geoid: str | None = None) -> Heights:
    """The vertical datum of heights in the output CRS *crs*.

    Parameters
    ----------
    crs : pyproj.CRS or None
        The products' CRS; a compound CRS names its vertical CRS.
    georeferenced : bool
        True for a raw flight georeferenced here (heights from the GNSS's
        ellipsoid, or the geoid grid), False for LAS/LAZ input.
    geoid : str, optional
        The geoid grid ``stages.georeference.geoid`` applied, if any.

    >>> heights_of(pyproj.CRS("EPSG:28992+5709"), georeferenced=False).datum
    'NAP height (EPSG:5709)'
    >>> heights_of(pyproj.CRS("EPSG:28992"), georeferenced=False).kind
    'unknown'
    >>> heights_of(pyproj.CRS("EPSG:32630"), georeferenced=True).datum
    'ellipsoidal: heights above the WGS 84 ellipsoid, no geoid applied'
    """
    vertical = _vertical_part(crs)
    if vertical is not None:
        code = vertical.to_epsg()
        return Heights(VERTICAL_CRS, f"{vertical.name}" + (f" (EPSG:{code})" if code else ""))
    if georeferenced and geoid:
        return Heights(
            GEOID_GRID,
            f"orthometric: ellipsoidal heights minus the geoid grid {Path(str(geoid)).name} (vertical CRS not named)",
        )
    if georeferenced:
        ellipsoid = crs.ellipsoid.name if crs is not None and crs.ellipsoid is not None else "unknown"
        above = "the GNSS's ellipsoid" if ellipsoid == "unknown" else f"the {ellipsoid} ellipsoid"
        return Heights(
            ELLIPSOIDAL,
            f"ellipsoidal: heights above {above}, no geoid applied",
            "the products' heights are ellipsoidal (no geoid applied), not heights above sea level; "
            "set stages.georeference.geoid to a geoid grid (frame: exact) for orthometric heights.",
        )
    example = _compound_example(crs)
    return Heights(
        UNKNOWN,
        "unknown: the input names no vertical CRS",
        "the input's CRS names no vertical CRS, so the heights' vertical datum is unknown (kept as the files "
        f"have it); state it with input.override_crs set to the compound CRS, for example {example}.",
    )


def heights_of_run(config, crs: pyproj.CRS | None) -> Heights:
    """:func:`heights_of` for a run's configuration (the keys :data:`HEIGHTS_KEYS`) and its output CRS."""
    fmt = getattr(getattr(config, "input", None), "format", "las")
    geo = getattr(getattr(config, "stages", None), "georeference", None)
    geoid = getattr(geo, "geoid", None) if getattr(geo, "frame", "exact") == "exact" else None  # ltp: none applied
    return heights_of(crs, georeferenced=fmt != "las", geoid=str(geoid) if geoid else None)


def _vertical_part(crs: pyproj.CRS | None) -> pyproj.CRS | None:
    if crs is None:
        return None
    if crs.is_compound:  # before is_vertical, which a compound CRS with a vertical part also answers True
        return next((c for c in crs.sub_crs_list if c.is_vertical), None)
    return crs if crs.is_vertical else None


def _compound_example(crs: pyproj.CRS | None) -> str:
    """'EPSG:28992+<vertical EPSG code>' for *crs* with an EPSG code, else a known example."""
    code = crs.to_epsg() if crs is not None else None
    return (
        f"EPSG:{code}+<the vertical CRS's EPSG code>"
        if code
        else "EPSG:25830+5782 (ETRS89 / UTM zone 30N + Alicante height)"
    )


def state_heights(ctx, heights: Heights, *, warn: bool = False) -> None:
    """Say the products' vertical datum in a stage's metrics (``heights``, ``heights_kind``) and log (*ctx*: a
    stage's context); with *warn*, its warning too, when it has one.

    The stage that writes the first height product (the DTM) warns, once
    it is written: a run that stops before has no heights to warn of, and
    its error stays the one sentence on the screen.
    """
    ctx.metrics.update(heights=heights.datum, heights_kind=heights.kind)
    ctx.log.info("vertical datum of the heights: %s", heights.datum)
    if warn and heights.warning:
        ctx.log.warning("%s", heights.warning)
