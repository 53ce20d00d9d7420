"""Reading and writing the artifacts that travel between stages.

- Point clouds between stages are uncompressed LAS 1.4, point format 6 (7
  with the input's RGB, 8 with RGB and NIR, plus the input's extra bytes;
  the input's GPS time type kept), with the CRS as a WKT VLR: an open format any LiDAR viewer opens, so every cached
  intermediate can be inspected; uncompressed because it is read and written
  several times per run and LAZ costs about ten times more CPU.
- Rasters are Cloud Optimized GeoTIFF (float32, internal 256-pixel tiles,
  DEFLATE with the floating-point predictor, overviews, explicit nodata);
  elevation rasters name their unit (the band's unit type: the unit of the
  CRS's vertical axis, else of its horizontal axes, :mod:`stages.units`), and
  a compound CRS is written whole (GDAL writes its vertical part as the
  GeoTIFF's vertical CRS).  Images meant for the eye (the hillshade) are
  Byte with nodata 0.
- Vector products are GeoPackage 1.2 (:data:`GPKG_VERSION`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np

#: Point format of every point cloud the pipeline writes (LAS 1.4).
POINT_FORMAT = 6
#: Nodata value of every float raster (documented in docs/PRODUCTS.md).
NODATA = -9999.0
#: Internal tile size of the Cloud Optimized GeoTIFFs.
COG_BLOCKSIZE = 256
#: ``unit`` value meaning "heights in the CRS's vertical unit" (an elevation raster).
HEIGHT = "height"
#: GeoPackage version written (GDAL's ``VERSION`` creation option).  GDAL 3.6
#: and QGIS 3.22 read 1.2 without warnings; GDAL 3.8's default, 1.4, makes them
#: warn that the file "may only be partially supported".
GPKG_VERSION = "1.2"
#: ``system_identifier`` of every point cloud the pipeline writes (LAS 1.4 allows
#: "a string up to 32 characters identifying the operation"; PDAL and LAStools
#: name themselves there too).
SYSTEM_IDENTIFIER = "dtm-pipeline"


def generating_software() -> str:
    """``generating_software`` of every point cloud the pipeline writes: this tool and its version."""
    from pipeline import __version__

    return f"dtm-pipeline {__version__}"[:32]


@dataclass(frozen=True)
class PointLayout:
    """What the point records of a written cloud hold, taken from the input files.

    Attributes
    ----------
    point_format : int
        6 (no colour), 7 (RGB) or 8 (RGB and near infrared).
    extra : tuple of laspy.ExtraBytesParams
        Extra-byte dimensions carried through, in the input's order.
    gps_adjusted : bool
        Global encoding bit 0: GPS times are adjusted standard GPS time
        (GPS seconds - 1e9), not seconds of the GPS week.
    synthetic_returns : bool
        Global encoding bit 3: the return numbers were synthesised.
    vlrs, evlrs : tuple of laspy VLR
        The input's own (extended) variable length records carried through
        (not the CRS, extra-byte, LASzip or waveform records, which the
        writer makes itself or which no longer apply).
    """

    point_format: int = POINT_FORMAT
    extra: tuple = ()
    gps_adjusted: bool = False
    synthetic_returns: bool = False
    vlrs: tuple = ()
    evlrs: tuple = ()


def point_header(crs, lo=None, hi=None, *, layout: PointLayout | None = None):
    """The header of every point cloud the pipeline writes: LAS 1.4, point format 6-8, the CRS as WKT.

    Offsets are *lo* rounded down to whole kilometres; the scale is 0.1 mm —
    finer than any airborne LiDAR's precision, and int32 holds +-214 km
    around the offset — and 1 mm, 1 cm, ... for a survey reaching farther
    (*hi*).  Without bounds (an empty cloud) offsets are 0.  The point
    format, extra bytes and the GPS time type follow *layout* (default:
    format 6, GPS week time); ``system_identifier`` and
    ``generating_software`` name this tool and its version.
    """
    import laspy

    layout = layout or PointLayout()
    header = laspy.LasHeader(point_format=layout.point_format, version="1.4")
    if layout.extra:
        header.add_extra_dims(list(layout.extra))
    header.global_encoding.gps_time_type = (
        laspy.header.GpsTimeType.STANDARD if layout.gps_adjusted else laspy.header.GpsTimeType.WEEK_TIME
    )
    header.global_encoding.synthetic_return_numbers = layout.synthetic_returns
    header.system_identifier = SYSTEM_IDENTIFIER
    header.generating_software = generating_software()
    header.vlrs.extend(layout.vlrs)
    if layout.evlrs:
        header.evlrs = [*(header.evlrs or []), *layout.evlrs]
    scale = 1e-4
    if lo is not None:
        header.offsets = np.floor(np.asarray(lo, dtype=np.float64) / 1000.0) * 1000.0
        reach = float(np.max(np.asarray(hi, dtype=np.float64) - header.offsets))
        while reach / scale > 2.0e9:
            scale *= 10.0
    header.scales = np.array([scale, scale, scale])
    header.add_crs(crs)
    return header


def read_cloud(path: Path):
    """Read a whole LAS/LAZ file into a :class:`laspy.LasData`."""
    import laspy

    return laspy.read(path)


def write_cloud(las, path: Path, *, compress: bool = False) -> None:
    """Write a :class:`laspy.LasData` (LAZ when *compress*, through lazrs)."""
    import laspy

    las.update_header()
    backend = laspy.LazBackend.Lazrs if compress else None
    las.write(str(path), do_compress=compress, laz_backend=backend)


def open_las_writer(path, header, **options):
    """``laspy.open(path, mode="w", header=header, **options)`` whose header grows without sorting each chunk.

    laspy's writer updates its header with every chunk it writes
    (:meth:`laspy.LasHeader.grow`): bounds, GPS time range and points per
    return, the last with ``np.unique`` (a sort of the chunk's return
    numbers: 27 ms of the 51 ms a 1 M-point chunk costs, 0.5 s in the
    three writers of a 10 M-point run).  This writer's header counts the
    returns with ``np.bincount`` instead (:func:`grow_header`): the same
    header, byte for byte (``tests/stages/test_las_writer.py``).
    """
    import laspy

    writer = laspy.open(str(path), mode="w", header=header, **options)
    writer.header.grow = partial(grow_header, writer.header)  # this header only: laspy itself is untouched
    return writer


def grow_header(header, points) -> None:
    """:meth:`laspy.LasHeader.grow` (laspy 2.5-2.7), the points per return counted by ``np.bincount``.

    Bounds as laspy computes them (``X.max() * scale + offset``, ...), the
    GPS time range, the returns numbered 1 to the header's 15 slots (0 and
    higher numbers are not counted, as laspy does not), the point count.
    """
    for axis, name in enumerate("XYZ"):
        raw = points[name]
        scale, offset = header.scales[axis], header.offsets[axis]
        header.maxs[axis] = max(header.maxs[axis], raw.max() * scale + offset)
        header.mins[axis] = min(header.mins[axis], raw.min() * scale + offset)
    if "gps_time" in points.point_format.dimension_names:
        gps_time = points["gps_time"]
        header.max_gps_time = max(header.max_gps_time, gps_time.max())
        header.min_gps_time = min(header.min_gps_time, gps_time.min())
    slots = header.number_of_points_by_return
    counts = np.bincount(np.asarray(points.return_number, dtype=np.intp), minlength=1)[1 : len(slots) + 1]
    slots[: len(counts)] += counts.astype(slots.dtype)
    header.point_count += len(points)


def xyz(las) -> np.ndarray:
    """The scaled coordinates of a LasData as an (n, 3) float64 array."""
    return np.column_stack((np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)))


def cloud_units(las):
    """The :class:`stages.units.Units` of a LasData's CRS (metres when it has none)."""
    from stages.units import Units

    return Units.of(cloud_crs(las))


