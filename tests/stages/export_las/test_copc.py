"""``points.copc.laz``: a Cloud Optimized Point Cloud 1.0 (https://copc.io) of the delivered points.

Known answers from the COPC 1.0 specification's byte layout (the info VLR
at byte 375 of the file, 160 bytes; the hierarchy EVLR ``copc``/1000 of
32-byte entries; one LAZ chunk per node) and from laspy's own COPC reader
(laspy >= 2.2), which finds the nodes of a query from the info VLR's cube.
"""

from __future__ import annotations

import io
import struct

import laspy
import lazrs
import numpy as np
import pytest
from laspy.vlrs.vlr import VLR
from laspy.vlrs.vlrlist import VLRList
from pyproj import CRS

from stages.export_las.copc import ENTRY, INFO, build_octree, write_copc


def _survey(path, n=60_000, seed=1, fmt=7):
    """A LAS 1.4 survey: a tilted plane 300 m x 200 m with trees, RGB, an extra-byte field, a WKT CRS."""
    rng = np.random.default_rng(seed)
    header = laspy.LasHeader(point_format=fmt, version="1.4")
    header.add_extra_dim(laspy.ExtraBytesParams(name="sigma_vertical", type=np.float32))
    header.offsets = [500_000.0, 4_400_000.0, 0.0]
    header.scales = [0.001, 0.001, 0.001]
    header.add_crs(CRS.from_epsg(25830))
    header.global_encoding.gps_time_type = laspy.header.GpsTimeType.STANDARD
    header.vlrs.append(VLR("survey-co", 7, "the user's own VLR", b"kept as it is"))
    las = laspy.LasData(header)
    las.evlrs = VLRList([VLR("survey-co", 8, "the user's own EVLR", b"kept too" * 10)])
    x = rng.uniform(500_000, 500_300, n)
    y = rng.uniform(4_400_000, 4_400_200, n)
    z = 100 + 0.05 * (x - 500_000) + np.where(rng.random(n) < 0.2, rng.uniform(0, 15, n), 0.0)
    las.x, las.y, las.z = x, y, z
    las.gps_time = np.sort(rng.uniform(1.0e8, 1.0e8 + 600, n))
    las.intensity = rng.integers(0, 65535, n)
    las.classification = rng.choice([1, 2], n)
    las.point_source_id = rng.integers(1, 4, n)
    las.return_number = np.ones(n, dtype=np.uint8)
    las.number_of_returns = np.ones(n, dtype=np.uint8)
    las.red = rng.integers(0, 65535, n)
    las.green = rng.integers(0, 65535, n)
    las.blue = rng.integers(0, 65535, n)
    las.sigma_vertical = rng.uniform(0.01, 0.1, n).astype(np.float32)
    las.write(str(path))
    return path


@pytest.fixture(scope="module")
def copc(tmp_path_factory):
    folder = tmp_path_factory.mktemp("copc")
    src = _survey(folder / "points.las")
    dst = folder / "points.copc.laz"
    tree = write_copc(src, dst, max_node_points=4000)
    return src, dst, tree


def _sorted(records: np.ndarray) -> np.ndarray:
    return np.sort(records.view(np.dtype((np.void, records.dtype.itemsize))))


def test_every_point_and_field_read_back_by_laspy_copc_reader(copc):
    src, dst, tree = copc
    original = laspy.read(str(src))
    with laspy.CopcReader.open(str(dst)) as reader:
        points = reader.query()
        assert reader.header.point_format.id == 7
        assert "sigma_vertical" in reader.header.point_format.extra_dimension_names
        assert reader.header.global_encoding.gps_time_type == laspy.header.GpsTimeType.STANDARD
        assert reader.header.parse_crs().to_epsg() == 25830
    assert len(points) == len(original.points) == 60_000
    copc_file = laspy.read(str(dst))
    vlrs = [(v.user_id, v.record_id) for v in copc_file.header.vlrs]
    assert vlrs[0] == ("copc", 1) and ("survey-co", 7) in vlrs and ("LASF_Projection", 2112) in vlrs
    evlrs = {(v.user_id, v.record_id): v for v in copc_file.evlrs}
    assert ("copc", 1000) in evlrs and evlrs[("survey-co", 8)].record_data == b"kept too" * 10
    # the same records, byte for byte, as a set (the octree reorders them)
    assert np.array_equal(_sorted(points.array), _sorted(original.points.array))
    assert tree["levels"] >= 3  # 60,000 points, nodes of at most 4,000: a real octree


