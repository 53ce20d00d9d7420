"""A LAS 1.4 point cloud rewritten as a Cloud Optimized Point Cloud (``points.copc.laz``).

COPC 1.0 (https://copc.io, Hobu Inc. 2021) is a LAZ 1.4 file whose points
are ordered by an octree so that a viewer (QGIS, potree-like web viewers,
PDAL's ``readers.copc``) reads only the nodes of the region and level of
detail it draws:

- point format 6, 7 or 8, and the CRS as a WKT VLR (global encoding bit 4);
- the first VLR is the COPC info record (user id ``copc``, record 1, 160
  bytes, so at byte 375 of the file): the octree's cube (centre,
  half-size), the spacing of the root node, where the hierarchy is, and
  the GPS time range;
- the points of every octree node are one LAZ chunk (variable-size chunks,
  LASzip chunk size ``0xFFFFFFFF``), so a node can be decompressed alone;
- an EVLR (``copc``, record 1000) holds the hierarchy: one 32-byte entry per
  node, its key (level, x, y, z), the offset and size of its chunk and its
  point count.

Written here with laspy and lazrs rather than the ``copclib`` wheel: every
field, extra-byte dimension, VLR and EVLR of the delivered cloud is copied
byte for byte (the records are moved, never decoded and re-encoded), and no
second LAS library is needed.  The octree is built the way PDAL's
``writers.copc`` and untwine do it: each node is a grid of
``GRID`` × ``GRID`` × ``GRID`` voxels and keeps one point per occupied voxel
(the first in file order); the other points go down to its children, and a
node with at most ``max_node_points`` points left keeps them all (a leaf).
Each point is in exactly one node.

Memory: the points' integer coordinates (12 bytes a point), the node order
(8 bytes a point) and, level by level, the sort keys of the points not yet
placed (about 60 bytes a point at level 0) are held; the point records are
gathered node by node from the uncompressed intermediate through a memory
map and compressed in batches on every core (lazrs).
"""

from __future__ import annotations

import copy
import math
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: voxels per side of a node's sampling grid (PDAL writers.copc and untwine use 128)
GRID = 128
#: the COPC info VLR's payload: centre x, y, z, half-size, spacing, hierarchy offset and size, GPS time min and max,
#: 11 reserved
INFO = struct.Struct("<5d2Q2d11Q")
#: one hierarchy entry: key (level, x, y, z), offset, byte size, point count
ENTRY = struct.Struct("<iiiiQii")
#: offset of the info VLR's payload: the LAS 1.4 header (375 bytes) and a VLR header (54 bytes)
INFO_PAYLOAD_OFFSET = 375 + 54
#: the deepest level built; deeper points stay in their node
MAX_LEVEL = 20


@dataclass(frozen=True)
class Octree:
    """The nodes of a COPC octree and the points of each.

    Attributes
    ----------
    center : ndarray (3,)
        Centre of the root cube (scaled coordinates).
    halfsize : float
        Half the side of the root cube.
    spacing : float
        Distance between points of the root node (its voxel side).
    keys : ndarray (nodes, 4) of int32
        Level, x, y, z of each node, in writing order.
    starts : ndarray (nodes + 1,) of int64
        Node ``i`` holds ``order[starts[i]:starts[i + 1]]``.
    order : ndarray of int64
        Point indices, node by node (ascending within a node).
    """

    center: np.ndarray
    halfsize: float
    spacing: float
    keys: np.ndarray
    starts: np.ndarray
    order: np.ndarray


