"""Gray-box coupled model: explicit base + WDSE-SVR on its residual, on data whose truth is outside the family."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from sklearn.base import clone
from sklearn.utils.estimator_checks import parametrize_with_checks

from pipeline.config.params import CoupledParams
from pipeline.evaluate import regression_scores
from pipeline.models.graybox import GrayBox
from pipeline.sim.synthetic import synthetic_frame
from pipeline.studies.coupled import build_model, model_inputs, tune

_NEEDS = "GrayBox's default base needs X[:, :6] = [u v r tau_u tau_v tau_r] and y = [udot vdot rdot]"
_FITTING = ("check_dict_unchanged", "check_dont_overwrite_parameters", "check_dtype_object", "check_estimators_dtypes",
            "check_estimators_fit_returns_self", "check_estimators_nan_inf", "check_estimators_overwrite_params",
            "check_estimators_pickle", "check_f_contiguous_array_estimator", "check_fit2d_1feature",
            "check_fit2d_1sample", "check_fit2d_predict1d", "check_fit_check_is_fitted", "check_fit_idempotent",
            "check_fit_score_takes_y", "check_methods_sample_order_invariance", "check_methods_subset_invariance",
            "check_n_features_in", "check_n_features_in_after_fitting", "check_pipeline_consistency",
            "check_positive_only_tag_during_fit", "check_readonly_memmap_input", "check_regressor_data_not_an_array",
            "check_regressors_int", "check_regressors_no_decision_function", "check_regressors_train",
            "check_supervised_y_2d")


def _without_array_api(marker):
    argnames, values = marker.args
    keep = [v for v in values if getattr((v.values if hasattr(v, "values") else v)[1], "func", None).__name__
            != "check_array_api_input"]
    return pytest.mark.parametrize(argnames, keep, **marker.kwargs)


@_without_array_api(parametrize_with_checks([GrayBox()], xfail_strict=True,
                                            expected_failed_checks=lambda e: dict.fromkeys(_FITTING, _NEEDS)))
def test_sklearn_contract(estimator, check):
    check(estimator)


#: Five training/unseen-trial pairs (seed, seed + 1), declared before any was scored: one seed's R² on one output
#: moves by a few hundredths with the search's path, which a single seed and a 0.01 margin cannot carry.
GRAYBOX_SEEDS = (2, 4, 6, 8, 10)


def _parents_and_graybox(seed: int) -> dict[str, np.ndarray]:
    """Test-trial R² per output of WDSE-SVR, McFarland-Whitcomb and the gray box, trained on ``seed``'s trial."""
    frame = synthetic_frame(1500, rate_hz=4.0, seed=seed, noise=0.02)
    test = synthetic_frame(800, rate_hz=4.0, seed=seed + 1, noise=0.02, split="test", trial="syn02")
    params = CoupledParams(models=["wdse_svr", "mcfarland_whitcomb", "graybox"], max_evals=12, tuning_folds=3)
    tuning, train = frame[frame["split"] == "tuning"], frame[frame["split"] == "train_test"]
    hyper, _ = tune(tuning, params)
    assert set(hyper) == {"wdse_svr", "graybox"}
    scores = {}
    for model in params.models:
        cols = model_inputs(model, params)
        est = build_model(model, hyper.get(model), params, train=train)
        est.fit(train[cols].to_numpy(float), train[params.outputs].to_numpy(float))
        pred = est.predict(test[cols].to_numpy(float))
        scores[model] = np.array([s["r2"] for s in regression_scores(test[params.outputs].to_numpy(float), pred,
                                                                     params.outputs).values()])
    return scores


def test_graybox_at_least_as_good_as_its_parents():
    """Truth outside both families (thrust lost to inflow, a tanh term, linear damping): the gray box, tuned as the
    study tunes it, scores on unseen trials, averaged over five training/test pairs, at least the better of
    McFarland-Whitcomb and WDSE-SVR on every output (within 0.01), clearly more over the outputs, and collapses
    on no single trial."""
    runs = [_parents_and_graybox(seed) for seed in GRAYBOX_SEEDS]
    graybox = np.array([r["graybox"] for r in runs])  # (seeds, outputs)
    parents = np.array([np.maximum(r["wdse_svr"], r["mcfarland_whitcomb"]) for r in runs])
    assert np.all(graybox.mean(axis=0) >= parents.mean(axis=0) - 0.01), (graybox, parents)
    mean = {m: np.mean([r[m] for r in runs]) for m in runs[0]}
    assert mean["graybox"] > max(mean["wdse_svr"], mean["mcfarland_whitcomb"]) + 0.01, (mean, graybox, parents)
    assert np.all(graybox >= parents - 0.05), (graybox, parents)