def xyz_metres(las) -> tuple[np.ndarray, object]:
    """The coordinates in metres (see :mod:`stages.units`) and the cloud's units."""
    units = cloud_units(las)
    return units.to_metres(xyz(las)), units


def chunk_xyz_metres(chunk, units) -> np.ndarray:
    """A chunk's (laspy record's) coordinates in metres, (n, 3) with contiguous columns.

    laspy's scaled values (``X * scale + offset``, computed as laspy does),
    then :meth:`stages.units.Units.to_metres`'s factors, column by column:
    no stacked copy of three separate columns.
    """
    xyz = np.empty((len(chunk), 3), order="F")
    for axis, name in enumerate("XYZ"):
        np.multiply(chunk.array[name], chunk.scales[axis], out=xyz[:, axis])
        xyz[:, axis] += chunk.offsets[axis]
        if not units.is_metre:
            xyz[:, axis] *= units.vertical if axis == 2 else units.horizontal
    return xyz


def cloud_crs(las):
    """The pyproj CRS of a LasData (or an open laspy reader), or None when its header has none."""
    try:
        return las.header.parse_crs()
    except Exception:  # laspy raises various errors for malformed GeoTIFF keys
        return None


def read_raster(path: Path):
    """Band 1 as float64 with NaN for nodata, and the raster's transform, CRS and cell size."""
    import rasterio

    with rasterio.open(path) as ds:
        band = ds.read(1).astype(np.float64)
        if ds.nodata is not None:
            band[band == ds.nodata] = np.nan
        return band, ds.transform, ds.crs, ds.res[0]


