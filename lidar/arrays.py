"""Small array operations NumPy does slowly for our inputs."""

from __future__ import annotations

import numpy as np


def sorted_union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The sorted unique values of two sorted arrays of unique values (what ``np.union1d`` gives).

    A stable sort of the two runs is a merge.  ``np.union1d`` hashes them
    (NumPy 2.4), slowly when most values are distinct: 280 ms for 512,000 +
    10,000 outline cells against 2 ms, 1.2 s for 1.5 M + 0.6 M point indices
    against 9 ms.

    >>> sorted_union(np.array([1, 4, 6]), np.array([2, 4, 9])).tolist()
    [1, 2, 4, 6, 9]
    """
    values = np.concatenate((a, b))
    values.sort(kind="stable")
    new = np.empty(len(values), dtype=bool)
    new[:1] = True
    np.not_equal(values[1:], values[:-1], out=new[1:])
    return values[new]


def add_counts(counts: np.ndarray, index: np.ndarray) -> None:
    """Add one to ``counts[i]`` for each *i* of *index* (repeats count again), in place.

    ``np.add.at`` with an array of ones of the counts' own type takes its
    fast path: 1.4 ms a million indices, where a scalar 1 took 50 ms and a
    ``np.bincount`` as long as *counts* 13 ms a chunk on 12.8 M cells,
    whatever the chunk's size.

    >>> c = np.zeros(4, np.int32); add_counts(c, np.array([1, 3, 1])); c.tolist()
    [0, 2, 0, 1]
    """
    np.add.at(counts, index, np.ones(len(index), counts.dtype))