def test_graybox_columns_and_clone():
    params = CoupledParams()
    cols = model_inputs("graybox", params)
    assert cols == ["u_mps", "v_mps", "r_radps", "tau_u_N", "tau_v_N", "tau_r_Nm", "T_th1_N", "T_th2_N", "T_th3_N"]
    hyper = {o: {"gammas": [0.1] * 6, "C": 1.0, "epsilon": 0.01} for o in params.outputs}
    est = build_model("graybox", hyper, params)
    assert est.residual_columns == (0, 1, 2, 6, 7, 8) and est.base_columns == tuple(range(6))
    assert clone(est).get_params()["residual_columns"] == (0, 1, 2, 6, 7, 8)
    X = np.zeros((5, 9))
    with pytest.raises(ValueError, match="outside X"):
        GrayBox(base_columns=(0, 1, 2, 3, 4, 12)).fit(X, np.zeros((5, 3)))


def test_nested_cv_folds_weight_the_gray_box_base_as_the_final_model(monkeypatch):
    """Each nested CV fold tunes a gray box whose base carries the same errors-in-variables weights (the smoother's
    SDs of the train_test block) as the final model's base; the fold's X has no SD columns to take them from."""
    import pipeline.studies.coupled as coupled
    from pipeline.studies.coupled import evaluate_models, noise_std_from
    from pipeline.vocabulary import NOISE_STD_COLUMNS

    frame = synthetic_frame(240, rate_hz=2.0, seed=4, noise=0.02, split="train_test")
    for k, col in enumerate(NOISE_STD_COLUMNS):
        frame[col] = 0.01 * (k + 1)
    params = CoupledParams(models=["graybox"], folds=2, tuning_folds=2, max_evals=2)
    seen: list = []

    def recording(real):
        def search(*a, **kw):
            seen.append(kw.get("noise_std"))
            return real(*a, **kw)
        return search

    def recording_rounds(real):  # the same for a search in rounds (pipeline.rounds)
        def search(*a, **kw):
            seen.append(kw.get("noise_std"))
            return (yield from real(*a, **kw))
        return search

    # a fold searches from the tune stage's result (tune_local_rounds) or, with fold_evals null, from scratch (tune)
    monkeypatch.setattr(coupled, "tune", recording(coupled.tune))
    monkeypatch.setattr(coupled, "tune_local_rounds", recording_rounds(coupled.tune_local_rounds))
    hyper = {o: {"gammas": [0.1] * 6, "C": 1.0, "epsilon": 0.01} for o in params.outputs}
    out = evaluate_models(frame, frame.iloc[:0], {"graybox": hyper}, params)
    expected = noise_std_from(frame)
    assert expected is not None and len(seen) == params.folds
    for fold_noise in seen:  # (tau's entries are NaN: estimated from the data; assert_array_equal matches NaNs)
        np.testing.assert_array_equal(np.asarray(fold_noise, float), np.asarray(expected, float))
    np.testing.assert_array_equal(np.asarray(out["graybox"]["estimator"].base_.noise_std, float),
                                  np.asarray(expected, float))


# -- the residual kept per output only where the blocked CV says it helps (issue 33 item 3) ------------------------

def _in_family_frame(extra: float, seed: int = 3) -> tuple:
    """Rows of a synthetic trial whose targets are exactly a McFarland-Whitcomb model of its inputs plus white noise
    (30 % of each target's SD), plus ``extra`` x SD(udot) x cos(2 u / SD(u)): a smooth term in u that the family
    (odd in each velocity, no constant) cannot carry. Returns (tuning, train, test) blocks of one and the same
    truth; the test block is another trial."""
    from pipeline.models.explicit import McFarlandWhitcomb

    params = CoupledParams(models=["mcfarland_whitcomb"])
    cols = model_inputs("mcfarland_whitcomb", params)
    src = synthetic_frame(900, rate_hz=2.0, seed=seed, noise=0.0)
    truth = McFarlandWhitcomb(solver="ols").fit(src[cols].to_numpy(float), src[params.outputs].to_numpy(float))
    blocks = []
    for k, frame in enumerate((src, synthetic_frame(600, rate_hz=2.0, seed=seed + 1, noise=0.0, split="test",
                                                    trial="syn02"))):
        y = truth.predict(frame[cols].to_numpy(float))
        sd = y.std(axis=0)
        y[:, 0] += extra * sd[0] * np.cos(2.0 * frame["u_mps"].to_numpy() / src["u_mps"].std())
        rng = np.random.default_rng(100 + k)
        frame = frame.copy()
        frame[params.outputs] = y + 0.3 * sd * rng.normal(size=y.shape)
        blocks.append(frame)
    src, test = blocks
    return src[src["split"] == "tuning"], src[src["split"] == "train_test"], test


