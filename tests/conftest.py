"""Shared test setup."""

from __future__ import annotations

from pathlib import Path

import pytest


@pytest.fixture(autouse=True)
def _config_snapshots_per_test(monkeypatch: pytest.MonkeyPatch, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Each test keeps its config snapshots (pipeline.config.snapshot) in a directory of its own: a snapshot one test
    wrote never answers another's configs, and the user's ~/.cache is not touched. Subprocesses inherit it."""
    directory = tmp_path_factory.mktemp("auvid-cache")
    monkeypatch.setenv("AUVID_CACHE_DIR", str(directory))
    return directory