def test_an_ordinary_laz_reader_reads_the_same_points(copc):
    src, dst, _ = copc
    original, delivered = laspy.read(str(src)), laspy.read(str(dst))
    assert np.array_equal(_sorted(delivered.points.array), _sorted(original.points.array))
    assert delivered.header.mins.tolist() == pytest.approx(original.header.mins.tolist(), abs=1e-9)
    assert delivered.header.maxs.tolist() == pytest.approx(original.header.maxs.tolist(), abs=1e-9)


def test_a_spatial_query_returns_exactly_the_points_in_the_box(copc):
    src, dst, _ = copc
    las = laspy.read(str(src))
    mins, maxs = np.array([500_040.0, 4_400_030.0, 95.0]), np.array([500_111.5, 4_400_077.25, 120.0])
    inside = (las.x >= mins[0]) & (las.x <= maxs[0]) & (las.y >= mins[1]) & (las.y <= maxs[1])
    inside &= (las.z >= mins[2]) & (las.z <= maxs[2])
    with laspy.CopcReader.open(str(dst)) as reader:
        got = reader.query(bounds=laspy.copc.Bounds(mins, maxs))
    assert 3000 < inside.sum() == len(got)
    assert np.array_equal(_sorted(got.array), _sorted(las.points.array[inside]))


def test_the_root_level_is_a_thinned_cloud_at_the_info_spacing(copc):
    _, dst, _ = copc
    with laspy.CopcReader.open(str(dst)) as reader:
        info = reader.copc_info
        root = reader.query(level=0)
        everything = reader.query()
    # one point per voxel of side `spacing`: fewer than all points, at most one per voxel
    assert 0 < len(root) < len(everything)
    cube_min = np.array(info.center) - info.halfsize
    voxel = np.floor((np.column_stack([root.x, root.y, root.z]) - cube_min) / info.spacing).astype(np.int64)
    assert len(np.unique(voxel, axis=0)) == len(root)
    assert info.spacing == pytest.approx(2 * info.halfsize / 128)


def _layout(path):
    data = path.read_bytes()
    header = laspy.LasHeader.read_from(io.BytesIO(data))
    return data, header


