"""The triangulation every TIN is made with (lidar.delaunay) against SciPy's Delaunay (Qhull), an independent one."""

from __future__ import annotations

import numpy as np
from scipy.spatial import Delaunay

from lidar.delaunay import delaunay


def _as_set(triangles: np.ndarray) -> set[tuple[int, ...]]:
    return {tuple(sorted(t)) for t in triangles.tolist()}


def test_the_triangles_are_qhulls_in_general_position():
    xy = np.random.default_rng(2).uniform(0, 100, (2000, 2))
    triangles, _ = delaunay(xy)
    assert _as_set(triangles) == _as_set(Delaunay(xy).simplices)
    a, b, c = xy[triangles[:, 0]], xy[triangles[:, 1]], xy[triangles[:, 2]]
    assert np.all((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]) > 0)


def test_neighbour_k_lies_across_the_edge_opposite_vertex_k():
    xy = np.random.default_rng(3).uniform(0, 50, (500, 2))
    triangles, neighbours = delaunay(xy)
    hull_edges = 0
    for t, (tri, near) in enumerate(zip(triangles, neighbours, strict=True)):
        for k in range(3):
            edge = {int(tri[(k + 1) % 3]), int(tri[(k + 2) % 3])}
            if near[k] < 0:
                hull_edges += 1
                continue
            assert edge <= set(triangles[near[k]].tolist()) and t in neighbours[near[k]]
    assert hull_edges == len(Delaunay(xy).convex_hull)


def test_points_on_a_line_or_too_few_make_none_and_duplicates_are_one_vertex():
    line = np.column_stack((np.arange(10.0), 2.0 * np.arange(10.0)))
    assert delaunay(line) is None and delaunay(line[:2]) is None
    square = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0], [1.0, 1.0]])  # a corner twice
    triangles, _ = delaunay(square)
    assert len(triangles) == 2 and len(set(triangles.ravel().tolist()) & {2, 4}) == 1
