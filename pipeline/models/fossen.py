"""The standard 3-DOF Fossen maneuvering model (surge, sway, yaw) of a port-starboard symmetric vehicle, fitted by
the project's weighted total least squares, its damping terms selected by free-run error on held-out blocks.

    (M_RB + M_A) nudot + C_RB(nu) nu + C_A(nu) nu + D(nu) nu = tau                    (Fossen 2011, sec. 6.3-6.4)

- ``M_RB``: the rigid body's 3x3 mass matrix over (u, v, r), from the vehicle config (``rigid_body_mass``); None:
  zero, and the "added-mass" coefficients are then the whole inertia (``X_udot`` = -(m - X_udot), ...).
- ``M_A`` = [[-X_udot, 0, 0], [0, -Y_vdot, -Y_rdot], [0, -Y_rdot, -N_rdot]] (symmetric: N_vdot = Y_rdot), identified.
- ``C(nu) nu`` from M = M_RB + M_A in the skew-symmetric form: with ``a = M nu``, ``[-r a_v, r a_u, u a_v - v a_u]``
  (the Munk moment ``(X_udot - Y_vdot) u v`` included).
- ``D(nu) nu``: X: -X_u u - X_|u|u |u|u; Y: -Y_v v - Y_r r - Y_|v|v |v|v - Y_|r|r |r|r - Y_|r|v |r|v - Y_|v|r |v|r;
  N the same with N. Every term is odd in the velocities, so a vehicle that surges (or sways) both ways is inside
  the family (Gertler-Hagen's X equation is even in u).

Coefficients are SNAME hydrodynamic derivatives (negative for added mass and dissipative damping).

Fit: each row of the three equations, ``A(nu, nudot) theta = tau - M_RB nudot - C_RB(nu) nu``, stacked and fitted
jointly (they share M_A) by WTLS: the right-hand side is a column like the others, the nine signals' noise SDs
(``noise_std``, :data:`pipeline.models.explicit.NOISE_SIGNALS`; estimated when None) propagated to every column,
right-hand side included, by the rows' Jacobian (central differences), and the null vector found by
:func:`pipeline.models.explicit.null_vector` (mixed LS-TLS for exact columns, Cholesky whitening); two passes of
equation weights, 1/RMS(right-hand side) then 1/RMS(residual), as McFarland-Whitcomb's fit. A mass matrix that is
not positive definite falls back to OLS for the model (``ols_fallback_``); still not: ModelError.

Term selection (``select=True``): backward elimination of damping terms by free-run error on held-out blocks. The
rows are cut into ``selection_folds`` contiguous blocks; a term set's score is the mean over the blocks of the
free-run error of the model fitted on the other blocks: windows of ``selection_horizon_s`` inside the held-out
block's contiguous runs, each started from the measured velocity and integrated by RK4 with tau held per step,
squared velocity error over each DOF's SD, averaged over each block's windows less the ``selection_trim`` share
with the largest errors (a free run through a stretch where the motion is unstable, straight-line surge with the
Munk moment, say, amplifies its start's noise whatever the terms, and one such window would decide the block's
score). Each round removes the term whose removal gives the lowest score if that score is at most
``(1 + selection_tolerance)`` times the current one, and stops otherwise; a round's candidate term sets are
integrated together, one batch of windows per block. Why free runs: a one-step (acceleration)
error hardly sees a small damping term, which a free run integrates; why held-out blocks: on the fitted rows every
added term lowers the error. The tolerance prefers the smaller model where
scores tie within noise. The last of a DOF's damping terms in its own velocity (X_u or X_|u|u, ...) is never
removed: a body in water dissipates in every DOF (D(nu) > 0, Fossen 2011, sec. 6.4), and a free run can score
better without any surge damping only because an unknown force (a tether) drives the motion.

Dissipation (``dissipative=True``): each DOF's damping in its own velocity must dissipate energy at every speed,
``-X_u u^2 - X_|u|u |u|u^2 >= 0`` for all u (Fossen 2011, sec. 6.4: D(nu) > 0), which holds for all u only with
both coefficients <= 0 (the linear one rules at low speed, the quadratic one at high); the same for Y_v, Y_|v|v and
N_r, N_|r|r. A fit (every fit: the selection's folds and the final one) that gives one of these the wrong sign has
it pinned at 0 and the others refitted, until none has (an active set: the constrained least-squares optimum lies
on the bound its unconstrained one violates). Why: an unknown force that drives the velocities (a tether), or
cross-flow terms nearly collinear with the quadratic one on one trial's excitation, can give a positive Y_|v|v
whose held-out blocks (the same excitation) look fine and that drives the vehicle at speeds the training trials
did not reach. Pinned terms: ``pinned_terms_`` (final fit), not in ``selected_terms_``.

Guard (``mean_fallback_outputs_``): an output whose one-step R² on the held-out blocks (the selected terms) is
below 0 is predicted by its training mean: never worse there than the mean predictor.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import NamedTuple

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from pipeline.errors import ModelError
from pipeline.models import bootstrap
from pipeline.models.explicit import NOISE_SIGNALS, contiguous_runs, estimate_noise_std, null_vector, ols
from pipeline.rk4 import rk4_step

log = logging.getLogger(__name__)

__all__ = ["Fossen3DOF", "ADDED_MASS_TERMS", "DAMPING_TERMS", "DISSIPATIVE_TERMS"]

#: identified added mass (SNAME), in the order of theta's first four entries
ADDED_MASS_TERMS = ("X_udot", "Y_vdot", "Y_rdot", "N_rdot")
#: damping terms: name -> (equation, regressor); regressor names as in :func:`_damping_columns`
DAMPING_TERMS = {
    "X_u": (0, "u"), "X_|u|u": (0, "|u|u"),
    "Y_v": (1, "v"), "Y_r": (1, "r"), "Y_|v|v": (1, "|v|v"), "Y_|r|r": (1, "|r|r"), "Y_|r|v": (1, "|r|v"),
    "Y_|v|r": (1, "|v|r"),
    "N_v": (2, "v"), "N_r": (2, "r"), "N_|v|v": (2, "|v|v"), "N_|r|r": (2, "|r|r"), "N_|r|v": (2, "|r|v"),
    "N_|v|r": (2, "|v|r"),
}
#: each DOF's damping in its own velocity: dissipative at every speed only if each is <= 0 (SNAME)
DISSIPATIVE_TERMS = ("X_u", "X_|u|u", "Y_v", "Y_|v|v", "N_r", "N_|r|r")
_PARAMS = (*ADDED_MASS_TERMS, *DAMPING_TERMS)
_DAMPING_INDEX = {t: k for k, t in enumerate(DAMPING_TERMS)}
_ZERO_COLUMN = 1e-12  # a column with RMS below this fraction of the largest is degenerate (no excitation)
_ABS_SLACK = 1e-10  # free-run error (in SD^2) below which two scores tie whatever their ratio


class _Stats(NamedTuple):
    """A set of rows, per equation: the R factor of Z's QR (R^T R = Z^T Z, without squaring Z's condition), Z's noise
    covariance sum, and the row count."""

    r: np.ndarray
    noise: np.ndarray
    n: int


_REGRESSORS = ("u", "v", "r", "|u|u", "|v|v", "|r|r", "|r|v", "|v|r")  # :func:`_regressors`' keys, in order


def _regressors(nu: np.ndarray) -> dict[str, np.ndarray]:
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]  # (n, 3), or (K, n, 3): K models' states
    return {"u": u, "v": v, "r": r, "|u|u": np.abs(u) * u, "|v|v": np.abs(v) * v, "|r|r": np.abs(r) * r,
            "|r|v": np.abs(r) * v, "|v|r": np.abs(v) * r}


def _coriolis(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """C(nu) nu of the 3x3 mass matrix ``M`` (skew-symmetric form): ``[-r a_v, r a_u, u a_v - v a_u]``, a = M nu."""
    u, v, r = nu.T
    a_u = nu @ M[0]
    a_v = nu @ M[1]
    return np.column_stack([-r * a_v, r * a_u, u * a_v - v * a_u])


def _added_mass(theta_a: np.ndarray) -> np.ndarray:
    """M_A from the LHS parameters (-X_udot, -Y_vdot, -Y_rdot, -N_rdot)."""
    a11, a22, a23, a33 = theta_a
    return np.array([[a11, 0.0, 0.0], [0.0, a22, a23], [0.0, a23, a33]])


def _rows(nu: np.ndarray, nudot: np.ndarray, tau: np.ndarray, m_rb: np.ndarray) -> np.ndarray:
    """(n, 3, 19): every parameter's regressor per equation (LHS parameters: added mass, then damping), then the
    right-hand side ``tau - M_RB nudot - C_RB(nu) nu`` as the last column."""
    n = len(nu)
    Z = np.zeros((n, 3, len(_PARAMS) + 1))
    for k in range(4):  # added mass: its nudot terms and its share of C(nu) nu (linear in M)
        e = np.zeros(4)
        e[k] = 1.0
        MA = _added_mass(e)
        Z[:, :, k] = nudot @ MA.T + _coriolis(MA, nu)
    reg = _regressors(nu)
    for j, (eq, name) in enumerate(DAMPING_TERMS.values()):
        Z[:, eq, 4 + j] = reg[name]
    Z[:, :, -1] = tau - nudot @ m_rb.T - _coriolis(m_rb, nu)
    return Z


class Fossen3DOF(RegressorMixin, BaseEstimator):
    """Fossen's 3-DOF model (surge, sway, yaw; port-starboard symmetric) by WTLS with term selection.

    ``X = [u v r tau_u tau_v tau_r]``, ``y = [udot vdot rdot]``, rows in time order (as the explicit models).
    ``rigid_body_mass``: 3x3 M_RB over (u, v, r) (None: zero; the added mass is then the whole inertia).
    ``terms``: the damping terms offered (None: every one of :data:`DAMPING_TERMS`). ``noise_std``: the nine
    signals' SDs (None or NaN entries: estimated). ``dt_s``: sample interval for the free runs (None: estimated).
    ``dissipative``: pin a wrong-signed :data:`DISSIPATIVE_TERMS` coefficient at 0 (see the module's docstring).
    Fitted: ``coef_`` (LHS parameters), ``mass_matrix_``, ``selected_terms_``, ``selection_`` (the elimination's
    rounds), ``dropped_terms_``, ``pinned_terms_``, ``ols_fallback_``, ``mean_fallback_outputs_``, ``heldout_r2_``.
    """

    def __init__(self, rigid_body_mass: Sequence[Sequence[float]] | None = None, terms: Sequence[str] | None = None,
                 noise_std: Sequence[float] | None = None, dt_s: float | None = None, select: bool = True,
                 selection_folds: int = 4, selection_horizon_s: float = 5.0, selection_tolerance: float = 0.01,
                 selection_trim: float = 0.1, guard: bool = True, dissipative: bool = True) -> None:
        self.rigid_body_mass = rigid_body_mass
        self.terms = terms
        self.noise_std = noise_std
        self.dt_s = dt_s
        self.select = select
        self.selection_folds = selection_folds
        self.selection_horizon_s = selection_horizon_s
        self.selection_tolerance = selection_tolerance
        self.selection_trim = selection_trim
        self.guard = guard
        self.dissipative = dissipative

    # -- fitting ---------------------------------------------------------------------------------------
    def _m_rb(self) -> np.ndarray:
        if self.rigid_body_mass is None:
            return np.zeros((3, 3))
        m = np.asarray(self.rigid_body_mass, dtype=float)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)):
            raise ValueError(f"rigid_body_mass must be a finite 3x3 matrix over (u, v, r), got shape {m.shape}")
        return m

    def _sigma(self, X: np.ndarray, y: np.ndarray) -> np.ndarray:
        estimated = estimate_noise_std(X, y)
        if self.noise_std is None:
            return estimated
        s = np.asarray(self.noise_std, dtype=float).ravel()
        if s.size != len(NOISE_SIGNALS) or np.any(s < 0):
            raise ValueError(f"noise_std needs {len(NOISE_SIGNALS)} values >= 0 {NOISE_SIGNALS}, got {s.tolist()}")
        return np.where(np.isnan(s), estimated, s)

    def _stats(self, nu: np.ndarray, nudot: np.ndarray, tau: np.ndarray, sigma: np.ndarray, m_rb: np.ndarray,
               masks: Sequence[np.ndarray]) -> list[_Stats]:
        """Per row mask: each equation's R factor of Z and noise covariance sum of Z's columns, the latter
        ``sum_k sigma_k^2 J_k^T J_k`` with ``J_k = dZ/ds_k`` of the nine signals by central differences (Z is
        quadratic in nu except at the kinks of |.|, linear in nudot and tau). Every fit below works on these
        (P+1)x(P+1) matrices, so a term set's fit costs nothing that grows with the rows."""
        Z = _rows(nu, nudot, tau, m_rb)
        grams = [np.stack([np.linalg.qr(Z[m][:, e], mode="r") for e in range(3)]) for m in masks]
        noise = [np.zeros((3, Z.shape[2], Z.shape[2])) for _ in masks]
        signals = np.column_stack([nu, tau, nudot])
        for k in range(9):
            if sigma[k] == 0:
                continue
            h = 1e-6 * max(float(np.sqrt(np.mean(signals[:, k] ** 2))), 1e-9)
            plus, minus = signals.copy(), signals.copy()
            plus[:, k] += h
            minus[:, k] -= h
            J = (_rows(plus[:, :3], plus[:, 6:], plus[:, 3:6], m_rb)
                 - _rows(minus[:, :3], minus[:, 6:], minus[:, 3:6], m_rb)) / (2 * h)
            for acc, m in zip(noise, masks, strict=True):
                acc += sigma[k] ** 2 * np.einsum("nep,neq->epq", J[m], J[m])
        return [_Stats(g, c, int(np.count_nonzero(m))) for g, c, m in zip(grams, noise, masks, strict=True)]

    @staticmethod
    def _solve(stats: _Stats, cols: list[int], solver: str) -> np.ndarray:
        """LHS parameters of the columns ``cols`` (the right-hand side is the last column), the three equations
        stacked with two passes of weights: 1/RMS(right-hand side), then 1/RMS(residual). WTLS gets the
        equations' weighted R factors stacked, B (B^T B = (P+1) Z^T Z / rows: the same null vector and column RMS
        as the stacked rows themselves), and the rows' noise covariance."""
        p1 = stats.r.shape[-1]
        idx = [*cols, p1 - 1]
        ix = np.ix_(idx, idx)
        n_rows = 3 * stats.n
        R = stats.r[:, :, idx]
        w = 1.0 / np.maximum(np.linalg.norm(R[:, :, -1], axis=1) / np.sqrt(stats.n), 1e-300)
        theta = np.zeros(len(cols))
        for _ in range(2):
            B = np.sqrt(p1 / stats.n) * (w[:, None, None] * R).reshape(-1, len(idx))
            if solver == "ols":
                theta = ols(B[:, :-1], B[:, -1])
            else:
                cov = np.einsum("e,epq->pq", w * w, stats.noise)[ix] / n_rows
                x = null_vector(B, cov)
                if abs(x[-1]) < 1e-12:
                    raise ModelError("Fossen3DOF: non-generic WTLS problem (no right-hand-side component)")
                theta = -x[:-1] / x[-1]
            x = np.append(theta, -1.0)
            r = np.linalg.norm(R @ x, axis=1) / np.sqrt(stats.n)
            w = 1.0 / np.maximum(r, 1e-9 * r.max() + 1e-300)
        return theta

    def _fit_terms(self, stats: _Stats, terms: Sequence[str], m_rb: np.ndarray) -> tuple[np.ndarray, bool, list[str]]:
        """Full parameter vector (unused terms 0), whether OLS replaced a non-physical WTLS solution, and the terms
        pinned at 0 for their anti-dissipative sign (``dissipative``: every violator pinned, then a refit, until
        none; LHS parameters are -SNAME, so a violator is negative here)."""
        active, pinned = list(terms), []
        while True:
            theta, ols_used = self._fit_active(stats, active, m_rb)
            bad = [t for t in active if self.dissipative and t in DISSIPATIVE_TERMS
                   and theta[len(ADDED_MASS_TERMS) + _DAMPING_INDEX[t]] < 0]
            if not bad:
                return theta, ols_used, pinned
            pinned += bad
            active = [t for t in active if t not in bad]

    def _fit_active(self, stats: _Stats, terms: Sequence[str], m_rb: np.ndarray) -> tuple[np.ndarray, bool]:
        """Full parameter vector (unused terms 0) and whether OLS replaced a non-physical WTLS solution."""
        cols = [*range(4), *(4 + _DAMPING_INDEX[t] for t in terms)]
        theta = np.zeros(len(_PARAMS))
        theta[cols] = self._solve(stats, cols, "wtls")
        if self._physical(theta, m_rb):
            return theta, False
        theta[cols] = self._solve(stats, cols, "ols")
        if not self._physical(theta, m_rb):
            raise ModelError(f"Fossen3DOF: identified mass matrix M_RB + M_A is not positive definite (WTLS and OLS); "
                             f"terms {list(terms)}")
        return theta, True

    @staticmethod
    def _physical(theta: np.ndarray, m_rb: np.ndarray) -> bool:
        M = m_rb + _added_mass(theta[:4])
        return bool(np.all(np.isfinite(M)) and np.linalg.eigvalsh(0.5 * (M + M.T)).min() > 0)

    def fit(self, X, y, groups=None):
        """Fit on time-ordered rows; ``groups`` (optional, one id per row) marks contiguous runs."""
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        if X.shape[1] != 6 or y.ndim != 2 or y.shape[1] != 3:
            raise ValueError("Fossen3DOF expects X = [u v r tau_u tau_v tau_r] (6 columns) and y = [udot vdot rdot] "
                             f"(3 columns), got {X.shape[1]} and {1 if y.ndim == 1 else y.shape[1]}")
        if self.selection_folds < 2 or not self.selection_horizon_s > 0 or self.selection_tolerance < 0 \
                or not 0 <= self.selection_trim < 1:
            raise ValueError("selection_folds >= 2, selection_horizon_s > 0, selection_tolerance >= 0 and "
                             "0 <= selection_trim < 1 needed")
        unknown = [t for t in (self.terms or ()) if t not in DAMPING_TERMS]
        if unknown:
            raise ValueError(f"unknown damping term(s) {unknown}; known {list(DAMPING_TERMS)}")
        m_rb = self._m_rb()
        nu, tau = X[:, :3], X[:, 3:]
        sigma = self._sigma(X, y)
        terms = list(DAMPING_TERMS) if self.terms is None else [t for t in DAMPING_TERMS if t in self.terms]
        dt = float(self.dt_s) if self.dt_s is not None else _estimate_dt(nu, y)
        if not dt > 0:
            raise ValueError(f"dt_s must be > 0, got {self.dt_s!r}")
        self.dt_s_ = dt
        folds = self._folds(nu, y, groups, dt)
        everything, *fold_stats = self._stats(nu, y, tau, sigma, m_rb,
                                              [np.ones(len(X), dtype=bool), *(train for train, _ in folds)])
        rms = np.sqrt(np.sum(everything.r ** 2, axis=(0, 1))[:-1] / (3 * everything.n))
        dead = rms <= _ZERO_COLUMN * rms.max()
        self.dropped_terms_ = [t for t in terms if dead[4 + list(DAMPING_TERMS).index(t)]]
        for t in self.dropped_terms_:
            log.warning("Fossen3DOF: term %s has no excitation in the fit data (regressor identically zero); dropped",
                        t)
        terms = [t for t in terms if t not in self.dropped_terms_]
        if dead[:4].any():
            raise ModelError(f"Fossen3DOF: no acceleration excitation for "
                             f"{[ADDED_MASS_TERMS[k] for k in np.flatnonzero(dead[:4])]}: the mass matrix cannot be "
                             "identified")
        self._check_forced(everything, m_rb)
        folds = [(train, starts, st) for (train, starts), st in zip(folds, fold_stats, strict=True)]
        self.selection_: list[dict[str, object]] = []
        if self.select and folds:
            terms = self._eliminate(nu, tau, folds, terms, m_rb, dt)
        self.coef_, self.ols_fallback_, self.pinned_terms_ = self._fit_terms(everything, terms, m_rb)
        if self.pinned_terms_:
            log.warning("Fossen3DOF: %s came out anti-dissipative (wrong sign): pinned at 0", self.pinned_terms_)
        terms = [t for t in terms if t not in self.pinned_terms_]
        self.selected_terms_ = terms
        if self.ols_fallback_:
            log.warning("Fossen3DOF: WTLS gave a mass matrix that is not positive definite; OLS used")
        self.noise_std_ = sigma
        self._set_mass(m_rb)
        self.mean_ = y.mean(axis=0)
        self.heldout_r2_ = self._heldout_r2(X, y, folds, terms, m_rb) if folds else None
        bad = [] if self.heldout_r2_ is None or not self.guard else \
            [j for j in range(3) if self.heldout_r2_[j] < 0]
        self.mean_fallback_outputs_ = bad
        if bad:
            log.warning("Fossen3DOF: output(s) %s score held-out R2 %s < 0: predicted by their training mean", bad,
                        [round(float(self.heldout_r2_[j]), 3) for j in bad])
        log.debug("Fossen3DOF: terms %s, coefficients %s", terms, self.coefficients())
        return self

    @staticmethod
    def _check_forced(stats: _Stats, m_rb: np.ndarray) -> None:
        """Each equation needs a right-hand side (tau - M_RB nudot - C_RB nu) that is not identically zero: one
        that is (a ship's sway and yaw, whose rudder force is not in tau, without M_RB) leaves that equation
        homogeneous, its coefficients without a scale, and its weight (1/RMS) infinite."""
        rhs = np.linalg.norm(stats.r[:, :, -1], axis=1) / np.sqrt(max(stats.n, 1))
        unforced = [("surge", "tau_u"), ("sway", "tau_v"), ("yaw", "tau_r")]
        bad = [unforced[e] for e in range(3) if not rhs[e] > _ZERO_COLUMN * max(float(rhs.max()), 1e-300)]
        if bad:
            mass = "" if np.any(m_rb) else " and no rigid_body_mass (M_RB) is given"
            raise ModelError(f"Fossen3DOF: the {', '.join(d for d, _ in bad)} equation(s) have no force: "
                             f"{', '.join(t for _, t in bad)} are zero in every row{mass}, so nothing scales their "
                             "coefficients. A control surface's force (a rudder, fins) is not in tau; for a ship use "
                             "the manoeuvring model (abkowitz), or give the vehicle's M_RB")

    def _set_mass(self, m_rb: np.ndarray) -> None:
        self.mass_matrix_ = m_rb + _added_mass(self.coef_[:4])
        self.mass_matrix_inv_ = np.linalg.inv(self.mass_matrix_)

    # -- selection ---------------------------------------------------------------------------------------
    def _folds(self, nu: np.ndarray, nudot: np.ndarray, groups, dt: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per held-out block: (training row mask, free-run window starts inside the block's contiguous runs)."""
        n = len(nu)
        L = max(2, int(round(self.selection_horizon_s / dt)))
        runs = contiguous_runs(nu, nudot, dt, groups)
        edges = np.linspace(0, n, self.selection_folds + 1).round().astype(int)
        out = []
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            starts = [s for ra, rb in runs for s in range(max(ra, a), min(rb, b) - L, L)]
            if starts:
                train = np.ones(n, dtype=bool)
                train[a:b] = False
                out.append((train, np.array(starts, dtype=int)))
        if len(out) < 2:
            log.warning("Fossen3DOF: fewer than 2 held-out blocks hold a %d-step window: no term selection", L)
            return []
        return out

    def _free_run_errors(self, thetas: np.ndarray, m_rb: np.ndarray, nu: np.ndarray, tau: np.ndarray,
                         starts: np.ndarray, dt: float) -> np.ndarray:
        """The free-run error of each parameter vector (rows of ``thetas``) over the windows at ``starts``: every
        model's windows integrated together, one batch of RK4 steps."""
        L = max(2, int(round(self.selection_horizon_s / dt)))
        idx = starts[:, None] + np.arange(L + 1)[None, :]
        M = m_rb[None] + np.stack([_added_mass(t[:4]) for t in thetas])
        f = _batch_dynamics(thetas, M, np.linalg.inv(M))
        sd = np.maximum(nu.std(axis=0), 1e-9)
        bound = 10.0 * np.abs(nu).max(axis=0) + 1e-9
        x = np.repeat(nu[starts][None], len(thetas), axis=0)
        err = np.zeros(x.shape[:2])
        with np.errstate(all="ignore"):
            for i in range(L):
                x = np.clip(rk4_step(f, x, tau[idx[:, i]], dt), -bound, bound)
                x = np.where(np.isfinite(x), x, bound)
                err += np.sum(((x - nu[idx[:, i + 1]]) / sd) ** 2, axis=2)
        n_kept = max(1, int(np.ceil((1.0 - self.selection_trim) * len(starts))))
        return np.sort(err, axis=1)[:, :n_kept].mean(axis=1) / (L * 3)

    def _scores(self, nu, tau, folds, term_sets, m_rb, dt) -> list[float]:
        """Each term set's score: the mean over the held-out blocks of its free-run error (inf where a block's fit
        fails); the sets' free runs of a block integrated together."""
        errs = np.zeros((len(term_sets), len(folds)))
        failed = np.zeros(len(term_sets), dtype=bool)
        for j, (_, starts, stats) in enumerate(folds):
            fitted, thetas = [], []
            for k, terms in enumerate(term_sets):
                if failed[k]:
                    continue
                try:
                    thetas.append(self._fit_terms(stats, terms, m_rb)[0])
                    fitted.append(k)
                except (ModelError, np.linalg.LinAlgError):
                    failed[k] = True
            if fitted:
                errs[fitted, j] = self._free_run_errors(np.stack(thetas), m_rb, nu, tau, starts, dt)
        return [float("inf") if failed[k] else float(np.mean(errs[k])) for k in range(len(term_sets))]

    def _eliminate(self, nu, tau, folds, terms, m_rb, dt) -> list[str]:
        current = list(terms)
        score, = self._scores(nu, tau, folds, [current], m_rb, dt)
        self.selection_.append({"removed": None, "score": score, "terms": list(current)})
        while True:
            # a DOF keeps at least one damping term in its own velocity: D(nu) > 0 (Fossen 2011, sec. 6.4)
            removable = [t for t in current if not _last_own_damping(t, current)]
            if not removable:
                break
            sets = [[c for c in current if c != t] for t in removable]
            trial = dict(zip(removable, self._scores(nu, tau, folds, sets, m_rb, dt), strict=True))
            best = min(removable, key=lambda t: (trial[t], current.index(t)))
            # _ABS_SLACK: on noise-free data every score is rounding, and a zero term must still go
            if not trial[best] <= score * (1.0 + self.selection_tolerance) + _ABS_SLACK:
                break
            current.remove(best)
            score = trial[best]
            self.selection_.append({"removed": best, "score": score, "terms": list(current)})
            log.info("Fossen3DOF: %s removed (held-out free-run error %.4g)", best, score)
        return current

    def _heldout_r2(self, X, y, folds, terms, m_rb) -> np.ndarray:
        """One-step R² per output of the blocks' held-out rows, each predicted by the fit on the other blocks."""
        pred = np.full_like(y, np.nan)
        for train, _, stats in folds:
            try:
                theta, _, _ = self._fit_terms(stats, terms, m_rb)
            except (ModelError, np.linalg.LinAlgError):
                continue
            M = m_rb + _added_mass(theta[:4])
            pred[~train] = _dynamics(theta, M, np.linalg.inv(M))(X[~train, :3], X[~train, 3:])
        ok = np.all(np.isfinite(pred), axis=1)
        if not ok.any():
            return np.full(3, -np.inf)
        yt, pt = y[ok], pred[ok]
        return 1.0 - ((yt - pt) ** 2).sum(0) / np.maximum(((yt - yt.mean(0)) ** 2).sum(0), 1e-300)

    # -- prediction ------------------------------------------------------------------------------------
    def fast_predictor(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``predict`` without scikit-learn's per-call checks (rollouts, a gray box's base); None before ``fit``."""
        if getattr(self, "coef_", None) is None:
            return None
        f = _dynamics(self.coef_, self.mass_matrix_, self.mass_matrix_inv_)
        fallback, mean = list(self.mean_fallback_outputs_), self.mean_

        def predict(X: np.ndarray) -> np.ndarray:
            X = np.asarray(X, dtype=float)
            out = f(X[:, :3], X[:, 3:6])
            if fallback:
                out[:, fallback] = mean[fallback]
            return out

        return predict

    def predict(self, X):
        check_is_fitted(self, "coef_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        return self.fast_predictor()(X)

    def coefficients(self) -> dict[str, float]:
        """SNAME derivatives: added mass (``N_vdot`` = ``Y_rdot``) and damping; a term not selected is 0."""
        check_is_fitted(self, "coef_")
        return _sname(self.coef_)

    def selection_record(self, outputs: Sequence[str]) -> dict[str, object]:
        """The term selection for a model card: the terms kept, dropped and pinned, the elimination's rounds (JSON:
        an infinite score as None), the fallbacks (``outputs`` names the mean-fallback ones)."""
        check_is_fitted(self, "coef_")
        return {"selected": list(self.selected_terms_), "dropped_no_excitation": list(self.dropped_terms_),
                "rounds": [{**r, "score": r["score"] if np.isfinite(r["score"]) else None} for r in self.selection_],
                "ols_fallback": bool(self.ols_fallback_), "pinned_anti_dissipative": list(self.pinned_terms_),
                "mean_fallback_outputs": [outputs[j] for j in self.mean_fallback_outputs_]}

    def fit_intervals(self, X, y, groups=None, *, level: float = 0.9, n_boot: int = 200, seed: int = 0):
        """``coefficient_intervals_``: ``level`` intervals of the identified coefficients (added mass and the
        selected damping terms, SNAME) by the block bootstrap of :mod:`pipeline.models.bootstrap`, the terms held
        at the selection's (intervals conditional on it: the selection's own variability is not in them). ``X``,
        ``y``: the rows :meth:`fit` was given; ``groups`` (one id per row, e.g. the trial): blocks are drawn within
        each group, so every trial keeps its share (None: one group; a block may then span two trials, which
        only the blocks' correlation sees). Each replicate weights the rows' sufficient statistics by its block
        counts, so it costs a few small QR factorizations, not a fit."""
        check_is_fitted(self, "coef_")
        X, y = np.asarray(X, dtype=float), np.asarray(y, dtype=float)
        nu, tau, m_rb = X[:, :3], X[:, 3:], self._m_rb()
        resid = _rows(nu, y, tau, m_rb) @ np.append(self.coef_, -1.0)
        runs = [(0, len(X))] if groups is None else contiguous_runs(nu, y, self.dt_s_, groups)
        length, blocks, counts, short = bootstrap.resample_plan(resid, runs, n_boot, seed)
        masks = []
        for a, b, _ in blocks:
            m = np.zeros(len(X), dtype=bool)
            m[a:b] = True
            masks.append(m)
        parts = self._stats(nu, y, tau, self.noise_std_, m_rb, masks)
        samples, failed = [], 0
        names = [*ADDED_MASS_TERMS, "N_vdot", *self.selected_terms_]
        for c in counts:
            use = np.flatnonzero(c)
            r = np.concatenate([np.sqrt(c[b]) * parts[b].r for b in use], axis=1)
            stats = _Stats(np.stack([np.linalg.qr(r[e], mode="r") for e in range(3)]),
                           sum(c[b] * parts[b].noise for b in use), int(sum(c[b] * parts[b].n for b in use)))
            try:
                theta = self._fit_terms(stats, self.selected_terms_, m_rb)[0]
            except ModelError:  # a replicate without a physical mass matrix: left out, and counted
                failed += 1
                continue
            samples.append(np.array([_sname(theta)[k] for k in names]))
        self.coefficient_intervals_ = bootstrap.summary(names, samples, level, length=length, blocks=len(blocks),
                                                        failed=failed, short=short)
        return self


def _last_own_damping(term: str, current: Sequence[str]) -> bool:
    """Whether ``term`` is the last of its equation's :data:`DISSIPATIVE_TERMS` left in ``current``."""
    if term not in DISSIPATIVE_TERMS:
        return False
    eq = DAMPING_TERMS[term][0]
    return not any(t != term and t in DISSIPATIVE_TERMS and DAMPING_TERMS[t][0] == eq for t in current)


def _sname(theta: np.ndarray) -> dict[str, float]:
    out = {name: -float(v) for name, v in zip(_PARAMS, theta, strict=True)}
    out["N_vdot"] = out["Y_rdot"]
    return out


def _dynamics(theta: np.ndarray, M: np.ndarray, M_inv: np.ndarray) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """``nudot(nu, tau) = M^-1 (tau - C(nu) nu - D(nu) nu)`` of the LHS parameters ``theta`` and ``M``."""
    damping = [(eq, name, float(c)) for (eq, name), c in zip(DAMPING_TERMS.values(), theta[4:], strict=True) if c]

    def f(nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
        rhs = tau - _coriolis(M, nu)
        if damping:
            reg = _regressors(nu)
            for eq, name, c in damping:
                rhs[:, eq] -= c * reg[name]
        return rhs @ M_inv.T

    return f


def _batch_dynamics(thetas: np.ndarray, M: np.ndarray, M_inv: np.ndarray
                    ) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """:func:`_dynamics` of K models at once: ``thetas`` (K, parameters), ``M`` and ``M_inv`` (K, 3, 3); the
    returned ``f(nu, tau)`` takes ``nu`` (K, n, 3), each model's states, and ``tau`` (n, 3), shared."""
    W = np.zeros((len(thetas), len(_REGRESSORS), 3))  # damping: regressor -> equation, per model
    for k, (eq, name) in enumerate(DAMPING_TERMS.values()):
        W[:, _REGRESSORS.index(name), eq] = thetas[:, 4 + k]
    M_inv_t = np.swapaxes(M_inv, 1, 2)

    def f(nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
        u, v, r = nu[..., 0], nu[..., 1], nu[..., 2]
        a = nu @ np.swapaxes(M, 1, 2)  # a = M nu, per model
        coriolis = np.stack([-r * a[..., 1], r * a[..., 0], u * a[..., 1] - v * a[..., 0]], axis=-1)
        reg = _regressors(nu)
        return (tau - coriolis - np.stack([reg[name] for name in _REGRESSORS], axis=-1) @ W) @ M_inv_t

    return f


def _estimate_dt(nu: np.ndarray, nudot: np.ndarray) -> float:
    """The sample interval from the data: median over rows and DOFs of ``dnu / mean(nudot)`` where the trapezoid
    mean of the acceleration is in its DOF's upper quartile (a run's join is an outlier the median ignores)."""
    d = np.diff(nu, axis=0)
    a = 0.5 * (nudot[1:] + nudot[:-1])
    ratios = []
    for k in range(3):
        big = np.abs(a[:, k]) >= np.quantile(np.abs(a[:, k]), 0.75)
        big &= np.abs(a[:, k]) > 0
        ratios.append(d[big, k] / a[big, k])
    r = np.concatenate(ratios)
    r = r[np.isfinite(r)]
    if r.size == 0:
        raise ModelError("Fossen3DOF: cannot estimate the sample interval (no acceleration); give dt_s")
    return float(np.median(r))
