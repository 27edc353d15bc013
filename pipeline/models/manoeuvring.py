"""An Abkowitz-type manoeuvring model of a surface ship (surge, sway, yaw) with control-surface and propeller
terms, fitted by least squares, its terms selected by blocked cross-validation.

Abkowitz (1964) writes each hydrodynamic force of a port-starboard symmetric ship as a third-order Taylor
polynomial in the motion (u, v, r) and the rudder angle delta: X even in (v, r, delta) jointly, Y and N odd;
the vessel-identification literature fits its coefficients by regression on manoeuvres (zig-zags), with the
propeller's thrust T and the rudder's slipstream (T delta) as inputs (Abkowitz 1964; Fossen 2011, ch. 7, the
manoeuvring models based on odd functions; Luo & Zou 2009, the Abkowitz model identified from zig-zag tests).
Hull terms in the modulus form |v|v, |r|r follow Fossen (2011, ch. 7) and Norrbin.

The model is written solved for the accelerations (the mass matrix of a symmetric ship couples only sway and yaw,
which share one term library, so ``M^-1 [X Y N]`` has the same terms): ``nudot_e = sum_k c_k phi_k(u, v, r, T,
delta)``, one equation per DOF. A coefficient is then a hydrodynamic derivative over the inertia (``X_T`` =
(1 - t) / (m - X_udot) for the thrust deduction t, ``Y_d`` = the rudder's sway force per radian over the inertia,
...), named ``<X|Y|N>_<term>`` with ``d`` for delta (:data:`TERMS`).

Inputs: ``X = [u v r T_1 .. T_k delta_1 .. delta_m]`` (``n_thrust`` = k propeller thrusts in N, summed into T;
``n_surfaces`` = m control-surface angles in rad, averaged into delta: rudders that move together), ``y = [udot
vdot rdot]``, rows in time order. A term whose regressor is identically zero (no rudder given, or never moved) is
dropped with a warning (``dropped_terms_``).

Fit (per equation, they share no parameter): ordinary least squares on unit-RMS columns
(:func:`pipeline.models.explicit.ols`). Term selection (``select=True``): backward elimination by blocked
cross-validation, no shuffling: the rows are cut into ``selection_folds`` contiguous blocks; a term set's score is
the mean over the blocks of the squared one-step error of the fit on the other blocks, over the output's variance;
each round removes the term whose removal gives the lowest score if that score is at most ``(1 +
selection_tolerance)`` times the current one (plus 1e-10, for noise-free data), and stops otherwise. Rounds in
``selection_`` (the model card's ``term_selection``).

References: M. A. Abkowitz, Lectures on ship hydrodynamics - steering and manoeuvrability, Hy-5, Hydro- and
Aerodynamics Laboratory, Lyngby, 1964. T. I. Fossen, Handbook of Marine Craft Hydrodynamics and Motion Control,
Wiley, 2011, ch. 7. W. L. Luo, Z. J. Zou, Parametric identification of ship maneuvering models by using support
vector machines, Journal of Ship Research 53(1), 2009.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.utils.validation import check_is_fitted, validate_data

from pipeline.models.explicit import ols

log = logging.getLogger(__name__)

__all__ = ["Abkowitz3DOF", "TERMS", "REGRESSORS"]

#: the regressors, functions of (u, v, r, T, d): d is the rudder angle delta (rad), T the total thrust (N)
REGRESSORS: dict[str, Callable[..., np.ndarray]] = {
    "0": lambda u, v, r, T, d: np.ones_like(u),
    "u": lambda u, v, r, T, d: u, "|u|u": lambda u, v, r, T, d: np.abs(u) * u,
    "v": lambda u, v, r, T, d: v, "r": lambda u, v, r, T, d: r,
    "vv": lambda u, v, r, T, d: v * v, "rr": lambda u, v, r, T, d: r * r, "vr": lambda u, v, r, T, d: v * r,
    "|v|v": lambda u, v, r, T, d: np.abs(v) * v, "|r|r": lambda u, v, r, T, d: np.abs(r) * r,
    "vvr": lambda u, v, r, T, d: v * v * r, "vrr": lambda u, v, r, T, d: v * r * r,
    "T": lambda u, v, r, T, d: T, "d": lambda u, v, r, T, d: d, "dd": lambda u, v, r, T, d: d * d,
    "ddd": lambda u, v, r, T, d: d ** 3, "Td": lambda u, v, r, T, d: T * d,
    "vdd": lambda u, v, r, T, d: v * d * d, "rdd": lambda u, v, r, T, d: r * d * d,
}
_SURGE = ("0", "u", "|u|u", "vv", "rr", "vr", "dd", "T")
_LATERAL = ("0", "v", "r", "|v|v", "|r|r", "vvr", "vrr", "d", "ddd", "Td", "vdd", "rdd")
#: the candidate terms of each equation (surge even in (v, r, delta), sway and yaw odd; "0": a constant)
TERMS: dict[str, tuple[str, ...]] = {"X": _SURGE, "Y": _LATERAL, "N": _LATERAL}
_ZERO_COLUMN = 1e-12  # a column with RMS below this fraction of the equation's largest is degenerate
_ABS_SLACK = 1e-10  # normalized CV error below which two scores tie whatever their ratio


def _columns(eq: str, u, v, r, T, d) -> np.ndarray:
    return np.column_stack([REGRESSORS[t](u, v, r, T, d) for t in TERMS[eq]])


class Abkowitz3DOF(RegressorMixin, BaseEstimator):
    """Abkowitz-type 3-DOF manoeuvring model (acceleration form), least squares, terms by blocked CV.

    ``n_thrust``, ``n_surfaces``: how many thrust and control-surface-angle columns follow ``u v r`` in X.
    ``terms``: the names offered (``X_|u|u`` ...; None: every one of :data:`TERMS`). Fitted: ``coef_`` (3, P) over
    :data:`TERMS` per equation (0 where not selected), ``selected_terms_``, ``dropped_terms_``, ``selection_``,
    ``heldout_r2_`` (one-step R² of the selected terms on the held-out blocks).
    """

    def __init__(self, n_thrust: int = 1, n_surfaces: int = 1, terms: list[str] | None = None, select: bool = True,
                 selection_folds: int = 5, selection_tolerance: float = 0.01) -> None:
        self.n_thrust = n_thrust
        self.n_surfaces = n_surfaces
        self.terms = terms
        self.select = select
        self.selection_folds = selection_folds
        self.selection_tolerance = selection_tolerance

    @staticmethod
    def names() -> list[str]:
        """Every coefficient's name, equation by equation."""
        return [f"{eq}_{t}" for eq in TERMS for t in TERMS[eq]]

    def _signals(self, X: np.ndarray) -> tuple[np.ndarray, ...]:
        k, m = int(self.n_thrust), int(self.n_surfaces)
        if X.shape[1] != 3 + k + m:
            raise ValueError(f"Abkowitz3DOF expects X = [u v r] + {k} thrust + {m} control-surface angle columns "
                             f"({3 + k + m}), got {X.shape[1]}")
        u, v, r = X[:, 0], X[:, 1], X[:, 2]
        T = X[:, 3:3 + k].sum(axis=1) if k else np.zeros(len(X))
        d = X[:, 3 + k:].mean(axis=1) if m else np.zeros(len(X))
        return u, v, r, T, d

    def fit(self, X, y):
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        if self.n_thrust < 0 or self.n_surfaces < 0:
            raise ValueError(f"n_thrust and n_surfaces must be >= 0, got {self.n_thrust}, {self.n_surfaces}")
        if y.ndim != 2 or y.shape[1] != 3:
            raise ValueError(f"Abkowitz3DOF expects y = [udot vdot rdot] (3 columns), got "
                             f"{1 if y.ndim == 1 else y.shape[1]}")
        if self.selection_folds < 2 or self.selection_tolerance < 0:
            raise ValueError("selection_folds >= 2 and selection_tolerance >= 0 needed")
        offered = self.names() if self.terms is None else list(self.terms)
        unknown = [t for t in offered if t not in self.names()]
        if unknown:
            raise ValueError(f"unknown Abkowitz term(s) {unknown}; known {self.names()}")
        signals = self._signals(X)
        n = len(X)
        edges = np.linspace(0, n, self.selection_folds + 1).round().astype(int)
        blocks = [(a, b) for a, b in zip(edges[:-1], edges[1:], strict=True) if b > a]
        select = self.select and len(blocks) >= 2 and n >= 4 * len(TERMS["Y"])
        self.coef_ = np.zeros((3, max(len(t) for t in TERMS.values())))
        self.selected_terms_: list[str] = []
        self.dropped_terms_: list[str] = []
        self.selection_: list[dict[str, object]] = []
        self.heldout_r2_ = np.full(3, np.nan)
        for e, eq in enumerate(TERMS):
            A = _columns(eq, *signals)
            rms = np.sqrt(np.mean(A * A, axis=0))
            dead = rms <= _ZERO_COLUMN * max(rms.max(), 1e-300)
            cols = [j for j, t in enumerate(TERMS[eq]) if f"{eq}_{t}" in offered]
            for j in [j for j in cols if dead[j]]:
                log.warning("Abkowitz3DOF: term %s_%s has no excitation in the fit data (regressor identically "
                            "zero); dropped", eq, TERMS[eq][j])
                self.dropped_terms_.append(f"{eq}_{TERMS[eq][j]}")
            cols = [j for j in cols if not dead[j]]
            grams = self._blocks_gram(A, y[:, e], blocks)
            var = float(np.sum((y[:, e] - y[:, e].mean()) ** 2))
            if select and cols:
                cols = self._eliminate(eq, grams, var, cols)
            if cols:
                self.coef_[e, cols] = ols(A[:, cols], y[:, e])
                if len(blocks) >= 2:
                    self.heldout_r2_[e] = 1.0 - self._score(grams, cols, var)
            self.selected_terms_ += [f"{eq}_{TERMS[eq][j]}" for j in cols]
        self.ols_fallback_ = False  # the model card's term_selection keys, as Fossen3DOF's
        self.mean_fallback_outputs_: list[int] = []
        log.debug("Abkowitz3DOF: terms %s", self.selected_terms_)
        return self

    @staticmethod
    def _blocks_gram(A: np.ndarray, y: np.ndarray, blocks: list[tuple[int, int]]) -> list[np.ndarray]:
        """Per block, the Gram matrix of ``[A / rms | y]`` (unit-RMS columns): a term set's fits and held-out errors
        come from these small matrices, at no cost that grows with the rows."""
        rms = np.sqrt(np.mean(A * A, axis=0))
        Z = np.column_stack([A / np.where(rms > 0, rms, 1.0), y])
        return [Z[a:b].T @ Z[a:b] for a, b in blocks]

    @staticmethod
    def _score(grams: list[np.ndarray], cols: list[int], var: float) -> float:
        """Mean over the held-out blocks of the squared one-step error of the least-squares fit on the other
        blocks, over the output's sum of squares about its mean (1 - the blocked-CV R²)."""
        total = sum(grams)
        idx = [*cols, -1]
        err = 0.0
        for G in grams:
            train = (total - G)[np.ix_(idx, idx)]
            coef = np.linalg.lstsq(train[:-1, :-1], train[:-1, -1], rcond=None)[0]
            held = G[np.ix_(idx, idx)]
            x = np.append(coef, -1.0)
            err += max(float(x @ held @ x), 0.0)
        return err / max(var, 1e-300)

    def _eliminate(self, eq: str, grams: list[np.ndarray], var: float, cols: list[int]) -> list[int]:
        current = list(cols)
        score = self._score(grams, current, var)
        self.selection_.append({"equation": eq, "removed": None, "score": score})
        while len(current) > 1:
            trial = {j: self._score(grams, [c for c in current if c != j], var) for j in current}
            best = min(current, key=lambda j: (trial[j], current.index(j)))
            if not trial[best] <= score * (1.0 + self.selection_tolerance) + _ABS_SLACK:
                break
            current.remove(best)
            score = trial[best]
            self.selection_.append({"equation": eq, "removed": f"{eq}_{TERMS[eq][best]}", "score": score})
            log.info("Abkowitz3DOF: %s_%s removed (blocked-CV error %.4g of the variance)", eq, TERMS[eq][best],
                     score)
        return current

    def fast_predictor(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``predict`` without scikit-learn's per-call checks (rollouts, a gray box's base); None before ``fit``."""
        if getattr(self, "coef_", None) is None:
            return None
        coef = self.coef_.copy()

        def predict(X: np.ndarray) -> np.ndarray:
            signals = self._signals(np.asarray(X, dtype=float))
            return np.column_stack([_columns(eq, *signals) @ coef[e, :len(TERMS[eq])]
                                    for e, eq in enumerate(TERMS)])

        return predict

    def predict(self, X):
        check_is_fitted(self, "coef_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        return self.fast_predictor()(X)

    def coefficients(self) -> dict[str, float]:
        """Every coefficient by name (acceleration form; a term not selected is 0)."""
        check_is_fitted(self, "coef_")
        return {f"{eq}_{t}": float(self.coef_[e, j]) for e, eq in enumerate(TERMS) for j, t in enumerate(TERMS[eq])}
