"""Gray-box coupled model: explicit base + WDSE-SVR on its residual, on data whose truth is outside the family."""

from __future__ import annotations

import numpy as np
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
