from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.config.params import CoupledParams
from pipeline.errors import ModelError
from pipeline.models.card import load_model, save_model
from pipeline.models.search import fast_search, grid_search, paper_grid
from pipeline.report.coupled import table2, table3
from pipeline.sim.synthetic import synthetic_frame
from pipeline.studies.coupled import GRAYBOX_MODELS, run_study, tune


@pytest.fixture(scope="module")
def study():
    frame = pd.concat([synthetic_frame(1500, seed=0, tuning_fraction=0.4),
                       synthetic_frame(500, seed=1, trial="syn02", split="test")], ignore_index=True)
    params = CoupledParams(max_evals=12, tuning="split")  # the papers' protocol (nested: test_nested_* below)
    return params, run_study(frame, params)


def test_wdse_beats_rbf_and_explicit_models_on_test_trial(study):
    params, out = study
    res = out["results"]
    for o in params.outputs:
        wdse = res["wdse_svr"]["final"][o]["r2"]
        for other in ("gertler_hagen", "mcfarland_whitcomb"):
            assert wdse > res[other]["final"][o]["r2"], (o, other)
        # WDSE's search starts from RBF's optimum, so its tuning score is never lower; on the unseen trial the two
        # are within 0.001 on u_dot here (0.9846 vs 0.9853 with the search's GP fits on one BLAS thread)
        assert wdse > res["rbf_svr"]["final"][o]["r2"] - 0.005, (o, "rbf_svr")
        # CV on the train block: within seed noise of RBF (the search now leaves its warm start; on this data WDSE's
        # CV v_dot is 0.919 against RBF's 0.947 while its final check is higher: docs/models.md, search)
        assert res["wdse_svr"]["summary"][o]["test_r2"]["mean"] > res["rbf_svr"]["summary"][o]["test_r2"]["mean"] - 0.05
    md, doc = table3(res, params.outputs)
    assert "WDSE-SVR" in md and set(doc) == set(params.models)
    assert "gamma_v_mps" in table2(out["hyper"], params.outputs, params.inputs)


def test_study_is_deterministic_in_its_scores(study):
    params, out = study
    frame = pd.concat([synthetic_frame(600, seed=0), synthetic_frame(200, seed=1, trial="syn02", split="test")],
                      ignore_index=True)
    small = CoupledParams(models=["gertler_hagen", "mcfarland_whitcomb"])
    a, b = run_study(frame, small), run_study(frame, small)
    assert a["results"]["gertler_hagen"]["summary"] == b["results"]["gertler_hagen"]["summary"]


def test_fast_search_reproducible_and_grid_is_the_paper_grid():
    frame = synthetic_frame(200, seed=2, split="tuning")
    X, y = frame[["u_mps", "v_mps", "r_radps"]].to_numpy(), frame["rdot_radps2"].to_numpy()
    a = fast_search("wdse_svr", X, y, max_evals=6)
    b = fast_search("wdse_svr", X, y, max_evals=6)
    assert a.best_params == b.best_params and a.n_fits <= 18
    grid = paper_grid("wdse_svr", 6, 1.0)
    assert len(grid) == 8 and all(len(v) == 5 for v in grid.values())
    assert np.prod([len(v) for v in grid.values()]) == 390_625
    small = grid_search("rbf_svr", X, y, grid={"gamma": [0.1, 1.0], "C": [1.0], "epsilon": [0.01]})
    assert small.n_candidates == 2 and small.n_fits == 6


def test_tune_refuses_non_tuning_rows():
    frame = synthetic_frame(100, seed=0)
    with pytest.raises(ModelError, match="split"):
        tune(frame, CoupledParams())


def test_tune_names_the_missing_inputs_and_the_thrust_columns_the_table_has():
    """The default inputs are the thrusters' thrust columns of DAGON (T_th1_N ...): a vehicle whose thrusters have
    other names is told which columns to list in coupled.inputs, before any search runs."""
    from pipeline.studies.coupled import tune
    frame = synthetic_frame(100, seed=0, split="tuning").rename(columns={"T_th1_N": "T_port_N"})
    with pytest.raises(ModelError, match=r"lacks columns \['T_th1_N'\].*coupled.inputs.*\['T_port_N', 'T_th2_N'"):
        tune(frame, CoupledParams())