def write_cog(
    path: Path,
    array: np.ndarray,
    *,
    transform,
    crs,
    nodata: float = NODATA,
    dtype: str = "float32",
    unit: str | None = HEIGHT,
) -> None:
    """Write a single-band Cloud Optimized GeoTIFF (float32 unless *dtype* says otherwise).

    Parameters
    ----------
    path : Path
        Destination file.
    array : ndarray, shape (rows, cols)
        Values, with *nodata* (not NaN) in empty cells.
    transform : affine.Affine
        Pixel-to-map transform (north-up).
    crs : pyproj.CRS or str
        Coordinate reference system, written as WKT.
    nodata : float
        The nodata value recorded in the file.
    dtype : str
        ``float32`` or ``uint8`` (an image).
    unit : str or None
        The band's unit type: :data:`HEIGHT` (default) for the unit of the
        CRS's heights (:func:`height_unit`), a name, or None for values that
        are not lengths (counts, shades).
    """
    from rasterio.io import MemoryFile

    data = np.asarray(array, dtype=dtype)
    rows, cols = data.shape
    profile = float_raster_profile(rows, cols, transform=transform, crs=crs, nodata=nodata, dtype=dtype)
    with MemoryFile() as mem:
        with mem.open(**profile) as ds:
            ds.write(data, 1)
            set_unit(ds, crs, unit)
        with mem.open() as src:
            copy_to_cog(src, path)


def height_unit(crs) -> str:
    """The name of the unit heights are in, in *crs* (a pyproj, rasterio or WKT CRS): 'metre', 'foot', ..."""
    from stages.units import raster_units

    return raster_units(crs).vertical_name


def set_unit(ds, crs, unit: str | None) -> None:
    """Set band 1's unit type of the open, writable dataset *ds* (see :func:`write_cog`)."""
    if unit is None:
        return
    ds.units = (height_unit(crs) if unit == HEIGHT else unit,)


def float_raster_profile(
    rows: int, cols: int, *, transform, crs, nodata: float = NODATA, dtype: str = "float32"
) -> dict:
    """The rasterio profile of a single-band GeoTIFF, float32 by default (CRS written as WKT)."""
    import rasterio

    wkt = crs.to_wkt() if hasattr(crs, "to_wkt") else str(crs)
    return {
        "driver": "GTiff",
        "width": cols,
        "height": rows,
        "count": 1,
        "dtype": dtype,
        "crs": rasterio.crs.CRS.from_wkt(wkt),
        "transform": transform,
        "nodata": nodata,
    }


def copy_to_cog(src, path: Path) -> None:
    """Write the open dataset *src* to *path* as a Cloud Optimized GeoTIFF (GDAL's COG driver, streaming)."""
    import rasterio.shutil

    rasterio.shutil.copy(
        src,
        str(path),
        driver="COG",
        COMPRESS="DEFLATE",
        PREDICTOR="YES",
        BLOCKSIZE=str(COG_BLOCKSIZE),
        OVERVIEW_RESAMPLING="AVERAGE",
        BIGTIFF="IF_SAFER",
        NUM_THREADS="ALL_CPUS",
    )


def png_bytes(image: np.ndarray) -> bytes:
    """Encode a (rows, cols) or (rows, cols, 3) uint8 image as PNG (GDAL's PNG driver)."""
    import warnings

    from rasterio.errors import NotGeoreferencedWarning
    from rasterio.io import MemoryFile

    warnings.filterwarnings("ignore", category=NotGeoreferencedWarning)
    img = np.asarray(image, dtype=np.uint8)
    bands = img[np.newaxis] if img.ndim == 2 else np.moveaxis(img, -1, 0)
    with MemoryFile() as mem:
        with mem.open(
            driver="PNG", width=bands.shape[2], height=bands.shape[1], count=bands.shape[0], dtype="uint8"
        ) as ds:
            ds.write(bands)
        return mem.read()


def line_wkb(xy: np.ndarray) -> bytes:
    """A 2D LineString as WKB (little-endian flag, type 2, the point count, the coordinates)."""
    import struct

    coords = np.ascontiguousarray(np.asarray(xy)[:, :2], dtype="<f8")
    return struct.pack("<BII", 1, 2, len(coords)) + coords.tobytes()


