"""Explicit 3-DOF (surge, sway, yaw) hydrodynamic models, linear in their parameters, fit by total least squares.

Both models are written as ``A(nu, nudot) theta = tau``: each of the three equations of motion is a row of
regressors (functions of the body velocities nu = [u v r] and accelerations nudot) times the parameter vector.
Fitting solves that system for theta; prediction solves ``M(theta) nudot = tau - A_rest(nu) theta`` for nudot.

Estimator contract: ``X = [u v r tau_u tau_v tau_r]`` (6 columns: velocities in m/s, rad/s, generalized
forces in N, N, N·m), ``y = [udot vdot rdot]`` (3 columns), rows in time order within each contiguous run.
See docs/models.md for the regressor structures, their references and the sign convention (identified parameters
are on the left-hand side, i.e. a damping force ``-X_uu u^2`` appears as ``+theta u^2`` with ``theta = -X_uu``;
rigid-body terms are absorbed).

Solvers (``solver=``), each on one group of equations at a time, in homogeneous form ``[Phi | tau] x = 0``:

``"wtls"`` (default): weighted (generalized) total least squares. The noise SDs of the nine raw signals
    (``noise_std``: u, v, r, tau_u, tau_v, tau_r, udot, vdot, rdot; estimated from the data when None) are
    propagated to first order through the regressor functions, row by row (the Jacobian of the design, by
    central differences), and averaged over the rows into a column noise covariance ``C`` (off-diagonal terms
    included: ``v^2`` and ``v r`` share the noise of v). Columns whose noise is zero or negligible (SD below
    1e-8 of the column's RMS: typically tau computed from logged rpm, given as 0) are *exact*: mixed LS-TLS
    (Golub, Hoffman & Stewart 1987; Van Huffel & Vandewalle 1991, ch. 3; why not a variance floor: docs/models.md).
    The other columns are whitened by ``C^-1/2`` (Cholesky); the right singular vector of the smallest singular
    value is taken.
    A multi-equation group (McFarland-Whitcomb) is fitted twice: equations weighted by 1/RMS(tau_e) first, then
    by 1/RMS(residual_e) of that fit (equal equation-error variance across stacked rows, as TLS assumes).
``"tls"``: the paper's plain TLS, columns of ``[Phi | tau]`` scaled to unit RMS (right only if every column's
    error has the same variance after that scaling; kept for the paper's comparison).
``"ols"``: ordinary least squares of tau on Phi (errors in tau only).

Degenerate data. A regressor column identically zero in the fit data (no excitation, e.g. every ``r`` term when
the vehicle never turns) is dropped with a warning naming the model, equation and term (coefficient 0,
``dropped_terms_``). An equation whose tau is identically zero (no actuation: tau_v on a torpedo AUV or ship) is
homogeneous: its own mass coefficient is fixed to 1, the others found relative to it (prediction needs only the
ratios, as ``tau_e = 0`` there), listed in ``homogeneous_equations_``.

Output-error refinement (``refine=True``, needs ``dt_s``): from the (W)TLS solution, the free coefficients are
refined by multiple shooting: windows of ``refine_horizon_s`` s from the measured velocity, RK4 at ``dt_s`` with tau
held per step, velocity error over each DOF's SD minimized by ``scipy.optimize.least_squares``, inside contiguous
runs (``fit(..., groups=ids)``, else :func:`contiguous_runs`). Kept only if it lowers the cost and leaves a
well-conditioned mass matrix.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from sklearn.base import BaseEstimator, RegressorMixin, clone
from sklearn.utils.validation import check_is_fitted, validate_data

from pipeline.errors import ModelError
from pipeline.models import bootstrap
from pipeline.rk4 import rk4_step

log = logging.getLogger(__name__)

__all__ = ["GertlerHagen", "McFarlandWhitcomb", "tls", "ols", "null_vector", "contiguous_runs", "estimate_noise_std",
           "EXPLICIT_INPUTS", "NOISE_SIGNALS", "EQUATIONS", "SOLVERS"]

#: The feature-store columns an explicit model takes, in order.
EXPLICIT_INPUTS = ["u_mps", "v_mps", "r_radps", "tau_u_N", "tau_v_N", "tau_r_Nm"]
#: Order of ``noise_std`` (units m/s, m/s, rad/s, N, N, N·m, m/s², m/s², rad/s²).
NOISE_SIGNALS = ("u", "v", "r", "tau_u", "tau_v", "tau_r", "udot", "vdot", "rdot")
EQUATIONS = ("X", "Y", "N")
SOLVERS = ("wtls", "tls", "ols")
#: tau's noise SD when estimated: at least this fraction of its RMS (tau from logged rpm is nearly exact).
TAU_RELATIVE_FLOOR = 1e-3
_ZERO_COLUMN = 1e-12  # a column with RMS below this fraction of the group's largest column RMS is degenerate
_ZERO_TAU = 1e-9  # a tau below this fraction of the largest tau RMS is identically zero (homogeneous equation)
_EXACT = 1e-8  # a column whose noise SD is below this fraction of its RMS is exact (mixed LS-TLS)
_MAD_TO_SD = 1.482602218505602


def tls(Phi: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Plain total least squares of ``Phi theta ~ y`` (errors in Phi and y): columns of ``[Phi | y]`` scaled to unit
    RMS (units do not decide which column absorbs the error), ``theta = -v[:-1] / v[-1]`` of the right singular
    vector ``v`` of the smallest singular value, scaled back."""
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


