"""Accuracy of a ground classification against reference labels (ISPRS filter test).

Sithole, G., Vosselman, G. (2004).  Experimental comparison of filter
algorithms for bare-Earth extraction from airborne laser scanning point
clouds.  ISPRS J. Photogramm. Remote Sens. 59(1-2), 85-101.
doi:10.1016/j.isprsjprs.2004.05.004
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial import Delaunay, QhullError

from commands.evaluate.arguments import DTM_CELL, DTM_MAX_EDGE
from lidar.grid import Grid
from stages.rasterize.interpolate import thin_points, tin
from stages.rasterize.params import RasterizeParams


@dataclass(frozen=True)
class GroundScore:
    """Errors of a ground/non-ground split, as fractions (not per cent).

    Attributes
    ----------
    type_1 : float
        Ground rejected as object / reference ground points.
    type_2 : float
        Object accepted as ground / reference object points.
    total : float
        Misclassified points / all points.
    kappa : float
        Cohen's kappa of the 2 x 2 confusion matrix.
    """

    n: int
    ground_as_ground: int
    ground_as_object: int
    object_as_ground: int
    object_as_object: int
    type_1: float
    type_2: float
    total: float
    kappa: float

    def as_dict(self) -> dict:
        return asdict(self)


def score(reference_ground: np.ndarray, predicted_ground: np.ndarray) -> GroundScore:
    """Type I, Type II, total error and Cohen's kappa.

    >>> s = score(np.array([1, 1, 0, 0], bool), np.array([1, 0, 0, 0], bool))
    >>> (s.type_1, s.type_2, s.total, s.kappa)
    (0.5, 0.0, 0.25, 0.5)
    """
    ref = np.asarray(reference_ground, dtype=bool)
    pred = np.asarray(predicted_ground, dtype=bool)
    if ref.shape != pred.shape:
        raise ValueError("reference and prediction differ in length")
    n = ref.size
    a = int((ref & pred).sum())  # ground kept
    b = int((ref & ~pred).sum())  # Type I
    c = int((~ref & pred).sum())  # Type II
    d = int((~ref & ~pred).sum())
    observed = (a + d) / n if n else 0.0
    expected = ((a + b) * (a + c) + (c + d) * (b + d)) / (n * n) if n else 0.0
    kappa = (observed - expected) / (1.0 - expected) if expected < 1.0 else 1.0
    return GroundScore(
        n=n,
        ground_as_ground=a,
        ground_as_object=b,
        object_as_ground=c,
        object_as_object=d,
        type_1=b / (a + b) if a + b else 0.0,
        type_2=c / (c + d) if c + d else 0.0,
        total=(b + c) / n if n else 0.0,
        kappa=kappa,
    )


#: Heights (metres) of the DTM check's counts: a cell more than 0.5 m above the
#: reference is a visible bump in a 1 m DTM's contours; more than 2 m, a false hill.
DTM_ABOVE = (0.5, 2.0)
DTM_BELOW = 0.5


@dataclass(frozen=True)
class DtmCheck:
    """The DTM of the evaluated ground against the DTM of the reference ground, cell by cell.

    Differences are evaluated - reference, in metres; shares are fractions, not
    per cent; the figures are None when no cell is compared.
    """

    cell: float  # of both DTMs
    max_edge: float  # cells inside a reference triangle with a longer edge were left out
    n: int  # cells compared: both DTMs defined and the reference dense enough
    reference_cells: int  # cells where the reference DTM is defined
    sparse_cells: int  # of those, the cells left out because the reference triangle is too long
    missing_cells: int  # of the dense reference cells, those the evaluated DTM leaves empty
    rms: float | None
    mean: float | None
    above_0_5: float | None  # share of the cells more than 0.5 m above the reference
    above_2: float | None  # ... more than 2 m above
    below_0_5: float | None  # ... more than 0.5 m below
    max_above: float | None  # largest difference above (positive) the reference
    max_below: float | None  # largest difference below (negative)

    def as_dict(self) -> dict:
        return asdict(self)


def dtm_check(
    xyz: np.ndarray,
    reference_ground: np.ndarray,
    predicted_ground: np.ndarray,
    *,
    cell: float = DTM_CELL,
    max_edge: float = DTM_MAX_EDGE,
    rasterize: RasterizeParams | None = None,
) -> DtmCheck:
    """Compare the DTM made from the predicted ground with the DTM made from the reference ground.

    Both are the pipeline's TIN (:func:`stages.rasterize.interpolate.tin`,
    with the run's ``nodata_distance`` and ``tin.thin``: *rasterize*, the
    run's ``stages.rasterize``, its defaults when None) on one grid of *cell*
    metres covering every point (*xyz*, metres).  A cell is compared only when
    the reference triangle holding its centre has no edge longer than
    *max_edge*: under a longer one the reference DTM is a guess.  Why this
    check beside Type I and kappa, and its figures on real surveys:
    docs/GROUND.md, "The DTM check".

    Parameters
    ----------
    reference_ground, predicted_ground : ndarray of bool, shape (n,)
        Which points are ground in the reference and in the classification.
    """
    rasterize = rasterize if rasterize is not None else RasterizeParams()
    nodata_distance, thin = rasterize.nodata_distance, rasterize.tin.thin
    xyz = np.asarray(xyz, dtype=np.float64)
    ref = np.asarray(reference_ground, dtype=bool)
    pred = np.asarray(predicted_ground, dtype=bool)
    if not (len(xyz) == len(ref) == len(pred)):
        raise ValueError("coordinates, reference and prediction differ in length")
    if ref.sum() < 3:
        raise ValueError("the reference has fewer than 3 ground points: no DTM to compare with")
    lo, hi = xyz[:, :2].min(axis=0), xyz[:, :2].max(axis=0)
    grid = Grid.covering(lo[0], lo[1], hi[0], hi[1], cell)
    reference = tin(xyz[ref], grid, nodata_distance=nodata_distance, thin=thin)
    evaluated = tin(xyz[pred], grid, nodata_distance=nodata_distance, thin=thin) if pred.sum() >= 3 else None
    origin = np.array([grid.xmin, grid.ymax])
    vxy = xyz[ref, :2] - origin
    vxy = vxy[thin_points(vxy, cell / 2.0, sparse=4)] if thin else np.unique(vxy, axis=0)
    defined = np.isfinite(reference)
    dense = defined & ~_in_long_triangles(vxy, grid, max_edge)
    both = dense & np.isfinite(evaluated) if evaluated is not None else np.zeros_like(dense)
    d = (evaluated[both] - reference[both]) if evaluated is not None else np.zeros(0)
    some = d.size > 0
    return DtmCheck(
        cell=float(cell),
        max_edge=float(max_edge),
        n=int(d.size),
        reference_cells=int(defined.sum()),
        sparse_cells=int((defined & ~dense).sum()),
        missing_cells=int((dense & ~both).sum()),
        rms=float(np.sqrt(np.mean(d**2))) if some else None,
        mean=float(np.mean(d)) if some else None,
        above_0_5=float(np.mean(d > DTM_ABOVE[0])) if some else None,
        above_2=float(np.mean(d > DTM_ABOVE[1])) if some else None,
        below_0_5=float(np.mean(d < -DTM_BELOW)) if some else None,
        max_above=float(max(d.max(), 0.0)) if some else None,
        max_below=float(min(d.min(), 0.0)) if some else None,
    )


def _in_long_triangles(xy: np.ndarray, grid, max_edge: float, batch_cells: int = 1_000_000) -> np.ndarray:
    """Cells of *grid* whose centre lies in (or on) a Delaunay triangle of *xy* with an edge longer than *max_edge*.

    *xy* are relative to the grid's top-left corner.  Only the long
    triangles are drawn, each over the cells of its box (barycentric test,
    *batch_cells* candidate cells at a time), so the cost follows the
    voids, not the survey.
    """

    out = np.zeros((grid.rows, grid.cols), dtype=bool)
    if len(xy) < 3 or not np.isfinite(max_edge):
        return out
    try:
        tri = Delaunay(xy)
    except QhullError:  # all on a line: no triangle, and the TIN has no cell either
        return out
    corners = xy[tri.simplices]
    longest = np.max(np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2), axis=1)
    p = corners[longest > max_edge]
    res = grid.resolution
    c0 = np.clip(np.ceil(p[:, :, 0].min(axis=1) / res - 0.5), 0, None).astype(np.int64)
    c1 = np.clip(np.floor(p[:, :, 0].max(axis=1) / res - 0.5), None, grid.cols - 1).astype(np.int64)
    r0 = np.clip(np.ceil(-p[:, :, 1].max(axis=1) / res - 0.5), 0, None).astype(np.int64)
    r1 = np.clip(np.floor(-p[:, :, 1].min(axis=1) / res - 0.5), None, grid.rows - 1).astype(np.int64)
    width = np.maximum(c1 - c0 + 1, 0)
    count = width * np.maximum(r1 - r0 + 1, 0)
    a, b = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    ends = np.cumsum(count)
    first = 0
    while first < len(p):
        base = int(ends[first - 1]) if first else 0
        last = max(first + 1, int(np.searchsorted(ends, base + batch_cells, side="right")))
        t = np.repeat(np.arange(first, last), count[first:last])
        k = np.arange(len(t)) - np.repeat(ends[first:last] - count[first:last] - base, count[first:last])
        col, row = c0[t] + k % width[t], r0[t] + k // width[t]
        vx, vy = (col + 0.5) * res - p[t, 0, 0], -(row + 0.5) * res - p[t, 0, 1]
        l1 = (vx * b[t, 1] - vy * b[t, 0]) / det[t]
        l2 = (a[t, 0] * vy - a[t, 1] * vx) / det[t]
        inside = (l1 >= -1e-9) & (l2 >= -1e-9) & (l1 + l2 <= 1.0 + 1e-9)
        out[row[inside], col[inside]] = True
        first = last
    return out


@dataclass(frozen=True)
class ClassRow:
    """One ASPRS class of a multi-class comparison: counts, and recall and precision as fractions (None: 0 / 0)."""

    code: int
    name: str
    reference: int  # points of this class in the reference
    predicted: int  # points the classification gave this class
    correct: int  # points of this class in both
    recall: float | None  # correct / reference
    precision: float | None  # correct / predicted


@dataclass(frozen=True)
class ClassScores:
    """A classification against reference labels: per class, overall accuracy and Cohen's kappa (fractions)."""

    n: int
    classes: list[ClassRow]
    accuracy: float
    kappa: float

    def as_dict(self) -> dict:
        return asdict(self)


