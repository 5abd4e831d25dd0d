"""Fixtures of the training tests."""

from __future__ import annotations

import pytest


@pytest.fixture
def laplab_home(tmp_path, monkeypatch):
    """A fresh ``$LAPLAB_HOME`` under the test's tmp_path (its path)."""
    monkeypatch.setenv("LAPLAB_HOME", str(tmp_path / "home"))
    return tmp_path / "home"