def robust_noise_std(x: np.ndarray) -> np.ndarray:
    """White-noise SD per column of time-ordered ``x``: MAD of the second differences / sqrt(6).

    The second difference of white noise of SD s has SD s sqrt(6); a signal smooth at the sample interval adds
    little, and the MAD ignores the few rows where runs join or the signal steps. Underestimates the noise of a
    smoothed (time-correlated) signal: give the smoother's SDs when there are any.
    """
    x = np.asarray(x, dtype=float).reshape(len(x), -1)
    if len(x) < 4:
        return np.zeros(x.shape[1])
    d2 = np.diff(x, n=2, axis=0)
    mad = np.median(np.abs(d2 - np.median(d2, axis=0)), axis=0)
    return _MAD_TO_SD * mad / np.sqrt(6.0)


def estimate_noise_std(X: np.ndarray, y: np.ndarray, tau_floor: float = TAU_RELATIVE_FLOOR) -> np.ndarray:
    """The nine noise SDs (:data:`NOISE_SIGNALS` order) from time-ordered ``X = [nu tau]``, ``y = nudot``;
    tau's at least ``tau_floor`` times its RMS."""
    nu, tau = X[:, :3], X[:, 3:6]
    s_tau = np.maximum(robust_noise_std(tau), tau_floor * np.sqrt(np.mean(tau * tau, axis=0)))
    return np.concatenate([robust_noise_std(nu), s_tau, robust_noise_std(y)])


def null_vector(Z: np.ndarray, cov: np.ndarray | None) -> np.ndarray:
    """A unit vector ``x`` minimizing the (weighted) TLS residual of ``Z x = 0``.

    ``cov=None``: plain TLS on unit-RMS columns. Otherwise ``cov`` is the columns' noise covariance: exact
    columns (negligible noise) by mixed LS-TLS, the others whitened by ``cov^-1/2``.
    """
    rms = np.sqrt(np.mean(Z * Z, axis=0))
    rms[rms == 0] = 1.0
    if cov is None:
        _, _, vt = np.linalg.svd(Z / rms, full_matrices=False)
        x = vt[-1] / rms
        return x / np.linalg.norm(x)
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    exact = sd <= _EXACT * rms
    noisy = ~exact
    if not noisy.any():
        raise ModelError("WTLS: every column is exact (zero noise): nothing to adjust; use solver='ols'")
    C = cov[np.ix_(noisy, noisy)]
    d = np.sqrt(np.diag(C))
    L = np.linalg.cholesky(C / np.outer(d, d) + 1e-12 * np.eye(len(d))) * d[:, None]  # C = L L^T
    Zn = np.linalg.solve(L, Z[:, noisy].T).T  # whitened: unit noise covariance
    x = np.zeros(Z.shape[1])
    if not exact.any():
        _, _, vt = np.linalg.svd(Zn, full_matrices=False)
        x[noisy] = np.linalg.solve(L.T, vt[-1])
    else:
        Z1 = Z[:, exact] / rms[exact]
        k = Z1.shape[1]
        R = np.linalg.qr(np.column_stack([Z1, Zn]), mode="r")
        _, _, vt = np.linalg.svd(R[k:, k:], full_matrices=False)
        y2 = vt[-1]
        x1, *_ = np.linalg.lstsq(R[:k, :k], -R[:k, k:] @ y2, rcond=None)
        x[exact] = x1 / rms[exact]
        x[noisy] = np.linalg.solve(L.T, y2)
    return x / np.linalg.norm(x)