def _fit_both(tuning, train, test, **kw):
    """The gray box and its base McFarland-Whitcomb, tuned and built as the study does; their test predictions."""
    params = CoupledParams(models=["graybox", "mcfarland_whitcomb"], max_evals=8, tuning_folds=3, **kw)
    hyper, trace = tune(tuning, params)
    pred = {}
    for model in params.models:
        cols = model_inputs(model, params)
        est = build_model(model, hyper.get(model), params, train=train).fit(train[cols].to_numpy(float),
                                                                            train[params.outputs].to_numpy(float))
        pred[model] = (est, est.predict(test[cols].to_numpy(float)))
    return params, hyper, trace, pred


def test_a_residual_of_white_noise_is_dropped_and_the_gray_box_is_its_base():
    """Truth exactly in the base's family plus white noise: the residual carries nothing to learn, its search's
    blocked-CV R² is within one SE of 0 (the best of the search's candidates: a little above 0 by chance) on every
    output, so every residual is dropped and the gray box predicts exactly what its base McFarland-Whitcomb
    predicts, bit for bit; the tuned record says so."""
    params, hyper, trace, pred = _fit_both(*_in_family_frame(extra=0.0))
    gray = pred["graybox"][0]
    for out in params.outputs:
        rec = hyper["graybox"][out]
        assert rec["residual_cv_r2"] == trace["graybox"][out]["best_score"], rec
        assert rec["residual_cv_r2"] - rec["residual_cv_se"] <= 0.0 and rec["residual_cv_r2"] < 0.02, rec
        assert rec["residual"] == (f"dropped (CV R² {rec['residual_cv_r2']:.3f} ± {rec['residual_cv_se']:.3f}: "
                                   "not above 0 by 1 SE)")
    assert gray.kept_outputs_ == [] and gray.residual_ is None
    np.testing.assert_array_equal(pred["graybox"][1], pred["mcfarland_whitcomb"][1])
    X = np.zeros((4, 9)) + 0.1
    np.testing.assert_array_equal(gray.fast_predictor()(X), gray.base_.fast_predictor()(X[:, list(range(6))]))


def test_a_smooth_residual_is_kept_where_it_is_and_beats_the_base():
    """The same truth plus a smooth term in u on udot only: udot's residual search scores well above 0 and its
    residual is kept; the gray box then beats its base on udot on the unseen trial, and on every output is at least
    its base (the dropped outputs are the base's exact predictions)."""
    tuning, train, test = _in_family_frame(extra=1.0)
    params, hyper, _, pred = _fit_both(tuning, train, test)
    gray = pred["graybox"][0]
    cv = {o: hyper["graybox"][o]["residual_cv_r2"] for o in params.outputs}
    assert cv["udot_mps2"] > 0.3 and 0 in gray.kept_outputs_, cv
    rec = hyper["graybox"]["udot_mps2"]
    assert rec["residual"] == f"kept (CV R² {cv['udot_mps2']:.3f} ± {rec['residual_cv_se']:.3f})"
    y = test[params.outputs].to_numpy(float)
    r2 = {m: np.array([s["r2"] for s in regression_scores(y, p, params.outputs).values()])
          for m, (_, p) in pred.items()}
    assert r2["graybox"][0] > r2["mcfarland_whitcomb"][0] + 0.1, r2
    for k in set(range(3)) - set(gray.kept_outputs_):
        np.testing.assert_array_equal(pred["graybox"][1][:, k], pred["mcfarland_whitcomb"][1][:, k])
    # null threshold: every residual kept, whatever its score (the rule before issue 33)
    always = build_model("graybox", hyper["graybox"], params.model_copy(update={"residual_min_cv_r2": None}))
    assert always.residual_outputs == (0, 1, 2)