def test_thrust_inputs_the_default_let_the_wdse_learn_what_thruster_speeds_hide():
    """The default coupled.inputs feed the thrusters' static thrust (K n|n|, the derive stage's T_<thruster>_N),
    in which the truth's accelerations are nearly linear, instead of the paper's speeds, whose square the kernel
    must learn: on an unseen trial of the synthetic truth (inflow loss and damping beyond both explicit families)
    the WDSE-SVR, tuned the same way, is clearly better with thrust (measured: 0.973 / 0.937 / 0.943 against
    0.849 / 0.908 / 0.726 with speeds)."""
    from pipeline.studies.coupled import build_model, model_inputs, tune
    frame = synthetic_frame(1500, rate_hz=4.0, seed=2, noise=0.02)
    test = synthetic_frame(800, rate_hz=4.0, seed=3, noise=0.02, split="test", trial="syn02")
    tuning, train = frame[frame["split"] == "tuning"], frame[frame["split"] == "train_test"]
    default = CoupledParams(models=["wdse_svr"], max_evals=12, tuning_folds=3)
    assert default.inputs[3:] == ["T_th1_N", "T_th2_N", "T_th3_N"]
    speeds = default.model_copy(update={"inputs": [*default.inputs[:3], "n1_rpm", "n2_rpm", "n3_rpm"]})
    r2 = {}
    for name, params in (("thrust", default), ("speed", speeds)):
        hyper, _ = tune(tuning, params)
        cols = model_inputs("wdse_svr", params)
        est = build_model("wdse_svr", hyper["wdse_svr"], params, train=train)
        pred = est.fit(train[cols].to_numpy(float), train[params.outputs].to_numpy(float)).predict(
            test[cols].to_numpy(float))
        truth = test[params.outputs].to_numpy(float)
        r2[name] = 1.0 - ((pred - truth) ** 2).mean(axis=0) / truth.var(axis=0)
    assert np.all(r2["thrust"] > r2["speed"] + 0.01), r2
    assert np.mean(r2["thrust"] - r2["speed"]) > 0.05, r2


def test_card_roundtrip(tmp_path, study):
    _, out = study
    est = out["results"]["mcfarland_whitcomb"]["estimator"]
    path, card = save_model(est, tmp_path / "mw.joblib", {"model": "mcfarland_whitcomb", "seed": 0})
    loaded, meta = load_model(path)
    assert meta["versions"]["scikit-learn"] and meta["model"] == "mcfarland_whitcomb"
    np.testing.assert_array_equal(loaded.coef_, est.coef_)
    card.unlink()
    with pytest.raises(ModelError, match="card"):
        load_model(path)


def test_smooth_tolerance_picks_the_widest_kernel_among_near_ties():
    frame = synthetic_frame(200, seed=2, split="tuning")
    X, y = frame[["u_mps", "v_mps", "r_radps"]].to_numpy(), frame["rdot_radps2"].to_numpy()
    best = fast_search("rbf_svr", X, y, max_evals=6)
    smooth = fast_search("rbf_svr", X, y, max_evals=6, smooth_tolerance=0.05)
    near = [t for t in smooth.trace if t["score"] >= best.best_score - 0.05]
    assert smooth.best_params["gamma"] == min(t["params"]["gamma"] for t in near) <= best.best_params["gamma"]
    assert smooth.best_score >= best.best_score - 0.05


def test_nested_tuning_searches_each_fold_on_its_training_rows_only(monkeypatch):
    """coupled.tuning = nested: every CV fold's hyperparameters come from a search over exactly that fold's
    training rows (never a row of its test block), and the final model's from the whole train_test block."""
    from pipeline.studies import coupled

    frame = pd.concat([synthetic_frame(300, seed=0, tuning_fraction=0.2),
                       synthetic_frame(100, seed=1, trial="syn02", split="test")], ignore_index=True)
    params = CoupledParams(models=["rbf_svr", "mcfarland_whitcomb"], max_evals=3, folds=3, tuning="nested")
    searched: list[np.ndarray] = []
    real_tune, real_local = coupled.tune, coupled.tune_local_rounds

    def spy(rows, p, **kw):
        searched.append(rows[params.inputs].to_numpy(float))
        return real_tune(rows, p, **kw)

    def spy_local(rows, model, p, start, **kw):  # a fold's local search from the tune stage's optimum, in rounds
        searched.append(rows[params.inputs].to_numpy(float))
        return (yield from real_local(rows, model, p, start, **kw))

    monkeypatch.setattr(coupled, "tune", spy)
    monkeypatch.setattr(coupled, "tune_local_rounds", spy_local)
    out = run_study(frame, params)
    train_test = frame[frame["split"] == "train_test"][params.inputs].to_numpy(float)
    assert len(searched) == 1 + params.folds  # the final model's search, then one per fold (rbf only: MW has none)
    np.testing.assert_array_equal(searched[0], train_test)
    fold_results = out["results"]["rbf_svr"]["folds"]
    for rows, fold in zip(searched[1:], fold_results, strict=True):
        test_rows = train_test[fold["test_start"]:fold["test_stop"]]
        train_rows = np.delete(train_test, np.s_[fold["test_start"]:fold["test_stop"]], axis=0)
        np.testing.assert_array_equal(rows, train_rows)
        assert not (rows[:, None, :] == test_rows[None, :, :]).all(-1).any()


