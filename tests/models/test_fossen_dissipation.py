"""Known answers for the Fossen model's dissipation constraint (pipeline.models.fossen, ``dissipative``): each DOF's
damping in its own velocity (X_u, X_|u|u; Y_v, Y_|v|v; N_r, N_|r|r) must be <= 0 (SNAME), or the model pushes the
vehicle at speeds the training data did not reach."""

from __future__ import annotations

import numpy as np

from pipeline.models.fossen import DAMPING_TERMS, DISSIPATIVE_TERMS, Fossen3DOF
from pipeline.rk4 import rk4_step
from tests.models.fossen_data import DT_S, M_RB, TRUTH, forces, plant, run

#: the family's truth with an anti-dissipative quadratic sway damping (a positive Y_|v|v), still damped on the
#: data's speeds by a stronger linear term (-60 v + 10 |v| v < 0 for |v| < 6 m/s; the data reach 1.1 m/s)
ANTI = {**TRUTH, "Y_v": -60.0, "Y_|v|v": 10.0}


def _simulate(truth: dict[str, float], seed: int = 3, n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    names = ("X_udot", "Y_vdot", "Y_rdot", "N_rdot", *DAMPING_TERMS)
    f = plant(np.array([-truth.get(k, 0.0) for k in names]))
    tau = forces(n, np.random.default_rng(seed))
    nu, x = np.zeros_like(tau), np.zeros((1, 3))
    for k in range(n):
        nu[k] = x[0]
        x = rk4_step(f, x, tau[k:k + 1], DT_S)
    return np.column_stack([nu, tau]), f(nu, tau)


def test_an_anti_dissipative_own_damping_is_pinned_at_zero_and_the_rest_refitted():
    X, y = _simulate(ANTI)
    assert np.abs(X[:, 1]).max() < 6.0  # the plant is damped on these data: only the sign of Y_|v|v is wrong
    free = Fossen3DOF(rigid_body_mass=M_RB, dt_s=DT_S, select=False, dissipative=False).fit(X, y)
    assert abs(free.coefficients()["Y_|v|v"] / 10.0 - 1) < 1e-6  # the data say +10: the constraint binds
    model = Fossen3DOF(rigid_body_mass=M_RB, dt_s=DT_S, select=False).fit(X, y)
    c = model.coefficients()
    assert model.pinned_terms_ == ["Y_|v|v"] and "Y_|v|v" not in model.selected_terms_
    assert c["Y_|v|v"] == 0.0 and all(c[t] <= 0 for t in DISSIPATIVE_TERMS), c
    # the constrained optimum lies on the bound: the fit without the term, exactly
    without = Fossen3DOF(rigid_body_mass=M_RB, dt_s=DT_S, select=False,
                         terms=[t for t in DAMPING_TERMS if t != "Y_|v|v"]).fit(X, y)
    np.testing.assert_allclose(model.coef_, without.coef_, rtol=1e-10, atol=1e-12)
    # and its sway damping opposes the sway at every speed, far beyond the data's
    v = np.linspace(-20.0, 20.0, 401)
    assert np.all(v * (c["Y_v"] * v + c["Y_|v|v"] * np.abs(v) * v) <= 0)


def test_the_selection_with_the_constraint_still_finds_an_anti_dissipation_free_model():
    X, y = _simulate(ANTI)
    model = Fossen3DOF(rigid_body_mass=M_RB, dt_s=DT_S).fit(X, y)
    c = model.coefficients()
    assert all(c[t] <= 0 for t in DISSIPATIVE_TERMS), c
    assert "Y_|v|v" not in model.selected_terms_


def test_a_truth_in_the_family_pins_nothing():
    X, y, _, _, _ = run(0)
    model = Fossen3DOF(rigid_body_mass=M_RB, dt_s=DT_S).fit(X, y)
    assert model.pinned_terms_ == []
    assert set(model.selected_terms_) == {t for t in TRUTH if not t.endswith("dot")}