def write_gpkg(path: Path, geometry: list[bytes], fields: dict[str, np.ndarray], *, crs, layer: str) -> None:
    """Write WKB LineStrings with attribute columns to a GeoPackage, reproducibly.

    The GeoPackage's ``last_change`` timestamps are fixed (GDAL's
    ``OGR_CURRENT_DATE``) so the same lines give the same bytes on every run:
    products are compared and cached by checksum.  The file is a GeoPackage
    :data:`GPKG_VERSION` (GDAL's ``VERSION`` dataset creation option).
    """
    import pyogrio
    import pyogrio.raw

    pyogrio.set_gdal_config_options({"OGR_CURRENT_DATE": "2000-01-01T00:00:00.000Z"})
    wkb = np.empty(len(geometry), dtype=object)
    wkb[:] = list(geometry)
    wkt = crs.to_wkt() if hasattr(crs, "to_wkt") else str(crs)
    pyogrio.raw.write(
        str(path),
        geometry=wkb,
        field_data=list(fields.values()),
        fields=list(fields),
        layer=layer,
        driver="GPKG",
        geometry_type="LineString",
        crs=wkt,
        dataset_options={"VERSION": GPKG_VERSION},
    )


def write_lines_gpkg(path: Path, lines: list[tuple[float, np.ndarray]], *, crs, layer: str = "contours") -> None:
    """Write 2D line strings with an ``elevation`` attribute to a GeoPackage (:func:`write_gpkg`)."""
    elevation = np.array([level for level, _ in lines], dtype=np.float64)
    write_gpkg(path, [line_wkb(xy) for _, xy in lines], {"elevation": elevation}, crs=crs, layer=layer)


def npy_header(dtype, rows: int, size: int = 128) -> bytes:
    """The fixed-size (*size* bytes) NPY 1.0 header of a 1-D array of *rows* values of *dtype*.

    Written in front of a column whose values were streamed to disk first.
    """
    dtype = np.dtype(dtype)
    header = repr({"descr": np.lib.format.dtype_to_descr(dtype), "fortran_order": False, "shape": (int(rows),)})
    body = header.encode("latin1")
    pad = size - 10 - len(body) - 1
    return b"\x93NUMPY\x01\x00" + np.uint16(size - 10).tobytes() + body + b" " * pad + b"\n"


class NpyColumns:
    """Write a table as one ``.npy`` file per column in a folder, streaming.

    Rows are appended in chunks and go straight to disk, so memory does not
    grow with the input; each file's NPY header (fixed 128 bytes) is written
    last, when the row count is known.  ``meta`` goes to ``meta.json``.
    Read back with :func:`read_columns` (memory-mapped).
    """

    HEADER_BYTES = 128

    def __init__(self, folder: Path, schema: dict[str, str], meta: dict | None = None):
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.schema = {name: np.dtype(dtype) for name, dtype in schema.items()}
        self.meta = dict(meta or {})
        self.rows = 0
        self._files = {}
        for name in self.schema:
            fh = open(self.folder / f"{name}.npy", "wb")  # noqa: SIM115 - closed in close()
            fh.write(b"\0" * self.HEADER_BYTES)
            self._files[name] = fh

    def append(self, **columns: np.ndarray) -> None:
        lengths = {len(v) for v in columns.values()}
        if set(columns) != set(self.schema) or len(lengths) != 1:
            raise ValueError("append needs every column, all of one length")
        for name, values in columns.items():
            self._files[name].write(np.ascontiguousarray(values, dtype=self.schema[name]).tobytes())
        self.rows += lengths.pop()

    def close(self) -> None:
        import json

        for name, fh in self._files.items():
            fh.seek(0)
            fh.write(npy_header(self.schema[name], self.rows))
            fh.close()
        meta = {**self.meta, "rows": self.rows, "columns": {n: str(d) for n, d in self.schema.items()}}
        (self.folder / "meta.json").write_text(json.dumps(meta, indent=2, default=str))

    def __enter__(self) -> NpyColumns:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def read_columns(folder: Path) -> tuple[dict[str, np.ndarray], dict]:
    """The columns (memory-mapped) and ``meta.json`` of a folder written by :class:`NpyColumns`."""
    import json

    folder = Path(folder)
    meta = json.loads((folder / "meta.json").read_text())
    return {name: np.load(folder / f"{name}.npy", mmap_mode="r") for name in meta["columns"]}, meta