def test_nested_folds_apply_the_rule_to_their_own_search():
    """A nested CV fold's gray box keeps or drops each residual on its own local search's CV R² (recorded beside
    its hyperparameters), not the tune stage's."""
    from pipeline.studies.coupled import NestedTuned

    tuning, train, _ = _in_family_frame(extra=0.0)
    params = CoupledParams(models=["graybox"], max_evals=8, tuning_folds=3, fold_evals=3)
    hyper, _ = tune(tuning, params)
    start = {o: {**h, "residual_cv_r2": 1.0} for o, h in hyper["graybox"].items()}  # a stage that said "keep"
    cols = model_inputs("graybox", params)
    fold = NestedTuned("graybox", params, start=start).fit(train[cols].to_numpy(float),
                                                           train[params.outputs].to_numpy(float))
    own = {o: fold.search_[o]["best_score"] for o in params.outputs}
    assert all(fold.hyperparameters_[o]["residual_cv_r2"] == own[o] for o in params.outputs)
    se = {o: fold.hyperparameters_[o]["residual_cv_se"] for o in params.outputs}
    assert fold.estimator_.kept_outputs_ == [k for k, o in enumerate(params.outputs) if own[o] - se[o] > 0], own


# -- the second verdict: the gray box against its own base on the train stage's CV folds -------------------------

def test_paired_verdict_keeps_a_residual_only_above_its_standard_error_and_drops_ties():
    """Kept where the folds' mean gain is above 0 by more than its SE; one fold keeping its residual, (a, 0, 0, 0,
    0), has mean = SE = a / 5 exactly and is dropped whatever the rounding; a loss or a noisy gain is dropped."""
    from pipeline.models.graybox import paired_verdict

    assert paired_verdict([0.02, 0.03, 0.01])[0]
    assert paired_verdict([0.004, 0.004, 0.004, 0.004])[0]  # no spread: any gain is above its SE of 0
    for a in (0.1, 0.0123, 0.040682184936093595, 0.030371125210782276):  # the last two round to mean > SE
        for n in (3, 4, 5):
            assert not paired_verdict([a] + [0.0] * (n - 1))[0], (a, n)
            assert not paired_verdict([0.0] * (n - 1) + [a])[0], (a, n)
    assert not paired_verdict([0.0, 0.0, 0.0])[0]
    assert not paired_verdict([-0.01, -0.02, -0.005])[0]
    helps, score = paired_verdict([0.03, -0.02, 0.01])  # mean 0.0067, SE 0.0145
    assert not helps and score == "gray box − base, test R² +0.0067 ± 0.015 over 3 folds"
    with pytest.raises(ValueError, match="two or more"):
        paired_verdict([0.1])


def _study(tuning_rows, train, test, **kw):
    """The train stage's CV and final check of the gray box and its base McFarland-Whitcomb, tuned as the study
    tunes them, with the tune stage's verdict off (every residual fitted)."""
    from pipeline.studies.coupled import evaluate_models

    params = CoupledParams(models=["graybox", "mcfarland_whitcomb"], max_evals=8, tuning_folds=3, fold_evals=3,
                           folds=4, residual_min_cv_r2=None, **{"residual_fold_check": "folds", **kw})
    nested = params.tuning == "nested"
    hyper, _ = tune(train if nested else tuning_rows, params, split="train_test" if nested else "tuning")
    return params, evaluate_models(train, test, hyper, params, tuning_keys=tuning_rows[["trial", "t_ns"]])


