from __future__ import annotations

import pickle

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.utils.estimator_checks import parametrize_with_checks

from pipeline.errors import ModelError
from pipeline.models.explicit import GertlerHagen, McFarlandWhitcomb, tls

# These checks fit on scikit-learn's generic data (X with 1-10 arbitrary columns, 1-D y). A structured model needs
# exactly X = [u v r tau_u tau_v tau_r] and y = [udot vdot rdot]: it rejects other shapes with a ValueError by
# design, so every check that fits cannot apply. What remains (clone, params, repr, tags, init, unfitted
# predict, ...) must pass, and xfail_strict makes a check that starts passing fail this test.
_NEEDS_6_BY_3 = "needs X = [u v r tau_u tau_v tau_r] (6 columns) and y = [udot vdot rdot] (3 columns)"
_FITTING_CHECKS = (
    "check_dict_unchanged", "check_dont_overwrite_parameters", "check_dtype_object", "check_estimators_dtypes",
    "check_estimators_fit_returns_self", "check_estimators_nan_inf", "check_estimators_overwrite_params",
    "check_estimators_pickle", "check_f_contiguous_array_estimator", "check_fit2d_1feature", "check_fit2d_1sample",
    "check_fit2d_predict1d", "check_fit_check_is_fitted", "check_fit_idempotent", "check_fit_score_takes_y",
    "check_methods_sample_order_invariance", "check_methods_subset_invariance", "check_n_features_in",
    "check_n_features_in_after_fitting", "check_pipeline_consistency", "check_positive_only_tag_during_fit",
    "check_readonly_memmap_input", "check_regressor_data_not_an_array", "check_regressors_int",
    "check_regressors_no_decision_function", "check_regressors_train", "check_supervised_y_2d")


def _expected_failed(estimator) -> dict[str, str]:
    return dict.fromkeys(_FITTING_CHECKS, _NEEDS_6_BY_3)


def _without_array_api(marker: pytest.MarkDecorator) -> pytest.MarkDecorator:
    """The checks minus ``check_array_api_input`` (skipped unless SCIPY_ARRAY_API is set; numpy-only models)."""
    argnames, values = marker.args
    keep = [v for v in values if getattr((v.values if hasattr(v, "values") else v)[1], "func", None).__name__
            != "check_array_api_input"]
    return pytest.mark.parametrize(argnames, keep, **marker.kwargs)


@_without_array_api(parametrize_with_checks([GertlerHagen(), McFarlandWhitcomb()],
                                            expected_failed_checks=_expected_failed, xfail_strict=True))
def test_sklearn_contract(estimator, check):
    check(estimator)


def _states(n=400, seed=0):
    rng = np.random.default_rng(seed)
    nu = rng.normal(size=(n, 3)) * [0.5, 0.2, 0.3]
    nudot = rng.normal(size=(n, 3)) * [0.1, 0.05, 0.1]
    return nu, nudot


def _true_theta(model, seed=1):
    rng = np.random.default_rng(seed)
    theta = rng.uniform(1.0, 20.0, size=len(model.param_names)) * rng.choice([-1, 1], len(model.param_names))
    for eq, acc, k in model.mass_entries:  # a well-conditioned, positive "mass" diagonal
        theta[k] = 100.0 + 10 * k if eq == acc else 3.0 + k
    return theta


@pytest.mark.parametrize("cls", [GertlerHagen, McFarlandWhitcomb])
@pytest.mark.parametrize("solver", ["tls", "ols"])
def test_recovers_own_structure(cls, solver):
    model = cls(solver=solver)
    theta = _true_theta(model)
    nu, nudot = _states()
    tau = model.design(nu, nudot) @ theta
    X = np.column_stack([nu, tau])
    model.fit(X, nudot)
    np.testing.assert_allclose(model.coef_, theta, rtol=1e-8, atol=1e-8)
    np.testing.assert_allclose(model.predict(X), nudot, rtol=1e-8, atol=1e-10)
    if cls is McFarlandWhitcomb:
        M = model.mass_matrix_
        np.testing.assert_allclose(M, M.T)


