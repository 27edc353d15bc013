from __future__ import annotations

import pickle

import numpy as np
import pytest
from sklearn.base import clone
from sklearn.svm import SVR
from sklearn.utils.estimator_checks import parametrize_with_checks

from pipeline.models.svr import RBFSVR, WDSESVR, PerOutputRegressor, TwoWeightsSVR, wdse_gram


def _without_array_api(marker: pytest.MarkDecorator) -> pytest.MarkDecorator:
    """The checks minus ``check_array_api_input`` (skipped unless SCIPY_ARRAY_API is set; libsvm is numpy-only,
    and this project tolerates no skipped tests)."""
    argnames, values = marker.args
    keep = [v for v in values if getattr((v.values if hasattr(v, "values") else v)[1], "func", None).__name__
            != "check_array_api_input"]
    return pytest.mark.parametrize(argnames, keep, **marker.kwargs)


@_without_array_api(parametrize_with_checks([RBFSVR(), TwoWeightsSVR(n_velocity=1), WDSESVR()]))
def test_sklearn_contract(estimator, check):
    check(estimator)


def _data(n=200, d=6, seed=0):
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, d)) * np.array([1.0, 0.3, 0.1, 500.0, 800.0, 300.0])[:d]
    y = np.sin(X[:, 0]) + 5 * X[:, 1] ** 2 + 1e-3 * X[:, 3] + 0.01 * rng.normal(size=n)
    return X, y


def test_wdse_equals_explicit_kernel():
    X, y = _data()
    gammas = [0.3, 2.0, 0.05, 1e-3, 0.1, 0.7]
    est = WDSESVR(gammas=gammas, C=3.0, epsilon=0.01, tol=1e-8).fit(X, y)
    Z = est.scaler_.transform(X)  # the kernel acts on standardized inputs
    ref = SVR(kernel="precomputed", C=3.0, epsilon=0.01, tol=1e-8).fit(wdse_gram(Z, Z, gammas), y)
    Xt, _ = _data(50, seed=1)
    Zt = est.scaler_.transform(Xt)
    np.testing.assert_allclose(est.predict(Xt), ref.predict(wdse_gram(Zt, Z, gammas)), atol=1e-8, rtol=0)


def test_special_cases_agree():
    X, y = _data()
    a = RBFSVR(gamma=0.2, C=2.0, epsilon=0.05).fit(X, y).predict(X)
    b = TwoWeightsSVR(gamma_velocity=0.2, gamma_actuator=0.2, C=2.0, epsilon=0.05).fit(X, y).predict(X)
    c = WDSESVR(gammas=[0.2] * 6, C=2.0, epsilon=0.05).fit(X, y).predict(X)
    np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_allclose(a, c, atol=1e-12)
    tw = TwoWeightsSVR(gamma_velocity=0.5, gamma_actuator=0.01).fit(X, y)
    np.testing.assert_allclose(tw.gammas_, [0.5, 0.5, 0.5, 0.01, 0.01, 0.01])


def test_wrong_gamma_count():
    X, y = _data()
    with pytest.raises(ValueError, match="gammas"):
        WDSESVR(gammas=[1.0, 2.0]).fit(X, y)


def test_per_output_pickle_and_clone():
    X, y = _data()
    Y = np.column_stack([y, -2 * y + X[:, 2]])
    model = PerOutputRegressor([WDSESVR(gammas=[0.1] * 6, C=1.0), RBFSVR(gamma=0.5, C=10.0)])
    model.fit(X, Y)
    assert model.predict(X).shape == (200, 2)
    assert clone(model).get_params()["estimators"][1].C == 10.0
    again = pickle.loads(pickle.dumps(model))
    np.testing.assert_array_equal(again.predict(X), model.predict(X))
    assert model.estimators_[0].C == 1.0 and model.estimators_[1].gamma == 0.5


