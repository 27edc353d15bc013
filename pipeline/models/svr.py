"""SVR variants of the coupled acceleration model (paper 000): RBF, 2-weights and WDSE kernels.

All three standardize their inputs and then call libsvm's native RBF kernel. The WDSE kernel

    k(x, x') = exp(-sum_i gamma_i (x_i - x'_i)^2)

equals an RBF kernel with gamma = 1 on inputs scaled by sqrt(gamma_i), so every variant is "scale the
standardized inputs by a per-column factor, then ``SVR(kernel='rbf', gamma=1)``": exact, as fast as a plain
RBF-SVR, and picklable (no callable kernel, no Gram matrix). The gammas refer to STANDARDIZED inputs.

``C`` is libsvm's: it multiplies the SUM of the training losses, so the regularization of the equivalent
regularized risk, lambda = 1 / (2 C n), falls as 1/n when one C is fitted on more rows. Hyperparameters are
searched on a subsample (``coupled.max_samples``) and the model is then fitted on every row: with ``C_rows`` (the
rows per search fold the C was chosen on) a fit on n rows uses ``C * (C_rows / n) ** C_rate`` (:func:`scaled_C`),
so lambda goes as n^-C_rate between the search and the fit (0: C kept, lambda ~ 1/n; 1: lambda kept). The default
0.5 (lambda ~ n^-1/2) is the measured choice of docs/models.md.

Each estimator is single-output; :class:`PerOutputRegressor` fits one estimator per output column so that
every output keeps its own hyperparameters (Table II of the paper).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from sklearn.base import BaseEstimator, RegressorMixin, clone
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVR
from sklearn.utils.validation import check_is_fitted, validate_data

log = logging.getLogger(__name__)

__all__ = ["RBFSVR", "TwoWeightsSVR", "WDSESVR", "PerOutputRegressor", "fit_rows", "scaled_C", "wdse_gram"]


def scaled_C(C: float, C_rows: int | None, n_rows: int, C_rate: float = 0.5) -> float:
    """The C a fit on ``n_rows`` rows uses when ``C`` was chosen on ``C_rows`` rows (None: ``C`` unchanged)."""
    if C_rows is None:
        return float(C)
    if C_rows <= 0 or n_rows <= 0 or not 0.0 <= C_rate <= 1.0:
        raise ValueError(f"C_rows and the rows fitted must be > 0 and C_rate in [0, 1], got C_rows {C_rows}, "
                         f"{n_rows} rows, C_rate {C_rate}")
    return float(C) * (C_rows / n_rows) ** C_rate


def fit_rows(n_rows: int, max_rows: int | None) -> np.ndarray:
    """The rows an SVR is fitted on: all, or ``max_rows`` of them evenly spaced (the rows are in time order, so in
    time: a slowly varying signal sampled at 10-20 Hz repeats itself from row to row). A libsvm fit costs about the
    square of its rows, and a prediction its support vectors; both stay bounded on long campaigns."""
    if max_rows is None or n_rows <= max_rows:
        return np.arange(n_rows)
    if max_rows < 1:
        raise ValueError(f"max_rows must be >= 1, got {max_rows}")
    return np.unique(np.linspace(0, n_rows - 1, int(max_rows)).round().astype(np.int64))


class _ScaledRBFSVR(RegressorMixin, BaseEstimator):
    """Shared machinery: standardize, scale column i by sqrt(gamma_i), libsvm RBF with gamma = 1. ``max_rows``
    (None: every row): fit on at most this many rows (:func:`fit_rows`), C scaled to them."""

    def _gamma_vector(self, n_features: int) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def _svr(self) -> SVR:
        return SVR(kernel="rbf", gamma=1.0, C=self.C_, epsilon=self.epsilon, tol=self.tol,
                   cache_size=self.cache_size, max_iter=self.max_iter)

    def _transform(self, X: np.ndarray) -> np.ndarray:
        return self.scaler_.transform(X) * self.feature_scale_

    def fit(self, X, y):
        X, y = validate_data(self, X, y, y_numeric=True, dtype=np.float64)
        rows = fit_rows(len(X), self.max_rows)
        X, y = X[rows], y[rows]
        self.n_fit_rows_ = len(rows)
        gammas = self._gamma_vector(X.shape[1])
        if np.any(~np.isfinite(gammas)) or np.any(gammas < 0):
            raise ValueError(f"gammas must be finite and >= 0, got {gammas.tolist()}")
        self.gammas_ = gammas
        self.feature_scale_ = np.sqrt(gammas)
        self.scaler_ = StandardScaler().fit(X)
        self.C_ = scaled_C(self.C, self.C_rows, len(X), self.C_rate)
        self.svr_ = self._svr().fit(self._transform(X), y)
        self.n_iter_ = int(np.max(self.svr_.n_iter_))
        return self

    def predict(self, X):
        check_is_fitted(self, "svr_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        return self.svr_.predict(self._transform(X))

    @property
    def n_support_(self) -> int:
        check_is_fitted(self, "svr_")
        return int(self.svr_.support_.size)

    def kernel_terms(self) -> tuple[np.ndarray, ...] | None:
        """What :meth:`PerOutputRegressor.fast_predictor` needs of this fitted SVR: ``(mean, scale, feature_scale,
        centre, support vectors - centre, their squared norms, dual coefficients, intercept)``; None unless it is
        libsvm's RBF with gamma = 1 on standardized, scaled inputs."""
        svr, scaler, scale = (getattr(self, k, None) for k in ("svr_", "scaler_", "feature_scale_"))
        if not isinstance(svr, SVR) or svr.kernel != "rbf" or getattr(svr, "_gamma", None) != 1.0 or \
                scale is None or getattr(scaler, "mean_", None) is None or getattr(scaler, "scale_", None) is None:
            return None
        sv = np.asarray(svr.support_vectors_, dtype=float)
        centre = sv.mean(axis=0)  # distances from the centroid: less cancellation in |z|^2 + |s|^2 - 2 z.s
        sv_c = sv - centre
        return (scaler.mean_, scaler.scale_, np.asarray(scale, dtype=float), centre, sv_c,
                np.einsum("ij,ij->i", sv_c, sv_c), np.asarray(svr.dual_coef_[0], dtype=float),
                float(svr.intercept_[0]))