@pytest.mark.parametrize("cls", [GertlerHagen, McFarlandWhitcomb])
def test_the_fast_predictor_is_predict_to_float_rounding(cls):
    """A free run calls the model four times a step: its fast predictor (McFarland-Whitcomb's from the
    coefficients, not the design matrix) gives ``predict``'s accelerations on states with every sign, and on a
    single row; none before fit."""
    model = cls()
    assert model.fast_predictor() is None
    theta = _true_theta(model, seed=7)
    nu, nudot = _states()
    X = np.column_stack([nu, model.design(nu, nudot) @ theta])
    model.fit(X, nudot)
    fast = model.fast_predictor()
    rng = np.random.default_rng(5)
    Xq = np.column_stack([rng.normal(0, 1.5, (64, 3)), rng.normal(0, 50.0, (64, 3))])
    slow = model.predict(Xq)
    assert np.abs(fast(Xq) - slow).max() <= 1e-12 * np.abs(slow).max()
    np.testing.assert_allclose(fast(Xq[:1]), slow[:1], rtol=1e-12, atol=1e-12 * np.abs(slow).max())


def test_tls_beats_ols_with_errors_in_variables():
    rng = np.random.default_rng(3)
    x = rng.normal(size=4000)
    y = 2.0 * x
    xn = x + 0.3 * rng.normal(size=x.size)
    yn = y + 0.6 * rng.normal(size=x.size)  # equal relative noise on both columns
    assert abs(tls(xn[:, None], yn)[0] - 2.0) < abs(np.linalg.lstsq(xn[:, None], yn, rcond=None)[0][0] - 2.0)


def test_noise_robustness_and_clone_pickle():
    model = McFarlandWhitcomb()
    theta = _true_theta(model)
    nu, nudot = _states(3000, seed=5)
    tau = model.design(nu, nudot) @ theta
    rng = np.random.default_rng(9)
    X = np.column_stack([nu, tau + 0.01 * tau.std(axis=0) * rng.normal(size=tau.shape)])
    model.fit(X, nudot)
    r2 = 1 - ((model.predict(X) - nudot) ** 2).sum(0) / ((nudot - nudot.mean(0)) ** 2).sum(0)
    assert np.all(r2 > 0.95)
    again = pickle.loads(pickle.dumps(model))
    np.testing.assert_array_equal(again.predict(X), model.predict(X))
    assert clone(model).get_params() == {"solver": "wtls", "weight_equations": True, "noise_std": None,
                                         "refine": False, "dt_s": None, "refine_horizon_s": 2.0,
                                         "refine_max_nfev": 30}


def test_errors():
    nu, nudot = _states(50)
    with pytest.raises(ValueError, match="6 columns|expects X"):
        GertlerHagen().fit(nu, nudot)
    with pytest.raises(ValueError, match="solver"):
        GertlerHagen(solver="lasso").fit(np.column_stack([nu, nu]), nudot)
    with pytest.raises(ValueError, match="noise_std"):
        GertlerHagen(noise_std=(0.1, 0.1)).fit(np.column_stack([nu, nu]), nudot)
    with pytest.raises(ValueError, match="dt_s"):
        GertlerHagen(refine=True).fit(np.column_stack([nu, nu]), nudot)
    tau = nudot.copy()
    nudot[:, 0] = 0.0  # no surge acceleration: the surge mass cannot be identified
    with pytest.raises(ModelError, match="mass matrix is singular"):
        GertlerHagen().fit(np.column_stack([nu, tau]), nudot)
    tau[:, 0] = 0.0  # ... nor, without surge force either, anything of the X equation
    with pytest.raises(ModelError, match="GertlerHagen: equation X has tau identically zero and no excited"):
        GertlerHagen().fit(np.column_stack([nu, tau]), nudot)
