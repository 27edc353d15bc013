"""Explicit 3-DOF (surge, sway, yaw) hydrodynamic models, linear in their parameters, fit by total least squares.

Both models are written as ``A(nu, nudot) theta = tau``: each of the three equations of motion is a row of
regressors (functions of the body velocities nu = [u v r] and accelerations nudot) times the parameter vector.
Fitting solves that system for theta; prediction solves ``M(theta) nudot = tau - A_rest(nu) theta`` for nudot.

Estimator contract: ``X = [u v r tau_u tau_v tau_r]`` (6 columns: velocities in m/s, rad/s, generalized
forces in N, N, N·m), ``y = [udot vdot rdot]`` (3 columns). See docs/models.md for the regressor structures,
their references and the sign convention (identified parameters are on the left-hand side, i.e. a damping
force ``-X_uu u^2`` appears as ``+theta u^2`` with ``theta = -X_uu``; rigid-body terms are absorbed).

``solver="tls"``: total least squares, the right singular vector of the smallest singular value of the
column-scaled ``[Phi | y]``; ``solver="ols"``: ordinary least squares for comparison.
"""

from __future__ import annotations

import logging

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from pipeline.errors import ModelError

log = logging.getLogger(__name__)

__all__ = ["GertlerHagen", "McFarlandWhitcomb", "tls", "ols", "EXPLICIT_INPUTS"]

#: The feature-store columns an explicit model takes, in order.
EXPLICIT_INPUTS = ["u_mps", "v_mps", "r_radps", "tau_u_N", "tau_v_N", "tau_r_Nm"]


