"""The k nearest neighbours of points chosen canonically (by distance, ties by index): a tile chooses as the whole survey."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from scipy.spatial import cKDTree


def canonical_neighbours(tree: cKDTree, queries: np.ndarray, k: int, upper: float) -> tuple[np.ndarray, np.ndarray]:
    """The *k* nearest points of each query within *upper*, chosen canonically.

    By distance, ties by index: a k-d tree breaks a tie at the k-th distance
    by its own traversal order, which changes with the set of points it
    holds (coordinates on a millimetre grid tie often), so a tile and the
    whole survey could pick different neighbours.  Rows are sorted by
    distance, then index; a missing neighbour has distance inf and index
    ``tree.n``.

    Returns
    -------
    dist, idx : ndarray, shape (len(queries), k)
    """
    n = tree.n
    m = len(queries)
    kk = min(k + 1, n)
    dist, idx = tree.query(queries, k=kk, distance_upper_bound=upper, workers=-1)
    dist, idx = dist.reshape(m, kk), idx.reshape(m, kk)
    if kk > k:
        # rows whose k-th and (k+1)-th neighbours tie: ask for more until the tie is inside
        tied = np.flatnonzero(np.isfinite(dist[:, k]) & (dist[:, k] == dist[:, k - 1]))
        more = kk
        while len(tied) and more < n:
            more = min(2 * more + 8, n)
            d2, i2 = tree.query(queries[tied], k=more, distance_upper_bound=upper, workers=-1)
            d2, i2 = d2.reshape(len(tied), more), i2.reshape(len(tied), more)
            order = np.lexsort((i2, d2), axis=1)[:, :kk]
            dist[tied] = np.take_along_axis(d2, order, axis=1)
            idx[tied] = np.take_along_axis(i2, order, axis=1)
            still = np.isfinite(d2[:, -1]) & (d2[:, -1] == dist[tied, k - 1])
            tied = tied[still]
    # The tree returns rows sorted by distance: only rows with equal
    # distances need their ties put in index order.
    same = (dist[:, 1:] == dist[:, :-1]) & np.isfinite(dist[:, 1:])
    tie = np.flatnonzero(same.any(axis=1))
    if len(tie):
        order = np.lexsort((idx[tie], dist[tie]), axis=1)
        dist[tie], idx[tie] = np.take_along_axis(dist[tie], order, axis=1), np.take_along_axis(idx[tie], order, axis=1)
    dist, idx = dist[:, :k], idx[:, :k]
    if dist.shape[1] < k:  # fewer points than k
        pad = k - dist.shape[1]
        dist = np.hstack((dist, np.full((m, pad), np.inf)))
        idx = np.hstack((idx, np.full((m, pad), n)))
    return dist, idx