def contiguous_runs(nu: np.ndarray, nudot: np.ndarray, dt_s: float, groups=None) -> list[tuple[int, int]]:
    """``(start, stop)`` of each contiguous run of time-ordered rows (at least 2 rows): from ``groups`` (one id per
    row) when given; otherwise a row starts a run where the velocity step and the trapezoid integral of the
    acceleration differ by more than 8 robust SDs and 5 median velocity steps (a smoother's nu and nu_dot agree to
    rounding on most rows, leaving that SD near 0; a seam under a few ordinary steps does a free run no harm)."""
    n = len(nu)
    if groups is not None:
        g = np.asarray(groups)
        if g.shape != (n,):
            raise ValueError(f"groups needs one id per row ({n}), got shape {g.shape}")
        breaks = np.flatnonzero(g[1:] != g[:-1]) + 1
    else:
        d = nu[1:] - nu[:-1] - 0.5 * dt_s * (nudot[1:] + nudot[:-1])
        scale = np.maximum(_MAD_TO_SD * np.median(np.abs(d - np.median(d, axis=0)), axis=0),
                           1e-12 * (np.abs(nu).max(axis=0) + 1e-300))
        breaks = np.flatnonzero(np.any((np.abs(d) > 8 * scale)
                                       & (np.abs(d) > 5 * np.median(np.abs(np.diff(nu, axis=0)), axis=0)), axis=1)) + 1
    edges = [0, *breaks.tolist(), n]
    return [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b - a >= 2]


