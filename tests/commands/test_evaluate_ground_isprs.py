"""The default ground filter against CSF on the shared ISPRS samples (issue 7's acceptance).

Apart from test_evaluate_ground.py so that, the test files running whole on
one worker each, this long test shares the workers with the rest.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from commands.evaluate.command import evaluate_ground
from stages.classify_ground.csf import CsfParams
from stages.classify_ground.smrf import SmrfParams

ROOT = Path(__file__).resolve().parents[2]
ISPRS = Path(os.environ.get("ISPRS_DIR", ROOT.parent / "shared" / "data" / "isprs"))
SAMPLES = ["samp11", "samp31", "samp51"]


@pytest.mark.slow
def test_default_beats_csf_on_the_isprs_samples(need_data):
    """Issue 7's acceptance: default mean total error <= 5 % and below CSF's (fails under CI without the data)."""
    need_data(*(ISPRS / f"{name}.laz" for name in SAMPLES), what="ISPRS samples")
    default, cloth = [], []
    for name in SAMPLES:
        rows, _ = evaluate_ground(ISPRS / f"{name}.laz", [SmrfParams(name="smrf"), CsfParams(name="csf")])
        default.append(rows[0]["total"])
        cloth.append(rows[1]["total"])
    assert np.mean(default) <= 0.05, default
    assert np.mean(default) < np.mean(cloth), (default, cloth)
