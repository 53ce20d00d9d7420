"""A LAS 1.4 point cloud rewritten as a Cloud Optimized Point Cloud (``points.copc.laz``).

COPC 1.0 (https://copc.io, Hobu Inc. 2021) is a LAZ 1.4 file whose points are
ordered by an octree, one LAZ chunk per node, with the octree's cube in an
info VLR and its nodes in a hierarchy EVLR, so that a viewer reads only the
nodes of the region and level of detail it draws.  The octree is sampled as
PDAL's ``writers.copc`` and untwine sample it (one point per voxel of a
``GRID``³ grid per node); the records are moved byte for byte with laspy and
lazrs, never decoded.  Layout, choices and memory: docs/stages/export_las.md.
"""

from __future__ import annotations

import copy
import math
import struct
from dataclasses import dataclass
from pathlib import Path

import laspy
import lazrs
import numpy as np
from laspy.vlrs.known import LasZipVlr
from laspy.vlrs.vlr import VLR
from laspy.vlrs.vlrlist import VLRList

#: voxels per side of a node's sampling grid (PDAL writers.copc and untwine use 128)
GRID = 128
#: the COPC info VLR's payload: centre x, y, z, half-size, spacing, hierarchy offset and size, GPS time min and max,
#: 11 reserved
INFO = struct.Struct("<5d2Q2d11Q")
#: one hierarchy entry: key (level, x, y, z), offset, byte size, point count
ENTRY = struct.Struct("<iiiiQii")
#: the deepest level built; deeper points stay in their node
MAX_LEVEL = 20
#: a node's x, y or z index in its 21 bits of a packed node id
MASK21 = (1 << 21) - 1


@dataclass(frozen=True)
class Octree:
    """The nodes of a COPC octree and the points of each (node ``i`` holds ``order[starts[i]:starts[i + 1]]``)."""

    center: np.ndarray  # (3,) centre of the root cube (scaled coordinates)
    halfsize: float  # half the side of the root cube
    spacing: float  # distance between points of the root node (its voxel side)
    keys: np.ndarray  # (nodes, 4) int32: level, x, y, z of each node, in writing order
    starts: np.ndarray  # (nodes + 1,) int64
    order: np.ndarray  # int64 point indices, node by node (ascending within a node)


@dataclass(frozen=True)
class _Cube:
    """The root cube: points at ``coords * scale + offset``, the cube from *origin* with sides *side*."""

    scale: np.ndarray
    offset: np.ndarray
    origin: np.ndarray
    side: float


def _root_cube(coords: np.ndarray, scale: np.ndarray, offset: np.ndarray) -> _Cube:
    """The cube from the lowest corner of the points, its side their largest extent.

    So readers that place the nodes from the header's minimum and span
    (copc-lib) and readers that use the info VLR's centre and half-size
    (laspy, PDAL) see the same nodes.  Points on the upper faces go to the
    last voxel of their row.
    """
    lo = coords.min(axis=0) * scale + offset
    hi = coords.max(axis=0) * scale + offset
    return _Cube(scale, offset, lo, float(max((hi - lo).max(), 1e-3)))