class RBFSVR(_ScaledRBFSVR):
    """RBF-SVR on standardized inputs: k(x, x') = exp(-gamma ||x - x'||^2)."""

    def __init__(self, gamma: float = 0.1, C: float = 1.0, epsilon: float = 0.1, *, tol: float = 1e-3,
                 cache_size: float = 200.0, max_iter: int = -1, C_rows: int | None = None,
                 C_rate: float = 0.5, max_rows: int | None = None) -> None:
        self.gamma = gamma
        self.C = C
        self.epsilon = epsilon
        self.tol = tol
        self.cache_size = cache_size
        self.max_iter = max_iter
        self.C_rows = C_rows
        self.C_rate = C_rate
        self.max_rows = max_rows

    def _gamma_vector(self, n_features: int) -> np.ndarray:
        return np.full(n_features, float(self.gamma))


class TwoWeightsSVR(_ScaledRBFSVR):
    """"2-weights-RBF" SVR: ``gamma_velocity`` for the first ``n_velocity`` inputs, ``gamma_actuator`` for the rest.

    With the default column order ``u v r T1 T2 T3`` (or the paper's ``u v r n1 n2 n3``), ``n_velocity=3``.
    """

    def __init__(self, gamma_velocity: float = 0.1, gamma_actuator: float = 0.1, C: float = 1.0,
                 epsilon: float = 0.1, *, n_velocity: int = 3, tol: float = 1e-3, cache_size: float = 200.0,
                 max_iter: int = -1, C_rows: int | None = None, C_rate: float = 0.5,
                 max_rows: int | None = None) -> None:
        self.gamma_velocity = gamma_velocity
        self.gamma_actuator = gamma_actuator
        self.C = C
        self.epsilon = epsilon
        self.n_velocity = n_velocity
        self.tol = tol
        self.cache_size = cache_size
        self.max_iter = max_iter
        self.C_rows = C_rows
        self.C_rate = C_rate
        self.max_rows = max_rows

    def _gamma_vector(self, n_features: int) -> np.ndarray:
        if self.n_velocity < 0:
            raise ValueError(f"n_velocity must be >= 0, got {self.n_velocity}")
        k = min(int(self.n_velocity), n_features)
        out = np.full(n_features, float(self.gamma_actuator))
        out[:k] = float(self.gamma_velocity)
        return out


class WDSESVR(_ScaledRBFSVR):
    """WDSE-SVR: one gamma per (standardized) input, k(x, x') = exp(-sum_i gamma_i (x_i - x'_i)^2).

    ``gammas=None`` means 1 / n_features for every input (sklearn's 'scale' on standardized data).
    """

    def __init__(self, gammas: Sequence[float] | None = None, C: float = 1.0, epsilon: float = 0.1, *,
                 tol: float = 1e-3, cache_size: float = 200.0, max_iter: int = -1, C_rows: int | None = None,
                 C_rate: float = 0.5, max_rows: int | None = None) -> None:
        self.gammas = gammas
        self.C = C
        self.epsilon = epsilon
        self.tol = tol
        self.cache_size = cache_size
        self.max_iter = max_iter
        self.C_rows = C_rows
        self.C_rate = C_rate
        self.max_rows = max_rows

    def _gamma_vector(self, n_features: int) -> np.ndarray:
        if self.gammas is None:
            return np.full(n_features, 1.0 / n_features)
        g = np.asarray(self.gammas, dtype=np.float64).ravel()
        if g.size != n_features:
            raise ValueError(f"WDSESVR has {g.size} gammas but X has {n_features} features")
        return g


def wdse_gram(A: np.ndarray, B: np.ndarray, gammas: Sequence[float]) -> np.ndarray:
    """Explicit WDSE Gram matrix exp(-sum_i gamma_i (a_i - b_i)^2) (for tests and checks; O(n m d) memory)."""
    g = np.asarray(gammas, dtype=np.float64)
    diff = A[:, None, :] - B[None, :, :]
    return np.exp(-np.einsum("ijk,k->ij", diff * diff, g))


