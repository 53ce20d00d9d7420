"""The default ground filter against CSF on the shared ISPRS samples (issue 7's acceptance).

Apart from test_evaluate_ground.py so that, the test files running whole on
one worker each, this long test shares the workers with the rest.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from commands.evaluate.command import evaluate_ground
from stages.classify_ground.csf import CsfParams
from stages.classify_ground.smrf import SmrfParams
from tests.shared_data import ISPRS

ROOT = Path(__file__).resolve().parents[2]
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


#: Total error (per cent) of each shared sample before the stages after the ground filter (5a6233d), the
#: whole run's classes (benchmarks/real_classes.py --at 5a6233d): no later stage may take ground away.
BEFORE_LATER_STAGES = {"samp11": 8.42, "samp31": 1.88, "samp51": 2.88, "samp61": 2.12, "samp71": 1.89}


@pytest.mark.slow
def test_no_stage_after_the_ground_filter_takes_ground_away():
    """Every shared sample within 0.1 percentage point of its total error before the objects and water stages
    (9bc4798: samp61 5.24 %, samp71 5.73 %, an embankment and a plateau taken for roofs and a deck)."""
    totals = {}
    for name in BEFORE_LATER_STAGES:
        rows, _ = evaluate_ground(ISPRS / f"{name}.laz", [None], dtm=False)
        totals[name] = 100.0 * rows[0]["total"]
    assert all(totals[n] <= BEFORE_LATER_STAGES[n] + 0.1 for n in totals), totals
