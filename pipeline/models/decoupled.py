"""Decoupled damping models d_i(nu_i) (paper 001): LS on [nu, nu|nu|], MLP, kernel ridge, SVR and GP.

Every model is a scikit-learn estimator. Two are written here and pass ``parametrize_with_checks``:

- :class:`LinearQuadraticDamping`: closed-form least squares on ``[x, x|x|]`` per input column (paper eq. 6-7),
  without an intercept as in the paper or, with ``fit_intercept``, with a constant and its SD (for heave: the net
  buoyancy that the damping target still holds).
- :class:`DampingGP`: GP regression with ``C * RBF + WhiteKernel`` on standardized inputs and targets, kernel
  hyperparameters by marginal likelihood, trained on at most ``max_samples`` points chosen evenly in the
  first input (equal-width bins, water-filled), because scikit-learn's GP is O(n^3) (see ``bench/gp.py``).
  Its linear algebra runs on one BLAS thread: at these sizes (n <= 2000) a second thread gains little, and on
  a loaded machine OpenBLAS's spinning threads made fits 15-30x slower (bench/gp.py).
  ``predict(X, return_std=True)`` returns the std of the *latent* function (the white noise excluded), which is
  the band that should cover the true damping; with ``include_noise=True`` the std of a new observed target:
  latent + learned white noise + the target's own SD (``fit(X, y, sample_sd=...)`` takes the smoother's SD of each
  target as a fixed part of its noise, so a 2-sigma band on the target is a prediction interval);
  :meth:`DampingGP.sample_functions` draws posterior functions.
  The damping target's errors are correlated in time (smoothed derivatives: lag-1 autocorrelation 0.5-0.9 at the
  study's row spacing), which a WhiteKernel treats as independent, so the band came out too narrow (2-sigma
  coverage of the simulator's truth 0.3-0.7). With ``decorrelate`` (default) the rows, taken to be in time
  order, are first thinned to the decorrelation lag of a pilot fit's residuals, and the latent variance is
  scaled by the integrated autocorrelation time left in the thinned residuals (n / n_eff, :func:`decorrelation`).

The other three are compositions of scikit-learn built-ins (:func:`make_estimator`), inputs standardized:
MLP (one hidden layer, tanh, lbfgs; targets standardized too), kernel ridge (RBF) and SVR (RBF). Their grids use
the paper's names (:data:`PAPER_GRIDS`); :func:`param_grid` maps them onto the composed estimators' keys.
"""

from __future__ import annotations

import logging
from typing import Any, Literal

import numpy as np
from scipy.linalg import cho_solve, cholesky, solve_triangular
from scipy.optimize import minimize
from sklearn.base import BaseEstimator, RegressorMixin
from sklearn.compose import TransformedTargetRegressor
from sklearn.kernel_ridge import KernelRidge
from sklearn.neural_network import MLPRegressor
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVR
from sklearn.utils.validation import check_is_fitted, validate_data
from threadpoolctl import threadpool_limits

log = logging.getLogger(__name__)

MODEL_NAMES = ("ls", "mlp", "krr", "svr", "gp")

#: The grids of paper 001, section IV, in the paper's names.
PAPER_GRIDS: dict[str, dict[str, list[Any]]] = {
    "svr": {"gamma": [1, 5, 10, 20, 30], "epsilon": [1e-3, 1e-2, 1e-1, 1e0, 1e1],
            "C": [1e0, 1e1, 1e2, 1e3, 1e4]},
    "krr": {"alpha": [1e-3, 1e-2, 1e-1, 1e0], "gamma": [1e-3, 1e-2, 1e-1, 1e0, 1e1, 1e2]},
    "mlp": {"nodes": [1, 5, 10, 20, 50], "alpha": [1e-3, 1e-2, 1e-1, 1e0]},
}

#: The default ("fast") grids: subsets of the paper grids around where the paper's optima fell (Table I).
FAST_GRIDS: dict[str, dict[str, list[Any]]] = {
    "svr": {"gamma": [1, 10, 30], "epsilon": [1e-2, 1e-1, 1e0], "C": [1e1, 1e3]},
    "krr": {"alpha": [1e-3, 1e-2, 1e-1], "gamma": [1e-1, 1e0, 1e1]},
    "mlp": {"nodes": [5, 20], "alpha": [1e-3, 1e-1]},
}

