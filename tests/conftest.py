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


@pytest.fixture
def svr_fold_fits(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, int]]:
    """Every SVR fit of the hyperparameter searches a test runs, as (training rows, test rows)."""
    from pipeline.models import search as search_mod

    seen: list[tuple[int, int]] = []
    real = search_mod._fold_fit

    def counting(est, X, y, train, test):  # noqa: ANN001, ANN202
        seen.append((len(train), len(test)))
        return real(est, X, y, train, test)

    monkeypatch.setattr(search_mod, "_fold_fit", counting)
    return seen