@pytest.mark.parametrize("tuning", ["split", "nested"])
def test_the_folds_drop_a_residual_of_white_noise_and_every_score_and_the_model_are_the_base(tuning):
    """Truth exactly in the base's family plus white noise, every residual fitted (the tune stage's verdict off): on
    the CV's folds the gray box does not beat its base by one SE on any output, so every residual is dropped, and
    then the saved gray box predicts bit for bit what its base does, and its fold scores, final check and interval
    are the base's. With the check off the residuals stay and the gray box is not its base."""
    tuning_rows, train, test = _in_family_frame(extra=0.0)
    params, out = _study(tuning_rows, train, test, tuning=tuning)
    gray, base = out["graybox"], out["mcfarland_whitcomb"]
    assert set(gray["residual"]) == set(params.outputs)
    assert all(rec["verdict"].startswith("dropped (gray box − base, test R² ") and len(rec["differences"]) == 4
               for rec in gray["residual"].values()), gray["residual"]
    assert gray["estimator"].kept_outputs_ == [] and gray["estimator"].residual_ is None
    X = test[model_inputs("graybox", params)].to_numpy(float)
    np.testing.assert_array_equal(gray["estimator"].predict(X), gray["estimator"].base_predict(X))
    np.testing.assert_allclose(gray["estimator"].predict(X), base["estimator"].predict(X[:, :6]), rtol=1e-9)

    def scores(result, split):  # (the standalone base's fit on 6 columns rounds apart from the gray box's)
        return [[f[split][o][k] for o in params.outputs for k in ("r2", "mae")] for f in result["folds"]]

    for split in ("train", "test"):
        np.testing.assert_allclose(scores(gray, split), scores(base, split), rtol=1e-9)
    np.testing.assert_allclose([gray["final"][o]["r2"] for o in params.outputs],
                               [base["final"][o]["r2"] for o in params.outputs], rtol=1e-9)
    assert all(gray["interval"][o]["half_width"] == pytest.approx(base["interval"][o]["half_width"], rel=1e-9)
               for o in params.outputs)

    params, off = _study(tuning_rows, train, test, tuning=tuning, residual_fold_check="off")
    assert off["graybox"]["estimator"].kept_outputs_ == [0, 1, 2]  # recorded, not applied
    assert off["graybox"]["final"] != off["mcfarland_whitcomb"]["final"]
    assert {o: r["verdict"] for o, r in off["graybox"]["residual"].items()} == {
        o: r["verdict"].removeprefix("dropped (").removesuffix(": not above 0 by 1 SE)")
        for o, r in gray["residual"].items()}


def test_the_folds_keep_a_residual_that_beats_the_base_and_narrow_the_rest():
    """The same truth plus a smooth term in u on udot: the folds keep udot's residual (the gray box beats its base
    there in every fold) and drop the two others; the saved model keeps udot's residual SVR as fitted, predicts
    the base's exact values on vdot and rdot, and its final check is what that narrowed model scores."""
    tuning_rows, train, test = _in_family_frame(extra=1.0)
    params, out = _study(tuning_rows, train, test, tuning="split")
    gray, base = out["graybox"], out["mcfarland_whitcomb"]
    verdicts = [rec["verdict"] for rec in gray["residual"].values()]
    assert [v.split(" ")[0] for v in verdicts] == ["kept", "dropped", "dropped"], verdicts
    est = gray["estimator"]
    assert est.kept_outputs_ == [0] and est.residual_outputs == (0,) and len(est.residual_.estimators_) == 1
    X = test[model_inputs("graybox", params)].to_numpy(float)
    pred = est.predict(X)
    np.testing.assert_array_equal(pred[:, 1:], est.base_predict(X)[:, 1:])
    y = test[params.outputs].to_numpy(float)
    assert gray["final"]["udot_mps2"]["r2"] == regression_scores(y, pred, params.outputs)["udot_mps2"]["r2"]
    assert gray["final"]["udot_mps2"]["r2"] > base["final"]["udot_mps2"]["r2"] + 0.1
    assert all(f["test"]["udot_mps2"]["r2"] > fb["test"]["udot_mps2"]["r2"]
               for f, fb in zip(gray["folds"], base["folds"], strict=True))
    fast = est.fast_predictor()
    np.testing.assert_allclose(fast(X), pred, rtol=0, atol=1e-12)


def test_with_one_training_trial_the_default_offers_no_residual_even_where_the_folds_would():
    """The default rule (``residual_fold_check: trials``) with one training trial: no trial can be held out, and a
    CV within one trial does not show that a residual carries to the next, so every residual is dropped and the
    saved gray box predicts what its base does, bit for bit, even the smooth u term's, which the folds keep (the
    test above) and which does help on the unseen trial. The folds' differences are still recorded."""
    tuning_rows, train, test = _in_family_frame(extra=1.0)
    assert train["trial"].nunique() == 1
    params, out = _study(tuning_rows, train, test, tuning="split", residual_fold_check="trials")
    gray = out["graybox"]
    assert all(rec["verdict"].startswith("dropped (fewer than two training trials held out: ")
               and len(rec["differences"]) == 4 and "trial_differences" not in rec
               for rec in gray["residual"].values()), gray["residual"]
    assert "over 4 folds" in gray["residual"]["udot_mps2"]["verdict"]
    est = gray["estimator"]
    assert est.kept_outputs_ == [] and est.residual_ is None
    X = test[model_inputs("graybox", params)].to_numpy(float)
    np.testing.assert_array_equal(est.predict(X), est.base_predict(X))
    assert gray["final"]["udot_mps2"]["r2"] == pytest.approx(out["mcfarland_whitcomb"]["final"]["udot_mps2"]["r2"],
                                                             rel=1e-9)