def test_byte_layout_of_the_copc_specification(copc):
    src, dst, tree = copc
    data, header = _layout(dst)
    assert data[:4] == b"LASF" and data[24:26] == bytes([1, 4])
    assert data[104] == 7 | 0x80  # point format 7, LAZ bit
    assert struct.unpack_from("<H", data, 6)[0] & 0x10  # global encoding: WKT
    # the info VLR first, at byte 375: reserved, user id "copc", record id 1, 160 bytes
    reserved, user_id, record_id, length = struct.unpack_from("<H16sHH", data, 375)
    assert (user_id.rstrip(b"\0"), record_id, length) == (b"copc", 1, 160)
    cx, cy, cz, half, spacing, h_off, h_size, t_min, t_max, *rest = INFO.unpack_from(data, 375 + 54)
    assert rest == [0] * 11 and spacing > 0 and half > 0
    las = laspy.read(str(src))
    xyz = np.column_stack([las.x, las.y, las.z])
    centre = np.array([cx, cy, cz])
    assert np.all(xyz >= centre - half) and np.all(xyz <= centre + half)  # the root cube holds every point
    assert (t_min, t_max) == (float(las.gps_time.min()), float(las.gps_time.max()))
    # the LASzip VLR declares variable-size chunks
    laz = next(v for v in header.vlrs if v.record_id == 22204)
    assert lazrs.LazVlr(laz.record_data).uses_variable_size_chunks()
    # the hierarchy: an EVLR copc/1000 whose payload is where the info says
    evlr_start = header.start_of_first_evlr
    _, user_id, record_id, ev_len = struct.unpack_from("<H16sHQ", data, evlr_start)
    assert (user_id.rstrip(b"\0"), record_id) == (b"copc", 1000)
    assert (h_off, h_size) == (evlr_start + 60, ev_len) and h_size % ENTRY.size == 0
    entries = [ENTRY.unpack_from(data, h_off + i) for i in range(0, h_size, ENTRY.size)]
    assert sum(e[6] for e in entries) == len(las.points)
    keys = {e[:4] for e in entries}
    assert (0, 0, 0, 0) in keys
    for level, x, y, z, offset, size, count in entries:
        # every node's parent is in the hierarchy, and every node is one LAZ chunk that decompresses alone
        assert level == 0 or (level - 1, x // 2, y // 2, z // 2) in keys
        assert count > 0
        out = np.zeros(count * las.header.point_format.size, np.uint8)
        lazrs.decompress_points_with_chunk_table(
            data[offset : offset + size],
            laz.record_data,
            out,
            [(count, size)],
            lazrs.DecompressionSelection(lazrs.SELECTIVE_DECOMPRESS_ALL),
        )
        node = np.frombuffer(out.tobytes(), dtype=las.points.array.dtype)
        step = 2 * half / 2**level
        lo = centre - half + step * np.array([x, y, z])
        pts = np.column_stack([node["X"], node["Y"], node["Z"]]) * header.scales + header.offsets
        assert np.all(pts >= lo - 1e-6) and np.all(pts <= lo + step + 1e-6), (level, x, y, z)


def test_every_point_in_one_node_and_leaves_small():
    rng = np.random.default_rng(3)
    xyz = np.vstack([rng.uniform(0, 10, (5000, 3)), rng.uniform(0, 1000, (2000, 3))])  # one dense corner
    tree = build_octree(xyz, max_node_points=500)
    assert np.array_equal(np.sort(tree.order), np.arange(len(xyz)))
    assert len({tuple(k) for k in tree.keys}) == len(tree.keys)
    # the dense corner needs deeper levels than the sparse rest
    assert tree.keys[:, 0].max() >= 4


def test_a_cloud_without_crs_is_refused_with_a_reason(tmp_path):
    header = laspy.LasHeader(point_format=6, version="1.4")
    las = laspy.LasData(header)
    las.x, las.y, las.z = np.arange(10.0), np.arange(10.0), np.arange(10.0)
    las.write(str(tmp_path / "p.las"))
    with pytest.raises(ValueError, match="WKT"):
        write_copc(tmp_path / "p.las", tmp_path / "p.copc.laz")


def _check_tree(xyz, tree, grid, max_node_points):
    """The COPC octree's invariants, from the geometry of the cube alone."""
    assert np.array_equal(np.sort(tree.order), np.arange(len(xyz)))  # every point in exactly one node
    keys = {tuple(int(v) for v in k) for k in tree.keys}
    assert len(keys) == len(tree.keys)  # no node twice
    has_child = {(lv - 1, x // 2, y // 2, z // 2) for lv, x, y, z in keys if lv > 0}
    lo0 = tree.center - tree.halfsize
    for i, (level, x, y, z) in enumerate(tree.keys):
        assert level == 0 or (level - 1, x // 2, y // 2, z // 2) in keys  # its parent is there
        step = 2 * tree.halfsize / 2**level
        pts = xyz[tree.order[tree.starts[i] : tree.starts[i + 1]]]
        lo = lo0 + step * np.array([x, y, z])
        assert np.all(pts >= lo - 1e-9) and np.all(pts <= lo + step + 1e-9), (level, x, y, z)
        if (level, x, y, z) in has_child:  # an inner node: one point per voxel of its grid
            voxel = np.clip(np.floor((pts - lo) / step * grid), 0, grid - 1).astype(int)
            assert len(np.unique(voxel, axis=0)) == len(pts), (level, x, y, z)
        else:
            assert len(pts) <= max_node_points or level == 20


def test_octree_invariants_with_many_nodes_on_every_level():
    rng = np.random.default_rng(6)
    xyz = rng.uniform(0, 1000, (20_000, 3))
    tree = build_octree(xyz, max_node_points=50, grid=4)
    assert tree.keys[:, 0].max() >= 4 and np.sum(tree.keys[:, 0] == 3) > 100
    _check_tree(xyz, tree, 4, 50)


def test_a_deep_octree_keeps_its_invariants():
    """A 3 m cluster far from two outliers: nodes 15 levels deep and more (past the single-key sort)."""
    rng = np.random.default_rng(4)
    xyz = np.vstack([rng.uniform(0, 3.0, (20_000, 3)) + 5000.0, [[0.0, 0.0, 0.0], [1e4, 1e4, 1e4]]])
    tree = build_octree(xyz, max_node_points=50, grid=4)
    assert np.sum(tree.keys[:, 0] == 15) > 10
    _check_tree(xyz, tree, 4, 50)