def build_octree(
    coords: np.ndarray,
    max_node_points: int = 100_000,
    grid: int = GRID,
    scale: tuple[float, float, float] = (1.0, 1.0, 1.0),
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    chunk: int = 1_000_000,
) -> Octree:
    """Put each point of *coords* in one node of a COPC octree.

    Parameters
    ----------
    coords : ndarray (n, 3)
        Coordinates: the points are at ``coords * scale + offset`` (a LAS
        file's integer X, Y, Z with its header's scales and offsets, or
        scaled coordinates with the defaults).
    max_node_points : int
        A node with at most this many points left keeps them all (a leaf).
    grid : int
        Voxels per side of a node's sampling grid.
    scale, offset : tuple of 3 float
        See *coords*.
    chunk : int
        Points converted at a time (bounds the temporary arrays).

    Returns
    -------
    Octree

    >>> tree = build_octree(np.random.default_rng(0).uniform(0, 100, (1000, 3)), max_node_points=100)
    >>> int(tree.starts[-1]), sorted(set(tree.order.tolist())) == list(range(1000))
    (1000, True)
    """
    scale_a, offset_a = np.asarray(scale, dtype=np.float64), np.asarray(offset, dtype=np.float64)
    n = len(coords)
    lo = coords.min(axis=0) * scale_a + offset_a
    hi = coords.max(axis=0) * scale_a + offset_a
    # The cube starts at the lowest corner of the points and its side is their largest extent, so that
    # readers that place the nodes from the header's minimum and span (copc-lib) and readers that use the
    # info VLR's centre and half-size (laspy, PDAL) see the same nodes.  Points on the upper faces go to
    # the last voxel of their row.
    side = float(max((hi - lo).max(), 1e-3))
    halfsize = side / 2.0
    origin = lo
    remaining = np.arange(n, dtype=np.int64)  # ascending: ties below keep the file order
    node_keys: list[np.ndarray] = []
    node_members: list[np.ndarray] = []
    mask21 = (1 << 21) - 1
    for level in range(MAX_LEVEL + 1):
        m = remaining.size
        if m == 0:
            break
        cells = (1 << level) * grid
        node_id = np.empty(m, dtype=np.int64)  # node x, y, z packed in 21 bits each
        local = np.empty(m, dtype=np.int32)  # voxel inside the node
        for a in range(0, m, chunk):
            idx = remaining[a : a + chunk]
            v = np.floor((coords[idx] * scale_a + offset_a - origin) / side * cells).astype(np.int64)
            np.clip(v, 0, cells - 1, out=v)
            nd = v // grid
            lc = v - nd * grid
            node_id[a : a + len(idx)] = (nd[:, 0] << 42) | (nd[:, 1] << 21) | nd[:, 2]
            local[a : a + len(idx)] = (lc[:, 0] * grid + lc[:, 1]) * grid + lc[:, 2]
        # by node, then voxel, then file order; one int64 key while node and voxel fit in 63 bits (a stable
        # argsort of one key is about twice as fast as a lexsort of two)
        if 3 * level + 21 <= 62:
            compact = ((node_id >> 42) << (2 * level)) | (((node_id >> 21) & mask21) << level) | (node_id & mask21)
            perm = np.argsort((compact << 21) | local, kind="stable")
            del compact
        else:
            perm = np.lexsort((local, node_id))
        ids, loc = node_id[perm], local[perm]
        del node_id, local
        new_node = np.ones(m, dtype=bool)
        new_node[1:] = ids[1:] != ids[:-1]
        counts = np.diff(np.append(np.flatnonzero(new_node), m))
        leaf = (counts <= max_node_points) | (level == MAX_LEVEL)
        keep = np.repeat(leaf, counts)  # a leaf keeps every point ...
        keep[0] = True
        keep[1:] |= new_node[1:] | (loc[1:] != loc[:-1])  # ... the others the first of each voxel
        kept, kept_ids = perm[keep], ids[keep]
        bounds = np.append(np.flatnonzero(np.r_[True, kept_ids[1:] != kept_ids[:-1]]), len(kept))
        for a, b in zip(bounds[:-1], bounds[1:], strict=True):
            i = int(kept_ids[a])
            node_keys.append(np.array([level, i >> 42, (i >> 21) & mask21, i & mask21], dtype=np.int32))
            node_members.append(remaining[np.sort(kept[a:b])])
        remaining = remaining[np.sort(perm[~keep])]
        del perm, ids, loc, keep, kept, kept_ids
    sizes = np.array([len(m) for m in node_members], dtype=np.int64)
    return Octree(
        center=origin + halfsize,
        halfsize=halfsize,
        spacing=side / grid,
        keys=np.array(node_keys, dtype=np.int32).reshape(-1, 4),
        starts=np.concatenate([[0], np.cumsum(sizes)]),
        order=np.concatenate(node_members) if node_members else np.zeros(0, dtype=np.int64),
    )


