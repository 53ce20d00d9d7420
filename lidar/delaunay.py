"""The Delaunay triangulation every TIN of the pipeline is made with: the one place its triangulator is chosen.

The DTM's TIN (:mod:`stages.rasterize.interpolate`), the survey's outline
(:mod:`stages.rasterize.outline`) and the forest floor's envelopes
(:mod:`stages.rasterize.floor`) triangulate through :func:`delaunay`, so a
change of triangulator is made here and nowhere else.  Today it is
Shewchuk's Triangle (Shewchuk 1996, doi:10.1007/BFb0014497) through the
``triangle`` package: robust (exact predicates) and fast on a lattice of
cocircular points, where Qhull took minutes.  Triangle's notice asks for an
arrangement before it is part of a commercial product and its Python
binding is LGPL: docs/BENCHMARKS.md, and the delivery issue's permissive
default.
"""

from __future__ import annotations

import numpy as np
import triangle


def delaunay(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The Delaunay triangulation of the points *xy* ((n, 2)); None when they make no triangle (on a line).

    Returns the triangles ((m, 3) indices into *xy*, counter-clockwise) and
    their neighbours ((m, 3)): neighbour *k* of a triangle lies across the
    edge opposite its vertex *k*, -1 on the hull.  Of points with the same
    x, y one is a vertex, the others lie in no triangle.  Where points are
    cocircular the triangulation is one of the Delaunay ones.
    """
    if len(xy) < 3:
        return None
    # Q quiet, z indices from 0, n neighbours, B N: no boundary markers, no copy of the vertices
    mesh = triangle.triangulate({"vertices": np.ascontiguousarray(xy, dtype=np.float64)}, "QznBN")
    triangles = mesh.get("triangles")
    if triangles is None or not len(triangles):
        return None
    return triangles, mesh["neighbors"]
