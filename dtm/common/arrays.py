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