def build_octree(
    coords: np.ndarray,
    max_node_points: int = 100_000,
    grid: int = GRID,
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    chunk: int = 1_000_000,
) -> Octree:
    """Put each point of *coords* in one node of a COPC octree, level by level from the root.

    *coords* (n, 3) are at ``coords * scale + offset`` (a LAS file's integer
    X, Y, Z with its header's scales and offsets, or scaled coordinates with
    the defaults).  Each node keeps the first point of each of its *grid*³
    voxels and passes the others to its children; a node with at most
    *max_node_points* points left keeps them all (a leaf).  *chunk*: points
    converted at a time.

    >>> tree = build_octree(np.random.default_rng(0).uniform(0, 100, (1000, 3)), max_node_points=100)
    >>> int(tree.starts[-1]), sorted(set(tree.order.tolist())) == list(range(1000))
    (1000, True)
    """
    cube = _root_cube(coords, np.asarray(scale, dtype=np.float64), np.asarray(offset, dtype=np.float64))
    remaining = np.arange(len(coords), dtype=np.int64)  # ascending: ties below keep the file order
    node_keys: list[np.ndarray] = []
    node_members: list[np.ndarray] = []
    for level in range(MAX_LEVEL + 1):
        if remaining.size == 0:
            break
        node_id, local = _voxels(coords, remaining, cube, (1 << level) * grid, grid, chunk)
        perm = _node_voxel_order(node_id, local, level)
        ids, loc = node_id[perm], local[perm]
        del node_id, local
        keep = _kept(ids, loc, max_node_points, leaves_only=level == MAX_LEVEL)
        keys, members = _nodes(level, perm[keep], ids[keep], remaining)
        node_keys += keys
        node_members += members
        remaining = remaining[np.sort(perm[~keep])]
        del perm, ids, loc, keep
    sizes = np.array([len(m) for m in node_members], dtype=np.int64)
    halfsize = cube.side / 2.0
    return Octree(
        center=cube.origin + halfsize,
        halfsize=halfsize,
        spacing=cube.side / grid,
        keys=np.array(node_keys, dtype=np.int32).reshape(-1, 4),
        starts=np.concatenate([[0], np.cumsum(sizes)]),
        order=np.concatenate(node_members) if node_members else np.zeros(0, dtype=np.int64),
    )


def _voxels(
    coords: np.ndarray, remaining: np.ndarray, cube: _Cube, cells: int, grid: int, chunk: int
) -> tuple[np.ndarray, np.ndarray]:
    """Node (x, y, z packed in 21 bits each, int64) and voxel inside the node (int32) of each remaining point.

    *cells*: voxels on the cube's side at this level (nodes on it times *grid*).
    """
    m = remaining.size
    node_id = np.empty(m, dtype=np.int64)
    local = np.empty(m, dtype=np.int32)
    for a in range(0, m, chunk):
        idx = remaining[a : a + chunk]
        v = np.floor((coords[idx] * cube.scale + cube.offset - cube.origin) / cube.side * cells).astype(np.int64)
        np.clip(v, 0, cells - 1, out=v)
        nd = v // grid
        lc = v - nd * grid
        node_id[a : a + len(idx)] = (nd[:, 0] << 42) | (nd[:, 1] << 21) | nd[:, 2]
        local[a : a + len(idx)] = (lc[:, 0] * grid + lc[:, 1]) * grid + lc[:, 2]
    return node_id, local


def _node_voxel_order(node_id: np.ndarray, local: np.ndarray, level: int) -> np.ndarray:
    """The points sorted by node, then voxel, then file order (stable)."""
    # one int64 key while node and voxel fit in 63 bits (a stable argsort of one key is about twice as fast
    # as a lexsort of two)
    if 3 * level + 21 <= 62:
        compact = ((node_id >> 42) << (2 * level)) | (((node_id >> 21) & MASK21) << level) | (node_id & MASK21)
        return np.argsort((compact << 21) | local, kind="stable")
    return np.lexsort((local, node_id))


def _kept(ids: np.ndarray, loc: np.ndarray, max_node_points: int, *, leaves_only: bool) -> np.ndarray:
    """Which points (sorted by node and voxel) stay at this level: all of a leaf's, else the first of each voxel."""
    m = len(ids)
    new_node = np.ones(m, dtype=bool)
    new_node[1:] = ids[1:] != ids[:-1]
    counts = np.diff(np.append(np.flatnonzero(new_node), m))
    leaf = (counts <= max_node_points) | leaves_only
    keep = np.repeat(leaf, counts)  # a leaf keeps every point ...
    keep[0] = True
    keep[1:] |= new_node[1:] | (loc[1:] != loc[:-1])  # ... the others the first of each voxel
    return keep