_KEYS = {
    "svr": {"gamma": "svr__gamma", "epsilon": "svr__epsilon", "C": "svr__C"},
    "krr": {"alpha": "krr__alpha", "gamma": "krr__gamma"},
    "mlp": {"nodes": "regressor__mlp__hidden_layer_sizes", "alpha": "regressor__mlp__alpha"},
}


def even_subsample(x: np.ndarray, max_samples: int, n_bins: int = 64) -> np.ndarray:
    """Indices (sorted) of at most ``max_samples`` rows chosen evenly over the range of ``x``.

    ``x`` is cut into ``n_bins`` equal-width bins; every bin keeps up to ``k`` samples, with ``k`` the largest
    cap such that the total stays within ``max_samples`` (water-filling), so sparse extremes are all kept and
    the dense middle is thinned. Within a bin the kept samples are evenly spaced in time order. Deterministic.
    """
    x = np.asarray(x, dtype=float).ravel()
    n = x.size
    if n <= max_samples:
        return np.arange(n)
    lo, hi = float(np.min(x)), float(np.max(x))
    if hi <= lo:
        return np.linspace(0, n - 1, max_samples).round().astype(int)
    bins = np.minimum(((x - lo) / (hi - lo) * n_bins).astype(int), n_bins - 1)
    members = [np.flatnonzero(bins == b) for b in range(n_bins)]
    counts = np.array([m.size for m in members])
    lo_cap, hi_cap = 0, int(counts.max())
    while lo_cap < hi_cap:  # largest cap k with sum(min(counts, k)) <= max_samples
        mid = (lo_cap + hi_cap + 1) // 2
        if np.minimum(counts, mid).sum() <= max_samples:
            lo_cap = mid
        else:
            hi_cap = mid - 1
    if lo_cap == 0:  # more occupied bins than samples: one sample (its middle one in time) from bins spread evenly
        occupied = [m for m in members if m.size]
        chosen = np.unique(np.linspace(0, len(occupied) - 1, max_samples).round().astype(int))
        return np.sort(np.array([occupied[i][occupied[i].size // 2] for i in chosen], dtype=np.int64))
    keep = []
    for m in members:
        if m.size <= lo_cap:
            keep.append(m)
        elif lo_cap > 0:
            keep.append(m[np.linspace(0, m.size - 1, lo_cap).round().astype(int)])
    return np.sort(np.concatenate(keep)) if keep else np.arange(0)


def autocorrelation(r: np.ndarray, max_lag: int) -> np.ndarray:
    """Sample autocorrelation of ``r`` at lags ``0 .. max_lag`` (biased estimator, ``rho[0] = 1``)."""
    r = np.asarray(r, dtype=float) - float(np.mean(r))
    var = float(r @ r)
    max_lag = min(max_lag, r.size - 1)
    if var <= 0 or max_lag < 1:
        return np.ones(1)
    return np.array([1.0] + [float(r[:-k] @ r[k:]) / var for k in range(1, max_lag + 1)])


def decorrelation(r: np.ndarray, threshold: float = 0.1, max_lag: int = 60) -> tuple[int, float]:
    """``(lag, tau)`` of a residual series in time order.

    ``lag``: the first lag whose autocorrelation is <= ``threshold`` (rows that far apart are treated as
    independent); ``tau``: the integrated autocorrelation time ``1 + 2 sum rho_k`` over the initial positive
    sequence (Geyer), i.e. ``n / n_eff``, at least 1.
    """
    rho = autocorrelation(r, max_lag)
    below = np.flatnonzero(rho[1:] <= threshold)
    lag = int(below[0]) + 1 if below.size else len(rho)
    positive = np.flatnonzero(rho[1:] <= 0)
    stop = int(positive[0]) + 1 if positive.size else len(rho)
    return lag, max(1.0, 1.0 + 2.0 * float(rho[1:stop].sum()))


class LinearQuadraticDamping(RegressorMixin, BaseEstimator):
    """Least squares on ``[x, x|x|]`` for each input column (paper eq. 6-7): ``d = d_l x + d_q x|x|`` (``+ c`` with
    ``fit_intercept``).

    ``coef_`` holds ``[d_l, d_q]`` per input column (shape ``(2 * n_features,)`` or ``(n_outputs, 2 * n)``);
    ``intercept_`` the constant ``c`` (0 without ``fit_intercept``) and ``intercept_sd_`` its SD (None where
    ``coef_cov_`` is None or without ``fit_intercept``).
    """

    def __init__(self, fit_intercept: bool = False) -> None:
        self.fit_intercept = fit_intercept

    def __sklearn_tags__(self) -> Any:
        tags = super().__sklearn_tags__()
        tags.target_tags.multi_output = True
        return tags

    def _design(self, X: np.ndarray) -> np.ndarray:
        cols = [X, X * np.abs(X)]
        if self.fit_intercept:
            cols.append(np.ones((X.shape[0], 1)))
        return np.hstack(cols)

    def fit(self, X: Any, y: Any) -> LinearQuadraticDamping:
        X, y = validate_data(self, X, y, y_numeric=True, multi_output=True)
        A = self._design(X)
        theta, *_ = np.linalg.lstsq(A, y, rcond=None)
        n = 2 * X.shape[1]
        self.coef_ = theta[:n].T
        self.intercept_ = theta[n] if self.fit_intercept else np.zeros(y.shape[1:]) if y.ndim > 1 else 0.0
        cov = self._covariance(A, y - A @ theta) if y.ndim == 1 else None
        self.coef_cov_ = None if cov is None else cov[:n, :n]
        self.intercept_sd_ = float(np.sqrt(cov[n, n])) if cov is not None and self.fit_intercept else None
        return self

    @staticmethod
    def _covariance(A: np.ndarray, resid: np.ndarray) -> np.ndarray | None:
        """Covariance of the parameters (``coef_``, then the intercept): s^2 (A'A)^-1, scaled by the residuals'
        integrated autocorrelation time (:func:`decorrelation`; the rows are taken in time order, and smoothed
        targets are correlated in time, which plain OLS errors would ignore and so come out too narrow). None where
        it is not defined."""
        dof = A.shape[0] - A.shape[1]
        gram = A.T @ A
        if dof < 1 or np.linalg.matrix_rank(gram) < A.shape[1]:
            return None
        _, tau = decorrelation(resid)
        return float(resid @ resid) / dof * tau * np.linalg.inv(gram)

    def coefficient_intervals(self, level: float = 0.95) -> np.ndarray | None:
        """``(2 * n_features, 2)``: the ``level`` confidence interval of each of ``coef_`` (normal approximation,
        from ``coef_cov_``), or None (a multi-output fit, too few rows, a model pickled before it was kept)."""
        from scipy.stats import norm

        check_is_fitted(self)
        cov = getattr(self, "coef_cov_", None)
        if cov is None:
            return None
        half = norm.ppf(0.5 + level / 2) * np.sqrt(np.diag(cov))
        coef = np.ravel(self.coef_)
        return np.column_stack([coef - half, coef + half])

    def predict(self, X: Any) -> np.ndarray:
        check_is_fitted(self)
        X = validate_data(self, X, reset=False)
        return self._design(X)[:, : 2 * X.shape[1]] @ self.coef_.T + self.intercept_


_BOUNDS = ((1e-3, 1e3), (1e-2, 1e3), (1e-8, 1e1))  # signal variance, length scales, noise variance
WARPS = ("none", "signed_square")


def _sq_distances(Za: np.ndarray, Zb: np.ndarray) -> np.ndarray:
    """Squared differences per feature: shape ``(n_features, len(Za), len(Zb))``."""
    return (Za.T[:, :, None] - Zb.T[:, None, :]) ** 2


def _neg_log_marginal_likelihood(theta: np.ndarray, d2: np.ndarray, y: np.ndarray, known: np.ndarray | None = None
                                  ) -> tuple[float, np.ndarray]:
    """-log p(y | theta) and its gradient for ``c exp(-sum_j d2_j / (2 l_j^2)) + s2 I + diag(known)``, ``theta =
    log [c, l_1 .. l_p, s2]`` (one length scale per feature, ``d2`` from :func:`_sq_distances`; ``known``: each
    row's own noise variance, fixed, or None).

    The analytic gradient of this one kernel; scikit-learn's generic kernel gradients cost ~10x more per
    evaluation (``bench/gp.py``)."""
    c, ls, s2 = np.exp(theta[0]), np.exp(theta[1:-1]), np.exp(theta[-1])
    scaled = d2 / ls[:, None, None] ** 2
    k_rbf = np.exp(-0.5 * scaled.sum(axis=0))
    K = c * k_rbf
    K[np.diag_indices_from(K)] += s2 if known is None else s2 + known
    try:
        L = cholesky(K, lower=True, check_finite=False)
    except np.linalg.LinAlgError:
        return 1e25, np.zeros(theta.size)
    alpha = cho_solve((L, True), y, check_finite=False)
    nll = 0.5 * float(y @ alpha) + float(np.log(np.diag(L)).sum()) + 0.5 * y.size * np.log(2 * np.pi)
    W = np.outer(alpha, alpha) - cho_solve((L, True), np.eye(y.size), check_finite=False)
    Wk = W * (c * k_rbf)
    grad = [Wk.sum(), *np.einsum("ij,kij->k", Wk, scaled), s2 * np.trace(W)]
    return nll, -0.5 * np.array(grad)


def _fit_hyperparameters(Z: np.ndarray, y: np.ndarray, length_scale: float, noise_level: float, n_restarts: int,
                         random_state: int, known: np.ndarray | None = None) -> np.ndarray:
    """``[c, l_1 .. l_p, s2]`` by maximum marginal likelihood (L-BFGS-B in log space, the bounds of :data:`_BOUNDS`),
    restarts included, as scikit-learn's ``GaussianProcessRegressor`` does for ``C * RBF + WhiteKernel`` (plus the
    rows' own noise variances ``known``, fixed)."""
    d2 = _sq_distances(Z, Z)
    p = Z.shape[1]
    bounds = np.log(np.array([_BOUNDS[0], *[_BOUNDS[1]] * p, _BOUNDS[2]]))
    starts = [np.log([1.0, *[length_scale] * p, noise_level])]
    rng = np.random.RandomState(random_state)
    starts += [rng.uniform(bounds[:, 0], bounds[:, 1]) for _ in range(n_restarts)]
    best = None
    for theta0 in starts:
        res = minimize(_neg_log_marginal_likelihood, np.clip(theta0, bounds[:, 0], bounds[:, 1]),
                       args=(d2, y, known), jac=True, method="L-BFGS-B", bounds=bounds)
        if best is None or res.fun < best.fun:
            best = res
    assert best is not None
    return np.exp(best.x)


def _check_sd(sample_sd: Any, n: int) -> np.ndarray | None:
    """``sample_sd`` as a finite, non-negative ``(n,)`` array (or None); a ValueError that says what is wrong."""
    if sample_sd is None:
        return None
    sd = np.asarray(sample_sd, dtype=float).ravel()
    if sd.shape != (n,):
        raise ValueError(f"sample_sd has {sd.size} values for {n} rows")
    if not np.all(np.isfinite(sd)) or np.any(sd < 0):
        raise ValueError(f"sample_sd must be finite and >= 0; {int(np.sum(~(np.isfinite(sd) & (sd >= 0))))} rows "
                         "are not")
    return sd


class DampingGP(RegressorMixin, BaseEstimator):
    """GP regression, ``C * RBF + WhiteKernel``, hyperparameters by marginal likelihood, on standardized data.

    ``warp="signed_square"`` (default): the kernel sees each input ``x`` as the pair ``(x, x|x|)`` (standardized,
    one length scale each), the regressors of the LS damping model (paper eq. 6). Damping that is linear plus
    quadratic plus a smooth remainder is then a smooth function of the GP's inputs. With ``"none"`` (the paper's
    kernel, one length scale on ``x``) an RBF cannot follow ``x|x|``, whose curvature changes sign at 0: on the
    simulator the fitted mean came out steeper than the truth around rest and its 2-sigma band missed the truth
    there on every seed (coverage 0.70-0.85 of the curve, against 0.84-0.97 warped; ``docs/models.md``).

    At most ``max_samples`` training points are used, chosen evenly in the first input column
    (:func:`even_subsample`). ``length_scale_`` (one per GP input, standardized units) and ``noise_std_`` (target
    units) are the learned hyperparameters; ``predict(X, return_std=True)`` gives the latent function's std (noise
    excluded), or with ``include_noise=True`` the std of a new observation. ``fit(..., sample_sd=sd)``: the
    noise of row i is ``noise_std_**2 + sd_i**2`` (``sd`` fixed, e.g. the smoother's SD of the damping target);
    ``target_sd_`` is the RMS of the training rows' ``sd`` (0 without), the own-SD term of a prediction whose
    ``sample_sd`` is not given.

    ``decorrelate``: rows are in time order and their errors correlated; a pilot fit's residuals give the
    decorrelation lag (:func:`decorrelation`, ``acf_threshold``), the rows are thinned to that stride (keeping at
    least ``min_samples``) before the even-in-velocity subsample, and the latent variance is multiplied by the
    integrated autocorrelation time of the final fit's residuals (``variance_factor_``). ``stride_`` is the
    stride used (1 without ``decorrelate``).
    """

    def __init__(self, length_scale: float = 1.0, noise_level: float = 0.1, max_samples: int = 2000,
                 n_bins: int = 64, n_restarts_optimizer: int = 0, random_state: int = 0, decorrelate: bool = True,
                 acf_threshold: float = 0.1, min_samples: int = 30, warp: str = "signed_square") -> None:
        self.decorrelate = decorrelate
        self.acf_threshold = acf_threshold
        self.min_samples = min_samples
        self.length_scale = length_scale
        self.noise_level = noise_level
        self.max_samples = max_samples
        self.n_bins = n_bins
        self.n_restarts_optimizer = n_restarts_optimizer
        self.random_state = random_state
        self.warp = warp

    def fit(self, X: Any, y: Any, sample_sd: Any = None) -> DampingGP:
        """Fit on ``X``, ``y`` in time order; ``sample_sd`` (optional, ``(n,)``, target units): each target's own
        SD (the smoother's ``d_std_*`` column), a fixed part of its noise beside the learned white noise."""
        if self.warp not in WARPS:
            raise ValueError(f"DampingGP warp {self.warp!r}: expected one of {WARPS}")
        with threadpool_limits(1, user_api="blas"):
            return self._fit(X, y, sample_sd)

    def _fit(self, X: Any, y: Any, sample_sd: Any) -> DampingGP:
        X, y = validate_data(self, X, y, y_numeric=True)
        sd = _check_sd(sample_sd, len(y))
        self.stride_, self.variance_factor_ = 1, 1.0
        if not self.decorrelate or len(y) < 2 * self.min_samples:
            return self._fit_rows(X, y, sd)
        self._fit_rows(X, y, sd)  # pilot: its residuals measure how far apart rows must be to be independent
        lag, _ = decorrelation(y - self.predict(X), self.acf_threshold)
        self.stride_ = max(1, min(lag, len(y) // self.min_samples))
        rows = slice(self.stride_ // 2, None, self.stride_)
        self._fit_rows(X[rows], y[rows], None if sd is None else sd[rows])
        _, self.variance_factor_ = decorrelation(y[rows] - self.predict(X[rows]), self.acf_threshold)
        return self

    def _inputs(self, X: np.ndarray) -> np.ndarray:
        """The kernel's inputs, standardized: ``x`` or ``(x, x|x|)`` per column (``warp``)."""
        F = X if self.warp == "none" else np.hstack([X, X * np.abs(X)])
        return (F - self.f_mean_) / self.f_scale_

    def _signal(self, Za: np.ndarray, Zb: np.ndarray) -> np.ndarray:
        """The latent (RBF) covariance between two sets of standardized kernel inputs."""
        ls = self.theta_[1:-1]
        return self.theta_[0] * np.exp(-0.5 * (_sq_distances(Za, Zb) / ls[:, None, None] ** 2).sum(axis=0))

    def _fit_rows(self, X: np.ndarray, y: np.ndarray, sd: np.ndarray | None) -> DampingGP:
        idx = even_subsample(X[:, 0], self.max_samples, self.n_bins)
        X, y = X[idx], y[idx]
        F = X if self.warp == "none" else np.hstack([X, X * np.abs(X)])
        self.f_mean_, self.f_scale_ = F.mean(axis=0), F.std(axis=0)
        self.f_scale_[self.f_scale_ == 0] = 1.0
        self.y_mean_, self.y_scale_ = float(y.mean()), float(y.std()) or 1.0
        Z, t = self._inputs(X), (y - self.y_mean_) / self.y_scale_
        known = None if sd is None else (sd[idx] / self.y_scale_) ** 2
        self.theta_ = _fit_hyperparameters(Z, t, self.length_scale, self.noise_level, self.n_restarts_optimizer,
                                           self.random_state, known)
        K = self._signal(Z, Z)
        K[np.diag_indices_from(K)] += self.theta_[-1] if known is None else self.theta_[-1] + known
        self.L_ = cholesky(K, lower=True, check_finite=False)
        self.alpha_ = cho_solve((self.L_, True), t, check_finite=False)
        self.Z_train_ = Z
        self.length_scale_ = self.theta_[1:-1].copy()
        self.noise_std_ = float(np.sqrt(self.theta_[-1])) * self.y_scale_
        self.target_sd_ = 0.0 if sd is None else float(np.sqrt(np.mean(sd[idx] ** 2)))
        self.n_train_ = int(len(idx))
        return self

    def _latent(self, X: Any, full_cov: bool) -> tuple[np.ndarray, np.ndarray]:
        with threadpool_limits(1, user_api="blas"):
            return self._latent_unlimited(X, full_cov)

    def _latent_unlimited(self, X: Any, full_cov: bool) -> tuple[np.ndarray, np.ndarray]:
        check_is_fitted(self)
        X = validate_data(self, X, reset=False)
        Z = self._inputs(X)
        k_trans = self._signal(Z, self.Z_train_)
        mean = k_trans @ self.alpha_
        v = solve_triangular(self.L_, k_trans.T, lower=True, check_finite=False)
        if full_cov:
            cov = self._signal(Z, Z) - v.T @ v
        else:
            cov = np.clip(self.theta_[0] - np.einsum("ij,ij->j", v, v), 0, None)
        return mean * self.y_scale_ + self.y_mean_, cov * self.y_scale_**2 * getattr(self, "variance_factor_", 1.0)

    def predict(self, X: Any, return_std: bool = False, include_noise: bool = False, sample_sd: Any = None) -> Any:
        """The mean; with ``return_std`` also the latent SD, or with ``include_noise`` the SD of a new observed
        target: latent + learned white noise + the target's own SD (``sample_sd`` per row where known, else the
        RMS of the training targets' SDs, ``target_sd_``)."""
        mean, var = self._latent(X, full_cov=False)
        if not return_std:
            return mean
        if include_noise:
            sd = _check_sd(sample_sd, len(mean))
            own = getattr(self, "target_sd_", 0.0) ** 2 if sd is None else sd**2
            var = var + self.noise_std_**2 + own
        return mean, np.sqrt(var)

    def sample_functions(self, X: Any, n_samples: int, random_state: int = 0) -> np.ndarray:
        """Posterior samples of the latent function at ``X``: shape ``(n_samples, len(X))``."""
        mean, cov = self._latent(X, full_cov=True)
        cov = 0.5 * (cov + cov.T) + 1e-10 * self.y_scale_**2 * np.eye(len(mean))
        with threadpool_limits(1, user_api="blas"):
            w, vecs = np.linalg.eigh(cov)
        root = vecs * np.sqrt(np.clip(w, 0, None))
        z = np.random.default_rng(random_state).standard_normal((n_samples, len(mean)))
        return mean + z @ root.T

    def kernel_description(self) -> str:
        """The fitted kernel on standardized inputs, e.g. ``0.8 * RBF([1.2, 3.4] on (x, x|x|)) + White(0.02)``."""
        ls = ", ".join(f"{v:.3g}" for v in self.theta_[1:-1])
        on = "x" if self.warp == "none" else "(x, x|x|)"
        return f"{self.theta_[0]:.3g} * RBF([{ls}] on {on}) + White({self.theta_[-1]:.3g})"


def make_estimator(name: str, seed: int = 0, gp_max_samples: int = 2000, gp_warp: str = "signed_square",
                   intercept: bool = False) -> BaseEstimator:
    """A fresh, unfitted estimator for one of :data:`MODEL_NAMES` (paper-default hyperparameters); ``intercept``:
    the ``ls`` model fits a constant too (the others learn any offset anyway)."""
    if name == "ls":
        return LinearQuadraticDamping(fit_intercept=intercept)
    if name == "mlp":
        mlp = MLPRegressor(hidden_layer_sizes=(5,), activation="tanh", solver="lbfgs", alpha=1e-3,
                           max_iter=500, random_state=seed)
        return TransformedTargetRegressor(regressor=Pipeline([("scale", StandardScaler()), ("mlp", mlp)]),
                                          transformer=StandardScaler())
    if name == "krr":
        return Pipeline([("scale", StandardScaler()), ("krr", KernelRidge(kernel="rbf", alpha=1e-2, gamma=1.0))])
    if name == "svr":
        return Pipeline([("scale", StandardScaler()), ("svr", SVR(kernel="rbf", gamma=10, epsilon=0.1, C=1e3,
                                                                  cache_size=500))])
    if name == "gp":
        return DampingGP(max_samples=gp_max_samples, random_state=seed, warp=gp_warp)
    raise ValueError(f"unknown decoupled model {name!r}; expected one of {MODEL_NAMES}")


def param_grid(name: str, search: Literal["paper_grid", "fast"] | dict[str, list[Any]] = "fast"
               ) -> dict[str, list[Any]]:
    """The search grid of ``name`` in the keys of :func:`make_estimator`'s estimator ({} for ls and gp).

    ``search`` is ``"paper_grid"``, ``"fast"`` or an explicit grid in the paper's names.
    """
    if name not in _KEYS:
        return {}
    grid = search if isinstance(search, dict) else (PAPER_GRIDS if search == "paper_grid" else FAST_GRIDS)[name]
    out = {}
    for key, values in grid.items():
        values = [(int(v),) for v in values] if key == "nodes" else list(values)
        out[_KEYS[name][key]] = values
    return out


def paper_names(name: str, best_params: dict[str, Any]) -> dict[str, Any]:
    """Translate a fitted search's ``best_params_`` back into the paper's names."""
    inverse = {v: k for k, v in _KEYS.get(name, {}).items()}
    out = {}
    for key, value in best_params.items():
        paper_key = inverse.get(key, key)
        out[paper_key] = value[0] if paper_key == "nodes" else value
    return out


def describe(name: str, estimator: BaseEstimator) -> dict[str, Any]:
    """The hyperparameters / learned constants worth reporting for a fitted model."""
    if name == "ls":
        out = {"d_l": float(np.ravel(estimator.coef_)[0]), "d_q": float(np.ravel(estimator.coef_)[1])}
        if estimator.fit_intercept:  # the constant and its SD (None where the covariance is not defined)
            out.update(intercept=float(np.ravel(estimator.intercept_)[0]),
                       intercept_sd=getattr(estimator, "intercept_sd_", None))
        return out
    if name == "gp":
        return {"length_scale": [float(v) for v in estimator.length_scale_], "noise_std": estimator.noise_std_,
                "target_sd": getattr(estimator, "target_sd_", 0.0),
                "n_train": estimator.n_train_, "kernel": estimator.kernel_description(), "warp": estimator.warp,
                "stride": getattr(estimator, "stride_", 1),
                "variance_factor": getattr(estimator, "variance_factor_", 1.0)}
    params = estimator.get_params()
    return paper_names(name, {k: params[k] for k in _KEYS.get(name, {}).values()})