def class_scores(reference: np.ndarray, predicted: np.ndarray, name: Callable[[int], str] = str) -> ClassScores:
    """Per-class recall and precision, overall accuracy and Cohen's kappa of two labellings.

    Every class present in either labelling has a row (ascending codes),
    named by *name* (e.g. :func:`lidar.glossary.class_name`).
    Kappa is Cohen's over the full confusion matrix (Cohen 1960,
    doi:10.1177/001316446002000104).

    >>> s = class_scores(np.array([2, 2, 6, 6]), np.array([2, 6, 6, 6]))
    >>> [(r.code, r.recall, r.precision) for r in s.classes], s.accuracy, s.kappa
    ([(2, 0.5, 1.0), (6, 1.0, 0.6666666666666666)], 0.75, 0.5)
    """
    ref = np.asarray(reference).astype(np.int64)
    pred = np.asarray(predicted).astype(np.int64)
    if ref.shape != pred.shape:
        raise ValueError("reference and prediction differ in length")
    n = ref.size
    codes = np.union1d(ref, pred)
    r_idx, p_idx = np.searchsorted(codes, ref), np.searchsorted(codes, pred)
    matrix = np.bincount(r_idx * len(codes) + p_idx, minlength=len(codes) ** 2).reshape(len(codes), len(codes))
    ref_n, pred_n, diag = matrix.sum(axis=1), matrix.sum(axis=0), np.diag(matrix)
    observed = float(diag.sum() / n) if n else 0.0
    expected = float((ref_n * pred_n).sum() / (n * n)) if n else 0.0
    kappa = (observed - expected) / (1.0 - expected) if expected < 1.0 else 1.0
    rows = [
        ClassRow(
            code=int(c),
            name=name(int(c)),
            reference=int(ref_n[i]),
            predicted=int(pred_n[i]),
            correct=int(diag[i]),
            recall=float(diag[i] / ref_n[i]) if ref_n[i] else None,
            precision=float(diag[i] / pred_n[i]) if pred_n[i] else None,
        )
        for i, c in enumerate(codes)
    ]
    return ClassScores(n=int(n), classes=rows, accuracy=observed, kappa=float(kappa))