class _LinearInParameters(RegressorMixin, BaseEstimator):
    """M(theta) nudot + A_rest(nu) theta = tau, fit by (W)TLS/OLS, predicted by solving for nudot."""

    param_names: tuple[str, ...] = ()
    #: (equation, acceleration index, parameter index): M[eq, acc] += theta[param]
    mass_entries: tuple[tuple[int, int, int], ...] = ()
    #: groups of (equations, parameters) fitted jointly; parameters of different groups are disjoint
    groups: tuple[tuple[tuple[int, ...], tuple[int, ...]], ...] = ()

    def __init__(self, solver: str = "wtls", weight_equations: bool = True,
                 noise_std: Sequence[float] | None = None, refine: bool = False, dt_s: float | None = None,
                 refine_horizon_s: float = 2.0, refine_max_nfev: int = 30) -> None:
        self.solver = solver
        self.weight_equations = weight_equations
        self.noise_std = noise_std
        self.refine = refine
        self.dt_s = dt_s
        self.refine_horizon_s = refine_horizon_s
        self.refine_max_nfev = refine_max_nfev

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

    def _design_jacobian(self, nu: np.ndarray, sigma: np.ndarray) -> list[np.ndarray | None]:
        """d A_rest / d nu_k (n, 3, n_params) per velocity k, by central differences (the design is quadratic in
        nu, so they are exact up to rounding except within the step of a kink of |.|); None where sigma_k = 0."""
        out: list[np.ndarray | None] = []
        for k in range(3):
            if sigma[k] == 0:
                out.append(None)
                continue
            h = 1e-6 * max(float(np.sqrt(np.mean(nu[:, k] ** 2))), 1e-9)
            step = np.zeros(3)
            step[k] = h
            out.append((self._rest_design(nu + step) - self._rest_design(nu - step)) / (2 * h))
        return out

    def _design_noise_cov(self, jac: list[np.ndarray | None], sigma: np.ndarray, eqs: list[int],
                          params: list[int], w: np.ndarray) -> np.ndarray:
        """Noise covariance of the group's regressor columns, first order, averaged over the stacked rows."""
        p = len(params)
        cov = np.zeros((p, p))
        for k, J in enumerate(jac):  # velocities
            if J is None:
                continue
            G = (J[:, eqs][:, :, params] * w[None, :, None]).reshape(-1, p)
            cov += sigma[k] ** 2 * (G.T @ G) / G.shape[0]
        for acc in range(3):  # accelerations enter linearly
            if sigma[6 + acc] == 0:
                continue
            E = np.zeros((len(eqs), p))
            for eq, a, k in self.mass_entries:
                if a == acc and eq in eqs and k in params:
                    E[eqs.index(eq), params.index(k)] += w[eqs.index(eq)]
            cov += sigma[6 + acc] ** 2 * (E.T @ E) / len(eqs)
        return cov

    # -- estimator -------------------------------------------------------------------------------
    def _split(self, X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if X.shape[1] != 6:
            raise ValueError(f"{type(self).__name__} expects X = [u v r tau_u tau_v tau_r], got {X.shape[1]} columns")
        return X[:, :3], X[:, 3:]

    def _noise_sigma(self, X: np.ndarray, y: np.ndarray) -> np.ndarray:
        estimated = estimate_noise_std(X, y)
        if self.noise_std is None:
            return estimated
        s = np.asarray(self.noise_std, dtype=float).ravel()
        if s.size != len(NOISE_SIGNALS):
            raise ValueError(f"noise_std needs {len(NOISE_SIGNALS)} values {NOISE_SIGNALS}, got {s.size}")
        if np.any(s < 0):
            raise ValueError(f"noise_std must be >= 0 (NaN: estimate that one), got {s.tolist()}")
        return np.where(np.isnan(s), estimated, s)

    def fit(self, X, y, groups=None):
        """Fit on time-ordered rows; ``groups`` (optional, one id per row) marks contiguous runs for refinement."""
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {list(SOLVERS)}, got {self.solver!r}")
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        if y.ndim != 2 or y.shape[1] != 3:
            raise ValueError(f"{type(self).__name__} expects y = [udot vdot rdot] (3 columns)")
        if self.refine and (self.dt_s is None or not self.dt_s > 0):
            raise ValueError(f"refine=True needs the sample interval dt_s > 0, got {self.dt_s!r}")
        nu, tau = self._split(X)
        sigma = self._noise_sigma(X, y) if self.solver == "wtls" else None
        A = self.design(nu, y)
        jac = self._design_jacobian(nu, sigma) if sigma is not None else []
        theta = np.zeros(len(self.param_names))
        tau_rms = np.sqrt(np.mean(tau * tau, axis=0))
        zero_tau = tau_rms <= _ZERO_TAU * tau_rms.max() if tau_rms.max() > 0 else np.ones(3, dtype=bool)
        self.dropped_terms_: list[tuple[str, str]] = []
        self.homogeneous_equations_: list[str] = []
        self.ols_fallback_: list[str] = []
        fixed: list[int] = []
        for eqs, params in self.groups:
            theta_g, fixed_g = self._fit_group(jac, tau, A, list(eqs), list(params), zero_tau, tau_rms, sigma)
            theta[list(params)] = theta_g
            fixed += fixed_g
        M = self.mass_matrix(theta)
        cond = np.linalg.cond(M)
        if not np.isfinite(cond) or cond > 1e12:
            raise ModelError(f"{type(self).__name__}: identified mass matrix is singular (cond {cond:.3g}); "
                             f"dropped terms {self.dropped_terms_}")
        self.noise_std_ = sigma
        self.coef_ = theta
        self._set_mass(theta)
        self.refined_ = False
        self.refine_cost_: tuple[float, float] | None = None
        if self.refine:
            free = [k for k in range(len(theta)) if k not in fixed
                    and self.param_names[k] not in {t for _, t in self.dropped_terms_}]
            self._refine(nu, tau, y, free, groups)
        log.debug("%s fitted by %s: %s", type(self).__name__, self.solver, self.coefficients())
        return self

    def _set_mass(self, theta: np.ndarray) -> None:
        self.mass_matrix_ = self.mass_matrix(theta)
        self.mass_matrix_inv_ = np.linalg.inv(self.mass_matrix_)

    def _fit_group(self, jac: list[np.ndarray | None], tau: np.ndarray, A: np.ndarray, eqs: list[int],
                   params: list[int], zero_tau: np.ndarray, tau_rms: np.ndarray, sigma: np.ndarray | None
                   ) -> tuple[np.ndarray, list[int]]:
        """One group's coefficients (dropped terms 0) and the indices fixed by normalization."""
        name = type(self).__name__
        eq_names = "/".join(EQUATIONS[e] for e in eqs)
        Phi_all = A[:, eqs][:, :, params]
        col_rms = np.sqrt(np.mean(Phi_all * Phi_all, axis=(0, 1)))
        dead = col_rms <= _ZERO_COLUMN * col_rms.max() if col_rms.max() > 0 else np.ones(len(params), dtype=bool)
        for j in np.flatnonzero(dead):
            where = "/".join(EQUATIONS[e] for e in eqs if np.any(Phi_all[:, eqs.index(e), j] != 0)) or eq_names
            term = self.param_names[params[j]]
            log.warning("%s: equation %s: term %s has no excitation in the fit data (regressor identically zero); "
                        "dropped, coefficient 0", name, where, term)
            self.dropped_terms_.append((where, term))
        keep = [p for p, d in zip(params, dead, strict=True) if not d]
        homogeneous = bool(np.all(zero_tau[eqs]))
        norm_k: int | None = None
        if homogeneous:
            norm_k = next((k for eq, acc, k in self.mass_entries if eq == acc and eq in eqs and k in keep), None)
            if norm_k is None:
                raise ModelError(f"{name}: equation {eq_names} has tau identically zero and no excited acceleration "
                                 "term to normalize by: nothing to identify")
            log.warning("%s: equation %s has tau identically zero (no actuation): homogeneous fit, %s fixed to 1 "
                        "(prediction needs only the ratios)", name, eq_names, self.param_names[norm_k])
            self.homogeneous_equations_.append(eq_names)
        if not keep:
            return np.zeros(len(params)), []
        s = np.array([tau_rms[e] for e in eqs])
        live = ~zero_tau[eqs]
        s[~live] = s[live].mean() if live.any() else 1.0
        w = 1.0 / s if self.weight_equations and len(eqs) > 1 else np.ones(len(eqs))
        theta_k = self._solve(jac, tau, A, eqs, keep, w, homogeneous, norm_k, sigma)
        if self.solver == "wtls" and self.weight_equations and len(eqs) > 1:  # equation-error weights, second pass
            resid = np.einsum("nep,p->ne", A[:, eqs][:, :, keep], theta_k) - tau[:, eqs]
            r = np.sqrt(np.mean(resid * resid, axis=0))
            w = 1.0 / np.maximum(r, 1e-9 * s)
            theta_k = self._solve(jac, tau, A, eqs, keep, w, homogeneous, norm_k, sigma)
        inertia = [keep.index(k) for eq, acc, k in self.mass_entries if eq == acc and eq in eqs and k in keep]
        if self.solver != "ols" and any(theta_k[i] <= 0 for i in inertia):
            # a TLS solution with a non-positive own-acceleration (inertia) coefficient is no physical model: its
            # predictions divide by that coefficient (a fitted yaw inertia of -9.9 gave R2 -27 on its own data)
            bad = [self.param_names[keep[i]] for i in inertia if theta_k[i] <= 0]
            log.warning("%s: equation %s: %s gave non-positive inertia %s; this equation falls back to OLS",
                        name, eq_names, self.solver.upper(), bad)
            self.ols_fallback_.append(eq_names)
            theta_k = self._solve(jac, tau, A, eqs, keep, np.ones(len(eqs)) if len(eqs) == 1 else w, homogeneous,
                                  norm_k, sigma, solver="ols")
        out = np.zeros(len(params))
        out[[params.index(k) for k in keep]] = theta_k
        return out, ([norm_k] if norm_k is not None else [])

    def _solve(self, jac: list[np.ndarray | None], tau: np.ndarray, A: np.ndarray, eqs: list[int], keep: list[int],
               w: np.ndarray, homogeneous: bool, norm_k: int | None, sigma: np.ndarray | None,
               solver: str | None = None) -> np.ndarray:
        solver = solver or self.solver
        name = type(self).__name__
        eq_names = "/".join(EQUATIONS[e] for e in eqs)
        Phi = (A[:, eqs][:, :, keep] * w[None, :, None]).reshape(-1, len(keep))
        rhs = (tau[:, eqs] * w[None, :]).reshape(-1)
        if solver == "ols":
            if not homogeneous:
                return ols(Phi, rhs)
            j = keep.index(norm_k)
            others = [i for i in range(len(keep)) if i != j]
            theta = np.zeros(len(keep))
            theta[j] = 1.0
            theta[others] = ols(Phi[:, others], -Phi[:, j])
            return theta
        Z = Phi if homogeneous else np.column_stack([Phi, rhs])
        cov = None
        if solver == "wtls":
            cov_phi = self._design_noise_cov(jac, sigma, eqs, keep, w)
            if homogeneous:
                cov = cov_phi
            else:
                cov = np.zeros((len(keep) + 1, len(keep) + 1))
                cov[:-1, :-1] = cov_phi
                cov[-1, -1] = np.mean([(w[i] * sigma[3 + e]) ** 2 for i, e in enumerate(eqs)])
        x = null_vector(Z, cov)
        j = keep.index(norm_k) if homogeneous else len(keep)
        ref = x[j] * np.sqrt(np.mean(Z[:, j] ** 2))
        if abs(ref) < 1e-12 * np.linalg.norm(x * np.sqrt(np.mean(Z * Z, axis=0))):
            what = f"{self.param_names[norm_k]}" if homogeneous else "tau"
            raise ModelError(f"{name}: equation {eq_names}: non-generic {solver.upper()} problem (the smallest "
                             f"singular vector has no {what} component)")
        return (x[:len(keep)] / x[j]) if homogeneous else (-x[:len(keep)] / x[j])

    # -- output-error refinement -------------------------------------------------------------------
    def _runs(self, nu: np.ndarray, nudot: np.ndarray, groups) -> list[tuple[int, int]]:
        return contiguous_runs(nu, nudot, float(self.dt_s), groups)

    def _rollout(self, theta: np.ndarray, nu0: np.ndarray, taus: np.ndarray, bound: np.ndarray) -> np.ndarray:
        """RK4 of ``M nudot = tau - A_rest(nu) theta`` over a batch: ``nu0 (B, 3)``, ``taus (B, L, 3)`` held per
        step; returns (B, L, 3) velocities after each step."""
        Minv = np.linalg.inv(self.mass_matrix(theta))
        dt = float(self.dt_s)

        def f(x: np.ndarray, t: np.ndarray) -> np.ndarray:
            return (t - self._rest_design(x) @ theta) @ Minv.T

        out = np.empty_like(taus)
        x = nu0.copy()
        with np.errstate(all="ignore"):
            for i in range(taus.shape[1]):
                x = np.clip(rk4_step(f, x, taus[:, i], dt), -bound, bound)
                x = np.where(np.isfinite(x), x, bound)
                out[:, i] = x
        return out

    def _refine(self, nu: np.ndarray, tau: np.ndarray, nudot: np.ndarray, free: list[int], groups) -> None:
        L = max(2, int(round(self.refine_horizon_s / self.dt_s)))
        starts = np.array([s for a, b in self._runs(nu, nudot, groups) for s in range(a, b - L, L)], dtype=int)
        if starts.size == 0 or not free:
            log.warning("%s: no %d-sample window in the fit data: refinement skipped", type(self).__name__, L + 1)
            return
        idx = starts[:, None] + np.arange(L + 1)[None, :]
        nu0, taus, target = nu[starts], tau[idx[:, :-1]], nu[idx[:, 1:]]
        sd = np.maximum(nu.std(axis=0), 1e-9)
        bound = 10.0 * np.abs(nu).max(axis=0) + 1e-9
        theta0 = self.coef_.copy()

        def residual(p: np.ndarray) -> np.ndarray:
            theta = theta0.copy()
            theta[free] = p
            if np.linalg.cond(self.mass_matrix(theta)) > 1e12:
                return np.full(target.size, 1e3)
            return ((self._rollout(theta, nu0, taus, bound) - target) / sd).ravel()

        c0 = 0.5 * float(np.sum(residual(theta0[free]) ** 2))
        res = least_squares(residual, theta0[free], x_scale="jac", max_nfev=self.refine_max_nfev)
        theta = theta0.copy()
        theta[free] = res.x
        ok = res.cost < c0 and np.isfinite(res.cost) and np.linalg.cond(self.mass_matrix(theta)) < 1e12
        log.info("%s: output-error refinement over %d windows of %d steps: cost %.4g -> %.4g (%s)",
                 type(self).__name__, starts.size, L, c0, res.cost, "kept" if ok else "rejected")
        self.refine_cost_ = (c0, float(res.cost))
        if ok:
            self.coef_ = theta
            self._set_mass(theta)
            self.refined_ = True

    def predict(self, X):
        check_is_fitted(self, "coef_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        nu, tau = self._split(X)
        rest = self._rest_design(nu) @ self.coef_
        return (tau - rest) @ self.mass_matrix_inv_.T

    def fast_predictor(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``predict`` of the fitted model without scikit-learn's per-call input checks (a rollout calls it four
        times per step with a small batch; a gray box's base inside its own fast predictor); the same
        arithmetic, so equal to ``predict``. None before ``fit``."""
        if getattr(self, "coef_", None) is None:
            return None
        coef, m_inv_t = self.coef_, self.mass_matrix_inv_.T

        def predict(X: np.ndarray) -> np.ndarray:
            nu, tau = self._split(np.asarray(X, dtype=float))
            return (tau - self._rest_design(nu) @ coef) @ m_inv_t

        return predict

    def coefficients(self) -> dict[str, float]:
        check_is_fitted(self, "coef_")
        return {name: float(v) for name, v in zip(self.param_names, self.coef_, strict=True)}

    def fit_intervals(self, X, y, groups=None, *, level: float = 0.9, n_boot: int = 50, seed: int = 0):
        """``coefficient_intervals_``: ``level`` intervals of ``coef_`` by :mod:`pipeline.models.bootstrap`'s block
        bootstrap (``groups``: as :meth:`Fossen3DOF.fit_intervals`), each replicate a whole refit (noise SDs held,
        no refinement): fewer than Fossen's, so the estimate +- z times their SD. In tasks: :meth:`interval_tasks`."""
        plan, tasks = self.interval_tasks(X, y, groups, level=level, n_boot=n_boot, seed=seed, chunks=1)
        return self.join_intervals(plan, [fn(*args) for fn, args in tasks])

    def interval_tasks(self, X, y, groups=None, *, level: float = 0.9, n_boot: int = 50, seed: int = 0,
                       chunks: int = 5) -> tuple[tuple, list[tuple[Callable[..., Any], tuple]]]:
        """(plan, tasks): :meth:`fit_intervals`' replicates as ``chunks`` tasks ``(fn, args)``; the plan and their
        results, in order, go to :meth:`join_intervals` (the same intervals, to the bit, however many chunks)."""
        check_is_fitted(self, "coef_")
        X, y = np.asarray(X, dtype=float), np.asarray(y, dtype=float)
        resid = np.einsum("nep,p->ne", self.design(X[:, :3], y), self.coef_) - self._split(X)[1]
        runs = [(0, len(X))] if groups is None else contiguous_runs(X[:, :3], y, 0.0, groups)  # dt: unused here
        length, blocks, counts, short = bootstrap.resample_plan(resid, runs, n_boot, seed)
        sd = None if self.noise_std_ is None else list(self.noise_std_)
        replicate = clone(self).set_params(noise_std=sd, refine=False)
        parts = np.array_split(counts, max(1, min(chunks, len(counts))))
        return (level, length, len(blocks), short), [(bootstrap.refits, (replicate, X, y, blocks, part, (ModelError,)))
                                                     for part in parts]

    def join_intervals(self, plan: tuple, parts: Sequence[tuple[list[np.ndarray], int]]):
        """``coefficient_intervals_`` from :meth:`interval_tasks`' plan and its tasks' results, in order."""
        level, length, n_blocks, short = plan
        self.coefficient_intervals_ = bootstrap.summary(
            list(self.param_names), [s for samples, _ in parts for s in samples], level, point=self.coef_,
            length=length, blocks=n_blocks, failed=sum(failed for _, failed in parts), short=short)
        return self


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

    def fast_predictor(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``predict`` of the fitted model with ``C(nu) nu + sum_k |nu_k| D_k nu`` evaluated from the coefficients
        directly (the design matrix of :meth:`_rest_design` is 99 numbers per sample, rebuilt at every RK4 stage
        of a free run); equal to ``predict`` to float rounding. None before ``fit``."""
        if getattr(self, "coef_", None) is None:
            return None
        m11, m12, m13, m22, m23 = (float(c) for c in self.coef_[:5])
        damping = np.ascontiguousarray(self.coef_[6:33].reshape(3, 3, 3))  # D_k[i, j]
        m_inv_t = self.mass_matrix_inv_.T

        def predict(X: np.ndarray) -> np.ndarray:
            nu, tau = self._split(np.asarray(X, dtype=float))
            u, v, r = nu.T
            a_x, a_y = m11 * u + m12 * v + m13 * r, m12 * u + m22 * v + m23 * r
            rest = np.einsum("bk,kij,bj->bi", np.abs(nu), damping, nu)
            rest[:, 0] -= r * a_y
            rest[:, 1] += r * a_x
            rest[:, 2] += u * a_y - v * a_x
            return (tau - rest) @ m_inv_t

        return predict