def write_copc(src: Path, dst: Path, max_node_points: int = 100_000, chunk_size: int = 1_000_000) -> dict:
    """Write the points of the LAS/LAZ file *src* as the COPC file *dst*.

    Parameters
    ----------
    src : Path
        LAS 1.4, point format 6, 7 or 8, with a WKT CRS.
    dst : Path
        The COPC file (written in place: the caller writes to a temporary name).
    max_node_points : int
        Largest node of the octree (points).
    chunk_size : int
        Records taken at a time for the coordinates and GPS times, and the points compressed in one batch.

    Returns
    -------
    dict
        ``nodes``, ``levels``, ``points``, ``spacing`` (root node, in the
        CRS's unit), ``halfsize``.

    Raises
    ------
    ValueError
        When *src* is not LAS 1.4 with point format 6, 7 or 8, or has no WKT CRS
        (COPC requires both).
    """
    import laspy
    import lazrs
    from laspy.vlrs.known import LasZipVlr
    from laspy.vlrs.vlr import VLR
    from laspy.vlrs.vlrlist import VLRList

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
    # one pass over the records (read once): X, Y, Z are their first 12 bytes, the GPS time bytes 22-29
    # in formats 6-8 (LAS 1.4 R15, Table 28)
    xyz = np.empty((n, 3), dtype=np.int32)
    gps = [math.inf, -math.inf]
    for at in range(0, n, chunk_size):
        block = records[at : at + chunk_size]
        xyz[at : at + len(block)] = np.ascontiguousarray(block[:, :12]).view("<i4")
        t = np.ascontiguousarray(block[:, 22:30]).view("<f8")
        gps = [min(gps[0], float(t.min())), max(gps[1], float(t.max()))]
    scales, offsets = np.asarray(header.scales), np.asarray(header.offsets)
    tree = build_octree(xyz, max_node_points=max_node_points, scale=scales, offset=offsets)
    lo, hi = xyz.min(axis=0) * scales + offsets, xyz.max(axis=0) * scales + offsets
    del xyz

    out = copy.deepcopy(header)
    out.point_count = n
    out.mins, out.maxs = lo, hi
    laz_vlr = lazrs.LazVlr.new_for_compression(fmt.id, fmt.num_extra_bytes, use_variable_size_chunks=True)
    info = VLR("copc", 1, "COPC info VLR", bytes(INFO.size))
    others = [v for v in header.vlrs if not isinstance(v, LasZipVlr) and v.user_id != "copc"]
    out.vlrs = VLRList([info, LasZipVlr(laz_vlr.record_data()), *others])
    out.are_points_compressed = True

    with open(dst, "w+b") as f:
        out.write_to(f)
        first_chunk = out.offset_to_point_data + 8  # after the offset to the chunk table
        # one LAZ chunk per node, compressed on every core; batches of about chunk_size points bound the memory
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
        offsets = first_chunk + np.concatenate([[0], np.cumsum(sizes)[:-1]])
        page = b"".join(
            ENTRY.pack(*map(int, k), int(o), int(s), int(c))
            for k, o, s, c in zip(tree.keys, offsets, sizes, counts, strict=True)
        )
        f.seek(0, 2)
        out.start_of_first_evlr = f.tell()
        hierarchy = VLR("copc", 1000, "EPT hierarchy", page)
        ev = VLRList([hierarchy, *[e for e in evlrs if e.user_id != "copc"]])
        ev.write_to(f, as_extended=True)
        out.number_of_evlrs = len(ev)
        root_offset = out.start_of_first_evlr + 60  # an EVLR header is 60 bytes
        info.record_data = INFO.pack(
            *map(float, tree.center),
            tree.halfsize,
            tree.spacing,
            root_offset,
            len(page),
            gps[0],
            gps[1],
            *([0] * 11),
        )
        f.seek(0)
        out.write_to(f, ensure_same_size=True)
    return {
        "nodes": int(len(tree.keys)),
        "levels": int(tree.keys[:, 0].max()) + 1,
        "points": n,
        "spacing": tree.spacing,
        "halfsize": tree.halfsize,
    }
