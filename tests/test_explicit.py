from __future__ import annotations

import pickle

import numpy as np
import pytest
from sklearn.base import clone

from pipeline.errors import ModelError
from pipeline.models.explicit import GertlerHagen, McFarlandWhitcomb, tls


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
    assert clone(model).get_params() == {"solver": "tls", "weight_equations": True}


def test_errors():
    nu, nudot = _states(50)
    with pytest.raises(ValueError, match="6 columns|expects X"):
        GertlerHagen().fit(nu, nudot)
    with pytest.raises(ValueError, match="solver"):
        GertlerHagen(solver="lasso").fit(np.column_stack([nu, nu]), nudot)
    nu[:, 2] = 0.0  # no yaw rate at all: r-columns vanish
    with pytest.raises(ModelError):
        GertlerHagen().fit(np.column_stack([nu, nudot]), nudot)