def tls(Phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Total least squares solution of ``Phi theta ~ y`` (errors in Phi and y).

    Columns of ``[Phi | y]`` are scaled to unit RMS (so that units do not decide which column absorbs the
    error), the SVD gives the right singular vector ``v`` of the smallest singular value, and
    ``theta = -v[:-1] / v[-1]``, scaled back.
    """
    Z = np.column_stack([Phi, y])
    scale = np.sqrt(np.mean(Z * Z, axis=0))
    if np.any(scale == 0):
        raise ModelError(f"TLS: regressor column(s) {np.flatnonzero(scale == 0).tolist()} are identically zero")
    _, sv, vt = np.linalg.svd(Z / scale, full_matrices=False)
    v = vt[-1]
    if abs(v[-1]) < 1e-12:
        raise ModelError("TLS: non-generic problem (smallest singular vector has no y component); "
                         f"singular values {sv[-3:].tolist()}")
    return -(v[:-1] / v[-1]) * scale[-1] / scale[:-1]


def ols(Phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    scale = np.sqrt(np.mean(Phi * Phi, axis=0))
    scale[scale == 0] = 1.0
    theta, *_ = np.linalg.lstsq(Phi / scale, y, rcond=None)
    return theta / scale


class _LinearInParameters(RegressorMixin, BaseEstimator):
    """M(theta) nudot + A_rest(nu) theta = tau, fit by TLS/OLS, predicted by solving for nudot."""

    param_names: tuple[str, ...] = ()
    #: (equation, acceleration index, parameter index): M[eq, acc] += theta[param]
    mass_entries: tuple[tuple[int, int, int], ...] = ()
    #: groups of (equations, parameters) fitted jointly; parameters of different groups are disjoint
    groups: tuple[tuple[tuple[int, ...], tuple[int, ...]], ...] = ()

    def __init__(self, solver: str = "tls", weight_equations: bool = True) -> None:
        self.solver = solver
        self.weight_equations = weight_equations

    # -- structure -------------------------------------------------------------------------------
    def _rest_design(self, nu: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _acc_design(self, nudot: np.ndarray) -> np.ndarray:
        A = np.zeros((nudot.shape[0], 3, len(self.param_names)))
        for eq, acc, k in self.mass_entries:
            A[:, eq, k] += nudot[:, acc]
        return A

    def design(self, nu: np.ndarray, nudot: np.ndarray) -> np.ndarray:
        """Regressor tensor ``A`` of shape (n, 3, n_params) with ``A[i] @ theta = tau[i]``."""
        return self._acc_design(nudot) + self._rest_design(nu)

    def mass_matrix(self, theta: np.ndarray) -> np.ndarray:
        M = np.zeros((3, 3))
        for eq, acc, k in self.mass_entries:
            M[eq, acc] += theta[k]
        return M

    # -- estimator -------------------------------------------------------------------------------
    def _split(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if X.shape[1] != 6:
            raise ValueError(f"{type(self).__name__} expects X = [u v r tau_u tau_v tau_r], got {X.shape[1]} columns")
        return X[:, :3], X[:, 3:]

    def fit(self, X, y):
        if self.solver not in ("tls", "ols"):
            raise ValueError(f"solver must be 'tls' or 'ols', got {self.solver!r}")
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        if y.ndim != 2 or y.shape[1] != 3:
            raise ValueError(f"{type(self).__name__} expects y = [udot vdot rdot] (3 columns)")
        nu, tau = self._split(X)
        A = self.design(nu, y)
        theta = np.zeros(len(self.param_names))
        solve = tls if self.solver == "tls" else ols
        for eqs, params in self.groups:
            eqs_l, params_l = list(eqs), list(params)
            Phi = A[:, eqs_l][:, :, params_l]
            rhs = tau[:, eqs_l]
            if self.weight_equations and len(eqs_l) > 1:
                w = 1.0 / np.maximum(np.sqrt(np.mean(rhs * rhs, axis=0)), 1e-300)
                Phi = Phi * w[None, :, None]
                rhs = rhs * w[None, :]
            theta[params_l] = solve(Phi.reshape(-1, len(params_l)), rhs.reshape(-1))
        M = self.mass_matrix(theta)
        cond = np.linalg.cond(M)
        if not np.isfinite(cond) or cond > 1e12:
            raise ModelError(f"{type(self).__name__}: identified mass matrix is singular (cond {cond:.3g})")
        self.coef_ = theta
        self.mass_matrix_ = M
        self.mass_matrix_inv_ = np.linalg.inv(M)
        log.debug("%s fitted by %s: %s", type(self).__name__, self.solver, self.coefficients())
        return self

    def predict(self, X):
        check_is_fitted(self, "coef_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        nu, tau = self._split(X)
        rest = self._rest_design(nu) @ self.coef_
        return (tau - rest) @ self.mass_matrix_inv_.T

    def coefficients(self) -> dict[str, float]:
        check_is_fitted(self, "coef_")
        return {name: float(v) for name, v in zip(self.param_names, self.coef_, strict=True)}


class GertlerHagen(_LinearInParameters):
    """Gertler & Hagen (1967) standard submarine equations reduced to the horizontal plane (3 DOF, 20 params).

    X: [udot, u^2, v^2, r^2, vr]
    Y: [vdot, rdot, u^2, uv, ur, v|v|, v|r|]
    N: [rdot, vdot, u^2, uv, ur, |v|r, v|v|, r|r|]
    Each equation is fitted on its own (no shared parameters).
    """

    param_names = ("X_udot", "X_uu", "X_vv", "X_rr", "X_vr",
                   "Y_vdot", "Y_rdot", "Y_uu", "Y_uv", "Y_ur", "Y_vav", "Y_var",
                   "N_rdot", "N_vdot", "N_uu", "N_uv", "N_ur", "N_avr", "N_vav", "N_rar")
    mass_entries = ((0, 0, 0), (1, 1, 5), (1, 2, 6), (2, 2, 12), (2, 1, 13))
    groups = (((0,), tuple(range(0, 5))), ((1,), tuple(range(5, 12))), ((2,), tuple(range(12, 20))))

    def _rest_design(self, nu: np.ndarray) -> np.ndarray:
        u, v, r = nu.T
        A = np.zeros((nu.shape[0], 3, 20))
        A[:, 0, 1:5] = np.column_stack([u * u, v * v, r * r, v * r])
        A[:, 1, 7:12] = np.column_stack([u * u, u * v, u * r, v * np.abs(v), v * np.abs(r)])
        A[:, 2, 14:20] = np.column_stack([u * u, u * v, u * r, np.abs(v) * r, v * np.abs(v), r * np.abs(r)])
        return A


_MW_MASS = ("m11", "m12", "m13", "m22", "m23", "m33")
_MW_DAMP = tuple(f"D{k}_{i}{j}" for k in "uvr" for i in range(1, 4) for j in range(1, 4))


class McFarlandWhitcomb(_LinearInParameters):
    """McFarland & Whitcomb (2013) in 3 DOF: M nudot + C(nu) nu + sum_k |nu_k| D_k nu = tau (33 params).

    M is full symmetric (m11 m12 m13 m22 m23 m33), C(nu) is the Coriolis-centripetal matrix derived from M
    (Fossen's skew-symmetric form restricted to u, v, r), D_u, D_v, D_r are full 3x3 quadratic damping
    matrices; no separate linear damping. All three equations are fitted jointly (they share M).
    """

    param_names = _MW_MASS + _MW_DAMP
    mass_entries = ((0, 0, 0), (0, 1, 1), (1, 0, 1), (0, 2, 2), (2, 0, 2),
                    (1, 1, 3), (1, 2, 4), (2, 1, 4), (2, 2, 5))
    groups = (((0, 1, 2), tuple(range(33))),)

    def _rest_design(self, nu: np.ndarray) -> np.ndarray:
        u, v, r = nu.T
        A = np.zeros((nu.shape[0], 3, 33))
        m11, m12, m13, m22, m23 = 0, 1, 2, 3, 4
        # C(nu) nu with a = [m11 u + m12 v + m13 r, m12 u + m22 v + m23 r]:
        # X: -r a_y ; Y: r a_x ; N: u a_y - v a_x
        A[:, 0, m12] -= r * u
        A[:, 0, m22] -= r * v
        A[:, 0, m23] -= r * r
        A[:, 1, m11] += r * u
        A[:, 1, m12] += r * v
        A[:, 1, m13] += r * r
        A[:, 2, m12] += u * u - v * v
        A[:, 2, m22] += u * v
        A[:, 2, m23] += u * r
        A[:, 2, m11] -= u * v
        A[:, 2, m13] -= v * r
        absnu = np.abs(nu)
        for k in range(3):
            for i in range(3):
                base = 6 + 9 * k + 3 * i
                A[:, i, base:base + 3] = absnu[:, k:k + 1] * nu
        return A
