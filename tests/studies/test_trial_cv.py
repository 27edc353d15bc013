"""The coupled study's searches hold out whole training trials (``coupled.tuning_cv``): the tune stage's searches on
the rows ``max_samples`` keeps, a gray box's residual search (whose score decides its verdict), the nested CV's
local searches on each fold's training rows; ``C_rows`` is the trial folds' training rows."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import pipeline.studies.coupled as coupled
from pipeline.config.params import CoupledParams
from pipeline.evaluate import split_blocks
from pipeline.sim.synthetic import synthetic_frame
from pipeline.studies.coupled import evaluate_models, tune

INPUTS = ["u_mps", "v_mps", "r_radps"]


def _two_trials() -> pd.DataFrame:
    return pd.concat([synthetic_frame(600, seed=4, trial="syn01", split="train_test"),
                      synthetic_frame(400, seed=5, trial="syn02", split="train_test"),
                      synthetic_frame(200, seed=6, trial="syn03", split="test")], ignore_index=True)


def _kept_per_trial(frame: pd.DataFrame, max_samples: int) -> list[int]:
    """How many rows of each trial the search keeps: ``max_samples`` evenly spaced over the block."""
    idx = np.unique(np.linspace(0, len(frame) - 1, max_samples).round().astype(int))
    return frame["trial"].iloc[idx].value_counts(sort=False).tolist()


@pytest.mark.parametrize("cv", ["auto", "trials"])
def test_the_tune_stage_holds_out_each_training_trial_of_its_subsample(svr_fold_fits, cv):
    block = split_blocks(_two_trials())["train_test"]
    params = CoupledParams(models=["rbf_svr"], outputs=["udot_mps2"], inputs=INPUTS, max_evals=3, tuning_folds=5,
                           max_samples=300, tuning_cv=cv)
    hyper, trace = tune(block, params, split="train_test")
    a, b = _kept_per_trial(block, 300)
    assert (a, b) == (180, 120)
    res = trace["rbf_svr"]["udot_mps2"]
    assert (res["folds"], res["n_folds"], res["n_rows"]) == ("trials", 2, 300)
    assert set(svr_fold_fits) == {(b, a), (a, b)}  # each fit trains on one whole trial and tests on the other
    assert hyper["rbf_svr"]["udot_mps2"]["C_rows"] == (a + b) // 2


def test_blocked_folds_stay_as_they_were(svr_fold_fits):
    block = split_blocks(_two_trials())["train_test"]
    params = CoupledParams(models=["rbf_svr"], outputs=["udot_mps2"], inputs=INPUTS, max_evals=3, tuning_folds=5,
                           max_samples=300, tuning_cv="blocked")
    hyper, trace = tune(block, params, split="train_test")
    res = trace["rbf_svr"]["udot_mps2"]
    assert (res["folds"], res["n_folds"]) == ("blocked", 5)
    assert set(svr_fold_fits) == {(240, 60)}
    assert hyper["rbf_svr"]["udot_mps2"]["C_rows"] == 240


def test_one_trial_is_searched_by_blocked_folds_under_auto_and_refused_under_trials():
    block = synthetic_frame(600, seed=4, trial="syn01", split="train_test")
    params = CoupledParams(models=["rbf_svr"], outputs=["udot_mps2"], inputs=INPUTS, max_evals=2, tuning_folds=3,
                           max_samples=200)
    _, trace = tune(block, params.model_copy(update={"tuning_cv": "auto"}), split="train_test")
    assert trace["rbf_svr"]["udot_mps2"]["folds"] == "blocked"
    with pytest.raises(coupled.ModelError, match="tuning_cv: trials needs two training trials"):
        tune(block, params.model_copy(update={"tuning_cv": "trials"}), split="train_test")


def test_a_gray_box_residual_verdict_and_the_nested_folds_use_the_trial_folds(monkeypatch):
    frame = _two_trials()
    params = CoupledParams(models=["wdse_svr", "graybox"], inputs=INPUTS, folds=3, tuning_folds=5, max_evals=6,
                           fold_evals=3, max_samples=300, tuning_cv="trials")
    blocks = split_blocks(frame)
    hyper, trace = tune(blocks["train_test"], params, split="train_test")
    for out in params.outputs:  # the residual's score (and its SE, the verdict's margin) over the two trials
        assert trace["graybox"][out]["folds"] == "trials" and trace["graybox"][out]["n_folds"] == 2
        assert hyper["graybox"][out]["residual_cv_r2"] == trace["graybox"][out]["best_score"]
    seen: list[list[str]] = []
    real = coupled.search_rounds

    def spy(model, X, y, method="fast", **kw):  # noqa: ANN001, ANN202
        groups = kw.get("groups")
        seen.append(sorted(set(np.asarray(groups).tolist())) if groups is not None else [])
        return real(model, X, y, method, **kw)

    monkeypatch.setattr(coupled, "search_rounds", spy)
    evaluate_models(blocks["train_test"], blocks["test"], hyper, params)
    # per fold, model and output one local search, each on its fold's rows of both training trials
    assert len(seen) == params.folds * len(params.models) * len(params.outputs)
    assert all(s == [0, 1] for s in seen)
