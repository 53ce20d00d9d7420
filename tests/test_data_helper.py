"""Data-dependent tests skip on a workstation but fail under CI (tests/conftest.py, issue 19)."""

from __future__ import annotations

import pytest

from tests.conftest import require_data


def test_missing_data_skips_without_ci(tmp_path, monkeypatch):
    monkeypatch.delenv("CI", raising=False)
    with pytest.raises(pytest.skip.Exception, match="ISPRS samples not found"):
        require_data(tmp_path / "nope.laz", what="ISPRS samples")


@pytest.mark.parametrize("value", ["true", "1", "yes"])
def test_missing_data_fails_under_ci(tmp_path, monkeypatch, value):
    monkeypatch.setenv("CI", value)
    with pytest.raises(pytest.fail.Exception, match="CI is set and ISPRS samples not found"):
        require_data(tmp_path / "nope.laz", what="ISPRS samples")


def test_present_data_runs(tmp_path, monkeypatch):
    monkeypatch.setenv("CI", "true")
    (tmp_path / "here.laz").write_bytes(b"")
    require_data(tmp_path / "here.laz")  # neither skips nor fails
    monkeypatch.setenv("CI", "false")
    with pytest.raises(pytest.skip.Exception):
        require_data(tmp_path / "nope.laz")