def _fit_output(est: BaseEstimator, X: np.ndarray, y: np.ndarray, k: int) -> BaseEstimator:
    """A clone of ``est`` fitted on output ``k`` of ``y`` (a task of :meth:`PerOutputRegressor.output_tasks`)."""
    y2 = y.reshape(-1, 1) if y.ndim == 1 else y
    return clone(est).fit(X, y2[:, k])


class PerOutputRegressor(RegressorMixin, BaseEstimator):
    """One single-output regressor per output column, each with its own hyperparameters.

    ``estimators`` is a list (one per output, in column order) of unfitted estimators; they are cloned at fit.
    Unlike :class:`sklearn.multioutput.MultiOutputRegressor`, which clones ONE estimator for every output.
    """

    def __init__(self, estimators: Sequence[BaseEstimator] = ()) -> None:
        self.estimators = estimators

    def fit(self, X, y):
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        y2 = y.reshape(-1, 1) if y.ndim == 1 else y
        if len(self.estimators) != y2.shape[1]:
            raise ValueError(f"{len(self.estimators)} estimators for {y2.shape[1]} outputs")
        self._y_1d = y.ndim == 1
        self.estimators_ = [clone(est).fit(X, y2[:, k]) for k, est in enumerate(self.estimators)]
        return self

    def output_tasks(self, X: np.ndarray, y: np.ndarray) -> list[tuple[Callable[..., Any], tuple[Any, ...]]]:
        """:meth:`fit`'s work as one task per output (:mod:`pipeline.rounds`), each returning that output's fitted
        estimator; :meth:`join` their results in order. ``X`` and ``y`` as :meth:`fit` takes them (float64, C
        order): each task fits the same column view :meth:`fit` would, so the bits are :meth:`fit`'s."""
        return [(_fit_output, (est, X, y, k)) for k, est in enumerate(self.estimators)]

    def join(self, X: np.ndarray, y: np.ndarray, fitted: Sequence[BaseEstimator]) -> PerOutputRegressor:
        """This regressor fitted from :meth:`output_tasks`' results (what :meth:`fit` would set)."""
        X, y = validate_data(self, X, y, multi_output=True, y_numeric=True, dtype=np.float64)
        if len(fitted) != len(self.estimators) or len(self.estimators) != (1 if y.ndim == 1 else y.shape[1]):
            raise ValueError(f"{len(fitted)} fitted of {len(self.estimators)} estimators for y {y.shape}")
        self._y_1d = y.ndim == 1
        self.estimators_ = list(fitted)
        return self

    def predict(self, X):
        check_is_fitted(self, "estimators_")
        X = validate_data(self, X, reset=False, dtype=np.float64)
        out = np.column_stack([est.predict(X) for est in self.estimators_])
        return out[:, 0] if self._y_1d else out

    def fast_predictor(self) -> Callable[[np.ndarray], np.ndarray] | None:
        """``predict`` of a fitted multi-output regressor of this module's scaled-RBF SVRs as numpy sums over the
        support vectors, without scikit-learn's per-call checks (a rollout calls it four times per step with a
        small batch); None for other estimators or a 1-D target.

        Per output: ``z = (x - mean) / scale * sqrt(gamma)`` (the estimator's own transform), ``y = sum_j a_j
        exp(-|z - s_j|^2) + b`` (libsvm's RBF with gamma = 1; ``a`` the dual coefficients, ``b`` the intercept),
        with ``-|z - s|^2 = 2 z.s - |s|^2 - |z|^2`` about the support vectors' centroid as one BLAS product per
        output, ``[2z, -1, -|z|^2] . [s, |s|^2, 1]``, instead of a ``(B, n_sv, n_features)`` difference array; the
        exponential and the dual sum then work in place on it (a temporary of its size would be allocated and
        faulted in again at every call). Equal to ``predict`` to float rounding.
        """
        parts = []
        for est in getattr(self, "estimators_", None) or []:
            terms = est.kernel_terms() if isinstance(est, _ScaledRBFSVR) else None
            if terms is None:
                return None
            mean, std, scale, centre, sv_c, sv_sq, coef, b = terms
            gain = scale / std  # z = x gain + shift
            support = np.vstack([sv_c.T, sv_sq, np.ones_like(sv_sq)])  # (n_features + 2, n_sv)
            parts.append((gain, -mean * gain - centre, support, coef, b))
        if not parts or getattr(self, "_y_1d", True):
            return None

        def predict(X: np.ndarray) -> np.ndarray:
            X = np.asarray(X, dtype=float)
            n, d = X.shape
            out = np.empty((n, len(parts)))
            query = np.empty((n, d + 2))
            query[:, d] = -1.0
            for k, (gain, shift, support, coef, b) in enumerate(parts):
                z = X * gain + shift
                np.multiply(z, 2.0, out=query[:, :d])
                query[:, d + 1] = -np.einsum("ij,ij->i", z, z)
                arg = query @ support  # -|z - s|^2 for every query and support vector
                np.exp(arg, out=arg)
                out[:, k] = arg @ coef + b
            return out

        return predict
