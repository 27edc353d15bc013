"""Defaults that finish (issue 35, item 1): a search's fits are bounded whatever the trial length, the nested CV's
folds re-tune by a small local search from the tune stage's optimum, and the report says which searches kept
their warm start or ran out of budget."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

import pipeline.models.search as search_mod
from pipeline.config.params import CoupledParams
from pipeline.evaluate import split_blocks
from pipeline.report.studies import search_notes
from pipeline.sim.synthetic import synthetic_frame
from pipeline.studies.coupled import evaluate_models, tune


@pytest.fixture
def fits(monkeypatch):
    """Every SVR fit of a search, as (training rows, test rows, model class)."""
    seen: list[tuple[int, int, str]] = []
    real = search_mod._fold_fit

    def counting(est, X, y, train, test):
        seen.append((len(train), len(test), type(est).__name__))
        return real(est, X, y, train, test)

    monkeypatch.setattr(search_mod, "_fold_fit", counting)
    return seen


def test_a_long_trial_is_searched_on_a_bounded_subsample_by_default(fits):
    # 6000 rows: 10x the default bound. With max_samples None (the old default) every fit would see ~4800 rows.
    frame = synthetic_frame(6000, seed=3, split="train_test")
    params = CoupledParams(models=["rbf_svr"], outputs=["udot_mps2"], max_evals=3, tuning_folds=3,
                           inputs=["u_mps", "v_mps", "r_radps"])
    assert params.max_samples is not None, "the code's default must bound the search"
    hyper, trace = tune(frame, params, split="train_test")
    bound = params.max_samples
    assert fits and len(fits) == trace["rbf_svr"]["udot_mps2"]["n_fits"]
    assert max(tr + te for tr, te, _ in fits) <= bound
    assert trace["rbf_svr"]["udot_mps2"]["n_rows"] == bound
    # C was chosen on the subsample's fold rows, and the final fit on all rows scales it from there
    assert hyper["rbf_svr"]["udot_mps2"]["C_rows"] == round(bound * 2 / 3)


def _nested_frame() -> pd.DataFrame:
    return pd.concat([synthetic_frame(900, seed=4, split="train_test"),
                      synthetic_frame(200, seed=5, trial="syn02", split="test")], ignore_index=True)


def test_nested_folds_re_tune_locally_from_the_tune_stage_optimum(fits):
    frame = _nested_frame()
    params = CoupledParams(models=["wdse_svr", "graybox"], inputs=["u_mps", "v_mps", "r_radps"], folds=3,
                           tuning_folds=3, max_evals=12, fold_evals=4, max_samples=300)
    blocks = split_blocks(frame)
    hyper, _ = tune(blocks["train_test"], params, split="train_test")
    n_tune = len(fits)
    fits.clear()
    results = evaluate_models(blocks["train_test"], blocks["test"], hyper, params)
    # per fold, model and output one local search of at most fold_evals candidates x tuning_folds fits: no GP
    # seeds, no warm-start chain (the whole search made 12 candidates of each of RBF, 2-weights and WDSE)
    searches = params.folds * len(params.models) * len(params.outputs)
    assert len(fits) <= searches * params.fold_evals * params.tuning_folds
    assert len(fits) >= searches * params.tuning_folds  # each search scored its start at least
    assert {name for _, _, name in fits} == {"WDSESVR"}
    assert len(fits) < n_tune / 2  # all folds together: under half of one whole tune (the old protocol: one a fold)
    assert set(results) == {"wdse_svr", "graybox"}
    for model in results:
        assert all(np.isfinite(results[model]["summary"][o]["test_r2"]["mean"]) for o in params.outputs)


def test_fold_evals_none_keeps_a_whole_search_per_fold(fits):
    frame = _nested_frame()
    params = CoupledParams(models=["rbf_svr"], inputs=["u_mps", "v_mps", "r_radps"], outputs=["udot_mps2"],
                           folds=2, tuning_folds=3, max_evals=5, fold_evals=None, max_samples=300)
    blocks = split_blocks(frame)
    hyper, _ = tune(blocks["train_test"], params, split="train_test")
    fits.clear()
    evaluate_models(blocks["train_test"], blocks["test"], hyper, params)
    assert len(fits) == params.folds * params.max_evals * params.tuning_folds


def test_the_report_names_a_kept_warm_start_and_a_budget_that_ran_out():
    trace = {"two_weights_svr": {"rdot_radps2": {"best_score": 0.28, "n_candidates": 30, "warm_start_kept": True,
                                                 "note": "none of 29 other candidates beat its tuning R2 0.2793",
                                                 "budget_exhausted": False}},
             "wdse_svr": {"rdot_radps2": {"best_score": 0.98, "n_candidates": 30, "warm_start_kept": False,
                                          "note": "", "budget_exhausted": True},
                          "udot_mps2": {"best_score": 0.97, "n_candidates": 30, "warm_start_kept": False,
                                        "note": "", "budget_exhausted": False}}}
    html = search_notes(trace, ["udot_mps2", "rdot_radps2"])
    assert "none of 29 other candidates beat its tuning R2 0.2793" in html
    assert "2-weights" in html and "still moving when it stopped" in html
    assert html.count("<tr>") == 1 + 2  # the header and two searches: WDSE's u_dot is neither, not listed
    quiet = {"wdse_svr": {"udot_mps2": trace["wdse_svr"]["udot_mps2"]}}
    assert search_notes(quiet, ["udot_mps2"]) == ""