def _nodes(
    level: int, kept: np.ndarray, kept_ids: np.ndarray, remaining: np.ndarray
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The keys (level, x, y, z) and the point indices (ascending) of the nodes of one level."""
    keys, members = [], []
    bounds = np.append(np.flatnonzero(np.r_[True, kept_ids[1:] != kept_ids[:-1]]), len(kept))
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        i = int(kept_ids[a])
        keys.append(np.array([level, i >> 42, (i >> 21) & MASK21, i & MASK21], dtype=np.int32))
        members.append(remaining[np.sort(kept[a:b])])
    return keys, members


@dataclass(frozen=True)
class _Source:
    """The source cloud's header and its point records as bytes (n, record size), uncompressed."""

    header: laspy.LasHeader
    evlrs: list
    records: np.ndarray


def _read_source(src: Path) -> _Source:
    """The header, EVLRs and point records of *src*, checked for what COPC requires."""
    with laspy.open(str(src)) as reader:
        header = reader.header
        fmt = header.point_format
        if fmt.id not in (6, 7, 8) or str(header.version) != "1.4":
            raise ValueError(
                f"COPC holds LAS 1.4 point formats 6, 7 or 8 and the cloud is LAS {header.version} format {fmt.id}"
            )
        if not header.global_encoding.wkt or not any(v.record_id == 2112 for v in header.vlrs):
            raise ValueError("COPC requires the CRS as WKT and the cloud has none (set input.crs)")
        n = int(header.point_count)
        evlrs = list(reader.evlrs or []) if hasattr(reader, "evlrs") else []
        compressed = header.are_points_compressed
        offset_to_points = header.offset_to_point_data
    if n == 0:
        raise ValueError("the cloud is empty and a COPC file needs at least one point")
    size = fmt.size
    if compressed:
        records = np.frombuffer(laspy.read(str(src)).points.array.tobytes(), np.uint8).reshape(n, size)
    else:
        records = np.memmap(src, dtype=np.uint8, mode="r", offset=offset_to_points, shape=(n, size))
    return _Source(header, evlrs, records)


def _coordinates_and_times(records: np.ndarray, chunk_size: int) -> tuple[np.ndarray, list[float]]:
    """Integer X, Y, Z (n, 3) and the GPS time range, in one pass over the records."""
    # X, Y, Z are the records' first 12 bytes, the GPS time bytes 22-29 in formats 6-8 (LAS 1.4 R15, Table 28)
    n = len(records)
    xyz = np.empty((n, 3), dtype=np.int32)
    gps = [math.inf, -math.inf]
    for at in range(0, n, chunk_size):
        block = records[at : at + chunk_size]
        xyz[at : at + len(block)] = np.ascontiguousarray(block[:, :12]).view("<i4")
        t = np.ascontiguousarray(block[:, 22:30]).view("<f8")
        gps = [min(gps[0], float(t.min())), max(gps[1], float(t.max()))]
    return xyz, gps


def _copc_header(header, lo: np.ndarray, hi: np.ndarray):
    """The COPC file's header: the source's, with the info VLR first, the LAZ VLR, the bounds of the points.

    Returns the header, the LAZ VLR (variable-size chunks) and the info VLR (its payload written last).
    """
    fmt = header.point_format
    out = copy.deepcopy(header)
    out.point_count = int(header.point_count)
    out.mins, out.maxs = lo, hi
    laz_vlr = lazrs.LazVlr.new_for_compression(fmt.id, fmt.num_extra_bytes, use_variable_size_chunks=True)
    info = VLR("copc", 1, "COPC info VLR", bytes(INFO.size))
    others = [v for v in header.vlrs if not isinstance(v, LasZipVlr) and v.user_id != "copc"]
    out.vlrs = VLRList([info, LasZipVlr(laz_vlr.record_data()), *others])
    out.are_points_compressed = True
    return out, laz_vlr, info


def _write_chunks(f, out, laz_vlr, records: np.ndarray, tree: Octree, chunk_size: int) -> tuple[np.ndarray, ...]:
    """One LAZ chunk per node, compressed on every core; the byte size and point count of each chunk."""
    # batches of about chunk_size points bound the memory
    compressor = lazrs.ParLasZipCompressor(f, laz_vlr)
    batch: list[np.ndarray] = []
    held = 0
    for i in range(len(tree.keys)):
        idx = tree.order[tree.starts[i] : tree.starts[i + 1]]
        batch.append(np.ascontiguousarray(records[idx]).reshape(-1))
        held += len(idx)
        if held >= chunk_size or i == len(tree.keys) - 1:
            compressor.compress_chunks(batch)
            batch, held = [], 0
    compressor.done()
    f.seek(out.offset_to_point_data)
    table = lazrs.read_chunk_table(f, laz_vlr)
    sizes = np.array([b for _, b in table], dtype=np.int64)
    counts = np.array([c for c, _ in table], dtype=np.int64)
    if not np.array_equal(counts, np.diff(tree.starts)):
        raise RuntimeError("the LAZ chunk table does not match the octree's nodes")
    return sizes, counts


def _hierarchy_page(tree: Octree, first_chunk: int, sizes: np.ndarray, counts: np.ndarray) -> bytes:
    """The hierarchy: one entry per node, its key, the offset and size of its chunk, its point count."""
    offsets = first_chunk + np.concatenate([[0], np.cumsum(sizes)[:-1]])
    return b"".join(
        ENTRY.pack(*map(int, k), int(o), int(s), int(c))
        for k, o, s, c in zip(tree.keys, offsets, sizes, counts, strict=True)
    )


def _write_evlrs(f, out, page: bytes, evlrs: list) -> int:
    """The hierarchy EVLR first, then the source's EVLRs, at the end of *f*; the offset of the hierarchy."""
    f.seek(0, 2)
    out.start_of_first_evlr = f.tell()
    hierarchy = VLR("copc", 1000, "EPT hierarchy", page)
    ev = VLRList([hierarchy, *[e for e in evlrs if e.user_id != "copc"]])
    ev.write_to(f, as_extended=True)
    out.number_of_evlrs = len(ev)
    return out.start_of_first_evlr + 60  # an EVLR header is 60 bytes


def write_copc(src: Path, dst: Path, max_node_points: int = 100_000, chunk_size: int = 1_000_000) -> dict:
    """Write the points of the LAS/LAZ file *src* (LAS 1.4, format 6, 7 or 8, a WKT CRS) as the COPC file *dst*.

    *dst* is written in place (the caller writes to a temporary name).
    *max_node_points*: largest node of the octree; *chunk_size*: records
    read at a time for the coordinates and GPS times, and points compressed
    in one batch.  Returns ``nodes``, ``levels``, ``points``, ``spacing``
    (root node, in the CRS's unit) and ``halfsize``.

    Raises
    ------
    ValueError
        When *src* is not LAS 1.4 with point format 6, 7 or 8, or has no WKT CRS (COPC requires both).
    """
    source = _read_source(src)
    header, records = source.header, source.records
    xyz, gps = _coordinates_and_times(records, chunk_size)
    scales, offsets = np.asarray(header.scales), np.asarray(header.offsets)
    tree = build_octree(xyz, max_node_points=max_node_points, scale=scales, offset=offsets)
    lo, hi = xyz.min(axis=0) * scales + offsets, xyz.max(axis=0) * scales + offsets
    del xyz
    out, laz_vlr, info = _copc_header(header, lo, hi)
    with open(dst, "w+b") as f:
        out.write_to(f)
        first_chunk = out.offset_to_point_data + 8  # after the offset to the chunk table
        sizes, counts = _write_chunks(f, out, laz_vlr, records, tree, chunk_size)
        page = _hierarchy_page(tree, first_chunk, sizes, counts)
        root_offset = _write_evlrs(f, out, page, source.evlrs)
        info.record_data = INFO.pack(
            *map(float, tree.center), tree.halfsize, tree.spacing, root_offset, len(page), gps[0], gps[1], *([0] * 11)
        )
        f.seek(0)
        out.write_to(f, ensure_same_size=True)
    return {
        "nodes": int(len(tree.keys)),
        "levels": int(tree.keys[:, 0].max()) + 1,
        "points": len(records),
        "spacing": tree.spacing,
        "halfsize": tree.halfsize,
    }