def test_a_fold_without_a_finite_r2_leaves_that_output_to_the_tune_stages_verdict():
    """A fold whose held-out targets do not vary has no finite R²: that output gets no comparison and keeps what
    the tune stage decided (no error from deep inside the train stage); the others are judged as usual."""
    from pipeline.studies.residual_check import fold_check

    outputs = ["udot_mps2", "vdot_mps2"]

    def fold(gray, base):
        def scores(r2):
            return {split: {o: {"r2": v} for o, v in zip(outputs, r2, strict=True)} for split in ("train", "test")}
        return {"fold": scores(gray), "base": {"scores": scores(base)}}

    results = [fold((float("nan"), 0.90), (float("nan"), 0.93)), fold((0.8, 0.91), (0.7, 0.95)),
               fold((0.9, 0.90), (0.9, 0.94)), {"estimator": GrayBox(), "final": None, "pred": None}]
    from pipeline.models.svr import PerOutputRegressor

    gray = results[-1]["estimator"]
    gray.kept_outputs_, gray.residual_ = [0, 1], PerOutputRegressor(["svr u", "svr v"])
    gray.residual_.estimators_ = ["fitted u", "fitted v"]
    specs = [{"kind": "fold"}] * 3 + [{"kind": "final"}]
    record = fold_check(specs, results, outputs, rule="folds")
    assert record["udot_mps2"]["verdict"] == "no finite scores to compare"
    assert record["vdot_mps2"]["verdict"] == "dropped (gray box − base, test R² -0.037 ± 0.0033 over 3 folds: not " \
                                              "above 0 by 1 SE)"
    narrowed = results[-1]["estimator"]  # v̇ narrowed to its base, u̇ left as the tune stage had it
    assert narrowed.kept_outputs_ == [0] and narrowed.residual_.estimators_ == ["fitted u"]
    assert [f["fold"]["test"]["vdot_mps2"]["r2"] for f in results[:3]] == [0.93, 0.95, 0.94]


def _two_trials(extra: float) -> tuple:
    """Two training trials (train_test rows) and an unseen one of the same truth as :func:`_in_family_frame`."""
    tuning, train, test = _in_family_frame(extra=extra)
    second = _in_family_frame(extra=extra, seed=5)[1].assign(trial="syn03")
    return tuning, pd.concat([train, second], ignore_index=True), test


@pytest.mark.parametrize("extra", [0.0, 1.0])
def test_the_held_out_trials_keep_a_residual_only_where_it_beats_the_base_on_each(extra):
    """The default rule (``residual_fold_check: trials``), two training trials, every residual fitted: white noise
    on top of the base's family gives no residual that beats the base on both held-out trials, so every one is
    dropped and the saved gray box is its base bit for bit; a smooth term in u on udot beats it on both, so udot
    keeps its residual and the others do not. The record holds one difference per held-out trial."""
    from pipeline.studies.coupled import evaluate_models

    tuning, train, test = _two_trials(extra)
    params = CoupledParams(models=["graybox"], max_evals=8, tuning_folds=3, fold_evals=3, folds=3,
                           residual_min_cv_r2=None, tuning="split")
    assert params.residual_fold_check == "trials"
    hyper, _ = tune(tuning, params)
    gray = evaluate_models(train, test, hyper, params, tuning_keys=tuning[["trial", "t_ns"]])["graybox"]
    record = gray["residual"]
    assert all(len(rec["trial_differences"]) == 2 and " over 2 held-out trials" in rec["verdict"]
               for rec in record.values()), record
    kept = [k for k, o in enumerate(params.outputs) if min(record[o]["trial_differences"]) > 0]  # the rule, n = 2
    assert [k for k, o in enumerate(params.outputs) if record[o]["verdict"].startswith("kept")] == kept, record
    if extra:
        assert 0 in kept and min(record["udot_mps2"]["trial_differences"]) > 0.05, record
    else:  # what a residual of white noise keeps by chance neither helps nor hurts
        assert all(abs(d) < 0.002 for rec in record.values() for d in rec["trial_differences"]), record
    est = gray["estimator"]
    assert est.kept_outputs_ == kept
    X = test[model_inputs("graybox", params)].to_numpy(float)
    dropped = [k for k in range(3) if k not in kept]
    assert dropped and (not kept or not np.array_equal(est.predict(X)[:, kept], est.base_predict(X)[:, kept]))
    np.testing.assert_array_equal(est.predict(X)[:, dropped], est.base_predict(X)[:, dropped])
