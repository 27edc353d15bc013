"""A plant exactly in the Fossen 3-DOF family, simulated with known coefficients (tests of pipeline.models.fossen)."""

from __future__ import annotations

import functools

import numpy as np

from pipeline.models.fossen import DAMPING_TERMS, _added_mass, _coriolis, _regressors
from pipeline.rk4 import rk4_step
from tests.models.test_explicit_eiv import forces as explicit_forces

DT_S = 0.05
M_RB = np.array([[100.0, 0.0, 0.0], [0.0, 100.0, 0.0], [0.0, 0.0, 20.0]])
#: SNAME truth; every damping term not named is 0 (not in the truth)
TRUTH = {"X_udot": -20.0, "Y_vdot": -60.0, "Y_rdot": -4.0, "N_rdot": -8.0,
         "X_u": -10.0, "X_|u|u": -30.0, "Y_v": -20.0, "Y_r": -3.0, "Y_|v|v": -80.0, "Y_|r|r": -4.0,
         "N_v": -5.0, "N_r": -6.0, "N_|v|v": -6.0, "N_|r|r": -10.0}
SIGMA_NU = (0.015, 0.015, 0.005)


def theta_true() -> np.ndarray:
    names = ("X_udot", "Y_vdot", "Y_rdot", "N_rdot", *DAMPING_TERMS)
    return np.array([-TRUTH.get(n, 0.0) for n in names])


def plant(truth_theta: np.ndarray):
    M = M_RB + _added_mass(truth_theta[:4])
    M_inv = np.linalg.inv(M)
    damping = list(zip(DAMPING_TERMS.values(), truth_theta[4:], strict=True))

    def f(nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
        rhs = tau - _coriolis(M, nu)
        reg = _regressors(nu)
        for (eq, name), c in damping:
            rhs[:, eq] -= c * reg[name]
        return rhs @ M_inv.T

    return f


def forces(n: int, rng: np.random.Generator, amp=(80.0, 60.0, 8.0), bias=(0.0, 0.15, -0.1)) -> np.ndarray:
    """The explicit models' test forces (random steps through a 1-s lag plus a slow sine, per DOF), larger, with
    the surge going both ways and small sway and yaw biases that make the excitation asymmetric."""
    return explicit_forces(n, rng, amp=amp, bias=bias)


@functools.cache
def run(seed: int, n: int = 6000, rel_acc: float = 0.0, nu_noise: bool = False):
    """(X, y, noise_std, X_exact, y_exact): nu by RK4 (tau held per step), nudot exact from the plant, then noise
    (SIGMA_NU on nu when ``nu_noise``, ``rel_acc`` of each acceleration's SD on nudot); tau exact."""
    rng = np.random.default_rng(seed)
    tau = forces(n, rng)
    f = plant(theta_true())
    nu, x = np.zeros_like(tau), np.zeros((1, 3))
    for k in range(n):
        nu[k] = x[0]
        x = rk4_step(f, x, tau[k:k + 1], DT_S)
    nudot = f(nu, tau)
    s_nu = np.asarray(SIGMA_NU) if nu_noise else np.zeros(3)
    s_acc = rel_acc * nudot.std(axis=0)
    nu_n = nu + rng.normal(size=nu.shape) * s_nu
    nudot_n = nudot + rng.normal(size=nudot.shape) * s_acc
    out = (np.column_stack([nu_n, tau]), nudot_n, (*s_nu, 0.0, 0.0, 0.0, *s_acc), np.column_stack([nu, tau]), nudot)
    for a in out:
        if isinstance(a, np.ndarray):
            a.flags.writeable = False
    return out