def test_per_output_fitted_as_one_task_per_output_is_the_same_model_to_the_bit():
    """The train stage fits a final model's outputs as separate tasks (output_tasks, then join): the joined model
    predicts what fit's model predicts, bit for bit, and pickles to the same bytes."""
    X, y = _data()
    Y = np.ascontiguousarray(np.column_stack([y, -2 * y + X[:, 2], np.sin(X[:, 0])]))
    model = PerOutputRegressor([WDSESVR(gammas=[0.1, 0.3, 2.0, 0.05, 0.2, 1.0], C=1.0, epsilon=0.01),
                                RBFSVR(gamma=0.5, C=10.0), TwoWeightsSVR(gamma_velocity=0.3, gamma_actuator=0.02)])
    whole = clone(model).fit(X, Y)
    parts = clone(model)
    tasks = parts.output_tasks(X, Y)
    joined = parts.join(X, Y, [fn(*args) for fn, args in tasks])
    assert len(tasks) == 3
    np.testing.assert_array_equal(joined.predict(X), whole.predict(X))
    assert pickle.dumps(joined) == pickle.dumps(whole)
    with pytest.raises(ValueError, match="2 fitted of 3"):
        clone(model).join(X, Y, [fn(*args) for fn, args in tasks[:2]])


@pytest.mark.parametrize("make", [lambda **kw: RBFSVR(gamma=0.2, epsilon=0.05, **kw),
                                  lambda **kw: TwoWeightsSVR(gamma_velocity=0.3, gamma_actuator=0.02, **kw),
                                  lambda **kw: WDSESVR(gammas=[0.3, 2.0, 0.05, 1e-3, 0.1, 0.7], **kw)])
def test_C_chosen_on_fewer_rows_is_scaled_to_the_rows_fitted(make):
    """A C searched on C_rows rows and fitted on n: C (C_rows / n)^C_rate, the same model as that C given plainly
    (200 rows, C_rows 50: C_rate 0.5 halves C, C_rate 1 quarters it, no C_rows keeps it)."""
    X, y = _data()
    cases = [(dict(C_rows=50, C_rate=0.5), 2.0), (dict(C_rows=50, C_rate=1.0), 1.0), (dict(C_rate=1.0), 4.0),
             (dict(C_rows=800, C_rate=0.5), 8.0)]
    for kw, expected in cases:
        est = make(C=4.0, **kw).fit(X, y)
        assert est.C_ == pytest.approx(expected, rel=1e-12)
        np.testing.assert_array_equal(est.predict(X), make(C=expected).fit(X, y).predict(X))
    with pytest.raises(ValueError, match="C_rows"):
        make(C=4.0, C_rows=0).fit(X, y)


@pytest.mark.parametrize("make", [lambda **kw: RBFSVR(gamma=0.2, epsilon=0.05, **kw),
                                  lambda **kw: WDSESVR(gammas=[0.3, 2.0, 0.05, 1e-3, 0.1, 0.7], **kw)])
def test_max_rows_fits_on_evenly_spaced_rows_with_C_scaled_to_them(make):
    """``max_rows``: a fit on 1000 rows with max_rows 250 is the fit on rows 0, 4, 8, ... 999 (evenly spaced, the
    last included) with C scaled to 250 rows; fewer rows than the cap are all used."""
    X, y = _data(n=1000)
    capped = make(C=4.0, C_rows=100, C_rate=0.5, max_rows=250).fit(X, y)
    rows = np.unique(np.linspace(0, 999, 250).round().astype(int))
    assert capped.n_fit_rows_ == 250 and rows[0] == 0 and rows[-1] == 999
    assert capped.C_ == pytest.approx(4.0 * (100 / 250) ** 0.5, rel=1e-12)
    plain = make(C=4.0, C_rows=100, C_rate=0.5).fit(X[rows], y[rows])
    np.testing.assert_array_equal(capped.predict(X), plain.predict(X))
    assert make(max_rows=5000).fit(X, y).n_fit_rows_ == 1000
    with pytest.raises(ValueError, match="max_rows"):
        make(max_rows=0).fit(X, y)
