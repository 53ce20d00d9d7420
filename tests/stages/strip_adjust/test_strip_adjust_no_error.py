"""Strip adjustment of flights without injected strip error (issue 6): it must correct nothing.

The flight of test_strip_adjust.py (five lines at 50 % sidelap and a cross
line) with no strip bias or rotation, once without noise and once with its
2 cm range noise; the reference strip is the most-overlapping one.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.stages.strip_adjust.test_strip_adjust import _adjust, _flight

pytestmark = pytest.mark.slow  # simulates two flights (five lines and a cross line at 30 kHz)


def test_no_injected_error_gives_no_correction(tmp_path):
    """Nothing injected (no strip error, no noise): every correction below 5 mm and 0.001 degree."""
    sim = _flight(tmp_path, bias=0.0, rotation=0.0, noise=False)
    _adjust(tmp_path, sim, "reference_strip: most_overlap")
    report = json.loads((tmp_path / "out" / "strip_corrections.json").read_text())
    for strip in report["strips"].values():
        assert np.max(np.abs(strip["translation_m"])) < 0.005 and np.max(np.abs(strip["rotation_deg"])) < 0.001


def test_noise_alone_gives_no_significant_correction(tmp_path):
    """No strip error but 2 cm range noise: every correction within 3 sigma of zero (its own propagated sigma)."""
    sim = _flight(tmp_path, bias=0.0, rotation=0.0)
    _adjust(tmp_path, sim, "reference_strip: most_overlap")
    report = json.loads((tmp_path / "out" / "strip_corrections.json").read_text())
    for strip in report["strips"].values():
        t, st = np.abs(strip["translation_m"]), np.asarray(strip["sigma_translation_m"])
        w, sw = np.abs(strip["rotation_deg"]), np.asarray(strip["sigma_rotation_deg"])
        assert np.all(t <= 3 * st + 0.001) and np.all(w <= 3 * sw + 1e-4), strip
        assert t.max() < 0.015 and w.max() < 0.005, strip