def test_a_lone_rich_kernel_is_warm_started_from_the_simpler_kernels(study):
    """coupled.models: [wdse_svr] alone gets the same hyperparameters as in the full list: its fast search starts
    from 2-weights' optimum, itself from RBF's, although neither is asked for (and neither is returned)."""
    from pipeline.evaluate import split_blocks
    from pipeline.studies.coupled import tune
    full_params, out = study
    frame = pd.concat([synthetic_frame(1500, seed=0, tuning_fraction=0.4),
                       synthetic_frame(500, seed=1, trial="syn02", split="test")], ignore_index=True)
    lone_params = full_params.model_copy(update={"models": ["wdse_svr"]})
    hyper, trace = tune(split_blocks(frame)["tuning"], lone_params)
    assert set(hyper) == set(trace) == {"wdse_svr"}
    for o in full_params.outputs:
        assert hyper["wdse_svr"][o] == out["hyper"]["wdse_svr"][o], o
        assert trace["wdse_svr"][o]["warm_start_score"] is not None, o


def test_the_gray_box_residual_search_is_warm_started_by_its_own_chain(study):
    """The residual's WDSE search starts from a 2-weights optimum on the same residual (itself from RBF's), not
    from the GP seed alone: on the 480-s seed 0 of bench/coupled_study.py that took the gray box's v_dot from
    0.938 to 0.950."""
    params, out = study
    (graybox,) = [m for m in params.models if m in GRAYBOX_MODELS]
    for o in params.outputs:
        assert out["trace"][graybox][o]["warm_start_score"] is not None, o


def test_the_final_models_C_follows_the_rows_they_are_fitted_on(study):
    """The study's models were searched on folds of C_rows rows and fitted on the whole train_test block: each SVR
    (and the gray box's residual SVR) fits with C (C_rows / n)^c_rate; c_rate 0 keeps the searched C."""
    from pipeline.studies.coupled import build_model, model_inputs

    params, out = study
    frame = synthetic_frame(900, seed=3)
    for model in ("rbf_svr", "two_weights_svr", "wdse_svr"):
        hyper = out["hyper"][model]
        X, y = frame[model_inputs(model, params)].to_numpy(float), frame[params.outputs].to_numpy(float)
        for rate in (0.5, 0.0, 1.0):
            est = build_model(model, hyper, params.model_copy(update={"c_rate": rate})).fit(X, y)
            for k, o in enumerate(params.outputs):
                searched, rows = hyper[o]["C"], hyper[o]["C_rows"]
                assert 0 < rows < len(X)
                assert est.estimators_[k].C_ == pytest.approx(searched * (rows / len(X)) ** rate, rel=1e-12)
    assert "C chosen on rows" in table2(out["hyper"], params.outputs, params.inputs)


def test_nested_folds_run_each_search_once_and_keep_its_result(monkeypatch):
    """coupled.tuning = nested with the three kernels and a whole search per fold (fold_evals null): in each fold
    the WDSE's fast-search chain (RBF, then 2-weights, then WDSE) repeats the searches the RBF and 2-weights models
    of that fold ran on the same rows. Each runs once; the scores are those of running every search (a cache that
    keeps none)."""
    from pipeline.studies import coupled, tasks

    frame = pd.concat([synthetic_frame(300, seed=0, tuning_fraction=0.2),
                       synthetic_frame(100, seed=1, trial="syn02", split="test")], ignore_index=True)
    params = CoupledParams(models=["rbf_svr", "two_weights_svr", "wdse_svr"], outputs=["udot_mps2"], max_evals=3,
                           folds=2, tuning="nested", fold_evals=None)
    ran: list[str] = []
    real_search = tasks.search_rounds

    def counted(model, X, y, method="fast", **kw):  # a search in rounds (pipeline.rounds), counted as it starts
        ran.append(model)
        return (yield from real_search(model, X, y, method, **kw))

    monkeypatch.setattr(tasks, "search_rounds", counted)
    memo = coupled.run_study(frame, params, n_jobs=1)  # one process: the folds share the run's cache
    # the tune stage's call (one chain), then per fold the three kernels' chains: 3 + 2 x 3, not 3 + 2 x (1 + 2 + 3)
    assert sorted(ran) == sorted(["rbf_svr", "two_weights_svr", "wdse_svr"] * (1 + params.folds))

    every = coupled.run_study(frame, params, cache=coupled.SearchCache(kept=0))  # a cache that keeps nothing
    for model in params.models:
        assert memo["hyper"][model] == every["hyper"][model], model
        assert memo["results"][model]["summary"] == every["results"][model]["summary"], model


def test_an_empty_tuning_block_names_the_keys_that_make_it() -> None:
    """Found by the run campaign (seed 3911): ``features.tuning_fraction: 1e-298`` with ``coupled.tuning: split``
    left no tuning row, and the tune stage said only that the block was empty."""
    empty = pd.DataFrame({c: [] for c in ["u_mps", "v_mps", "r_radps", "udot_mps2", "split"]})
    with pytest.raises(ModelError, match=r"features.tuning_fraction .* coupled.tuning: nested"):
        tune(empty, CoupledParams(tuning="split"), split="tuning")
    with pytest.raises(ModelError, match=r"^train_test block is empty: nothing to tune on$"):
        tune(empty, CoupledParams(), split="train_test")
