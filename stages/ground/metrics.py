"""Accuracy of a ground classification against reference labels (ISPRS filter test).

Sithole, G., Vosselman, G. (2004).  Experimental comparison of filter
algorithms for bare-Earth extraction from airborne laser scanning point
clouds.  ISPRS J. Photogramm. Remote Sens. 59(1-2), 85-101.
doi:10.1016/j.isprsjprs.2004.05.004
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np


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
