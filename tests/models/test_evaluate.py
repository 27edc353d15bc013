from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.linear_model import LinearRegression
from sklearn.model_selection import KFold

from pipeline.errors import ModelError
from pipeline.evaluate import (
    blocked_folds,
    check_no_leakage,
    cross_validate_blocked,
    regression_scores,
    split_blocks,
    summarize_folds,
)


def _keys(n, trial="t1", t0=0):
    return pd.DataFrame({"trial": [trial] * n, "t_ns": t0 + np.arange(n, dtype=np.int64) * 50_000_000})


def test_blocked_folds_contiguous():
    folds = blocked_folds(103, 5)
    assert len(folds) == 5
    for train, test in folds:
        assert np.all(np.diff(test) == 1)
        assert np.intersect1d(train, test).size == 0
    assert np.concatenate([te for _, te in folds]).tolist() == list(range(103))


def test_guard_accepts_blocked_and_rejects_shuffled():
    keys = _keys(100)
    tuning = _keys(20, t0=-10**12)
    for train, test in blocked_folds(100, 5):
        check_no_leakage(keys.iloc[train], keys.iloc[test], tuning)
    train, test = next(iter(KFold(5, shuffle=True, random_state=0).split(np.arange(100))))
    with pytest.raises(ModelError, match="inside the test time span"):
        check_no_leakage(keys.iloc[train], keys.iloc[test])


def test_guard_rejects_tuning_overlap_and_shared_rows():
    keys = _keys(100)
    with pytest.raises(ModelError, match="tuning"):
        check_no_leakage(keys.iloc[:80], keys.iloc[80:], tuning=keys.iloc[90:95])
    with pytest.raises(ModelError, match="also in the training"):
        check_no_leakage(keys.iloc[:81], keys.iloc[80:])
    # the same times in a different trial are no leak
    check_no_leakage(_keys(50, trial="t2"), keys.iloc[:50])


def test_cross_validate_blocked_scores_and_guard():
    rng = np.random.default_rng(0)
    X = rng.normal(size=(200, 3))
    Y = np.column_stack([X @ [1.0, 2.0, 3.0], X[:, 0] - X[:, 1]]) + 0.01 * rng.normal(size=(200, 2))
    folds = cross_validate_blocked(LinearRegression(), X, Y, n_folds=5, keys=_keys(200), outputs=["a", "b"])
    assert [f["fold"] for f in folds] == list(range(5))
    summary = summarize_folds(folds)
    assert summary["a"]["test_r2"]["mean"] > 0.99 and summary["b"]["train_mae"]["mean"] < 0.02
    with pytest.raises(ModelError, match="tuning"):
        cross_validate_blocked(LinearRegression(), X, Y, keys=_keys(200), tuning_keys=_keys(200).iloc[5:10])


def test_split_blocks_and_scores():
    frame = pd.DataFrame({"split": ["tuning"] * 3 + ["train_test"] * 5 + ["test"] * 2, "x": range(10)})
    blocks = split_blocks(frame)
    assert [len(blocks[s]) for s in ("tuning", "train_test", "test")] == [3, 5, 2]
    with pytest.raises(ModelError, match="unknown split"):
        split_blocks(frame.assign(split="holdout"))
    s = regression_scores(np.array([1.0, 2.0, 3.0]), np.array([1.0, 2.0, 4.0]), ["y"])
    assert s["y"]["mae"] == pytest.approx(1 / 3) and s["y"]["r2"] == pytest.approx(0.5)
