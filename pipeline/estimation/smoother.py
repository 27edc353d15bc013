"""A Kalman filter with Rauch–Tung–Striebel smoothing, per degree of freedom, solved as one banded system.

Model (per DOF, a white-jerk or "constant acceleration" process): the state at grid time t_k is
(x, x', x''); between grid steps (uniform, h) the jerk is white noise of spectral density ``q``. Measurements
come at their own stamps, anywhere between grid steps: one at t_k + delta sees
``x + delta x' + delta^2/2 x''`` of the state at t_k, with its own variance (the sensor's noise, plus the
jerk's contribution over delta, q delta^5/20); a measurement of the derivative (``order`` 1: an accelerometer's
acceleration for a velocity DOF) sees ``x' + delta x''``, with the jerk's contribution q delta^3/3. Several
measurements per step, or none, are both fine: lost
bottom lock is a stretch of steps without measurements, bridged with a variance that grows with the gap.

The RTS smoother's estimate is the posterior mean of all states given all measurements, which is the solution
of one symmetric positive definite block-tridiagonal system A z = b (A = the process model's precision plus
the measurements' information). It is solved by a banded Cholesky factorization (LAPACK via scipy: linear in
the number of steps, no Python loop per step), which also gives the marginal likelihood of the measurements
exactly, so the process noise ``q`` is chosen by maximum likelihood (Brent's method on log q) at the cost of a
few dozen factorizations. The smoothed variances (diagonal blocks of A^-1) come from an information filter
and RTS pass written so that nothing large cancels (:func:`smoothed_variances`), vectorized across DOFs.

Outliers are rejected by gating the smoother's residuals: a measurement whose residual exceeds ``gate`` robust
standard deviations is dropped and the problem solved again (twice at most).

Why not a library: pykalman and statsmodels' state space models run a recursion per measurement, with time
varying matrices for irregular stamps, far slower over a long trial's few dozen likelihood evaluations (figures:
``docs/benchmarks.md``), and neither gives the exact likelihood of measurements between grid steps without
adding every stamp as a step.

States are scaled, z = (x, h x', h^2 x''), so the matrices are well conditioned whatever the grid step.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.optimize import minimize_scalar

log = logging.getLogger(__name__)

__all__ = ["Measurements", "Smoothed", "logliks", "memory_s", "smooth", "smoothed_variances", "white_jerk"]

_PHI = np.array([[1.0, 1.0, 0.5], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])
_PHI_INV = np.array([[1.0, -1.0, 0.5], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0]])
_QT = np.array([[1 / 20, 1 / 8, 1 / 6], [1 / 8, 1 / 3, 1 / 2], [1 / 6, 1 / 2, 1.0]])
_QT_INV = np.linalg.inv(_QT)
_LOGDET_QT = float(np.linalg.slogdet(_QT)[1])
_PRIOR_PRECISION = 1e-10  # on the first state (scaled units): effectively diffuse


def process_covariance(q: float, s: float, h_s: float) -> np.ndarray:
    """One step's process-noise covariance in scaled states: the white jerk's q h^5 QT, plus a white acceleration
    of spectral density ``s`` (a random walk of x, s h)."""
    Q = q * h_s**5 * _QT
    Q[0, 0] += max(s, 0.0) * h_s
    return Q


def process_precision(q: float, s: float, h_s: float) -> tuple[np.ndarray, float]:
    """Precision and log-determinant of one step's process noise in scaled states: the white jerk's
    q h^5 QT, plus, with ``s`` > 0, a white acceleration of spectral density ``s`` (a random walk of x, s h).
    The second term is the error of a known input (:mod:`pipeline.estimation.forced`): fast, unsmooth, and
    integrated by the velocity like the input itself."""
    if s <= 0:
        return _QT_INV / (q * h_s**5), 3.0 * np.log(q * h_s**5) + _LOGDET_QT
    Q = process_covariance(q, s, h_s)
    return np.linalg.inv(Q), float(np.linalg.slogdet(Q)[1])


def white_jerk(h_s: float, q: float) -> tuple[np.ndarray, np.ndarray]:
    """Transition and process-noise covariance of (x, x', x'') over ``h_s`` for jerk spectral density ``q``."""
    phi = np.array([[1.0, h_s, h_s**2 / 2], [0.0, 1.0, h_s], [0.0, 0.0, 1.0]])
    S = np.diag([1.0, h_s, h_s**2])
    return phi, q * h_s**5 * np.linalg.inv(S) @ _QT @ np.linalg.inv(S)


@dataclass
class Measurements:
    """One DOF's measurements: stamps (int64 ns), values and variances (per sample); ``order`` (per sample, or
    one for all): 0 measures the DOF's value x, 1 its derivative x'."""

    t_ns: np.ndarray
    y: np.ndarray
    var: np.ndarray
    order: np.ndarray | int = 0

    def __post_init__(self) -> None:
        self.t_ns = np.asarray(self.t_ns, dtype=np.int64)
        self.y = np.asarray(self.y, dtype=float)
        self.var = np.broadcast_to(np.asarray(self.var, dtype=float), self.y.shape).copy()
        self.order = np.broadcast_to(np.asarray(self.order, dtype=np.int64), self.y.shape).copy()
        if not np.isin(self.order, (0, 1)).all():
            raise ValueError("a measurement's order is 0 (the value) or 1 (its derivative)")
        ok = np.isfinite(self.y) & np.isfinite(self.var) & (self.var > 0)
        if not ok.all():
            self.t_ns, self.y, self.var, self.order = self.t_ns[ok], self.y[ok], self.var[ok], self.order[ok]

    def subset(self, mask: np.ndarray) -> Measurements:
        """The measurements where ``mask`` is true (the ones a smoother result kept, say)."""
        return Measurements(self.t_ns[mask], self.y[mask], self.var[mask], self.order[mask])

    @classmethod
    def concat(cls, *parts: Measurements) -> Measurements:
        """Several sources of one DOF as one set (any order of stamps)."""
        return cls(np.concatenate([m.t_ns for m in parts]), np.concatenate([m.y for m in parts]),
                   np.concatenate([m.var for m in parts]), np.concatenate([m.order for m in parts]))


@dataclass
class Smoothed:
    """The smoother's output on the grid: x, x', x'' (and their SDs, filled by :func:`smoothed_variances`), the
    process noise used, the log-likelihood and which measurements the gate rejected."""

    x: np.ndarray
    xdot: np.ndarray
    q: float
    loglik: float
    used: int
    gated: int
    x_sd: np.ndarray | None = None
    xdot_sd: np.ndarray | None = None
    # kept for the variance recursion: measurement information per step (N, 3, 3) and the process precision
    info: np.ndarray | None = None
    h_s: float = 0.0
    xddot: np.ndarray | None = None
    xddot_sd: np.ndarray | None = None
    # which of the given measurements the likelihood counts (inside the grid, not gated), to score other models
    # of the same DOF on the same measurements
    kept: np.ndarray | None = None
    # the smoothed covariance of x and x' (filled by smoothed_variances), for SDs of functions of both
    x_xdot_cov: np.ndarray | None = None
    # the known input's error (white acceleration, spectral density; 0 without an input)
    s: float = 0.0
    # cov(x_k, x_{k+2}) (last two steps 0), for the SD of x's central difference
    x_lag2_cov: np.ndarray | None = None


class _Problem:
    """The fixed part of one DOF's system: which step each measurement belongs to, where in it, its variance."""

    def __init__(self, grid_ns: np.ndarray, meas: Measurements) -> None:
        self.n = int(grid_ns.size)
        self.t0 = int(grid_ns[0])
        step = np.diff(grid_ns)
        if self.n > 1 and step.min() != step.max():
            raise ValueError("the smoother's grid must be uniform")
        self.h_ns = int(step[0]) if self.n > 1 else 1
        self.h_s = self.h_ns / 1e9
        rel = meas.t_ns - self.t0
        inside = (rel >= 0) & (rel <= (self.n - 1) * self.h_ns)
        self.inside = inside
        rel = rel[inside]
        self.k = np.minimum(rel // self.h_ns, self.n - 1).astype(np.int64)
        self.delta = (rel - self.k * self.h_ns) / self.h_ns            # in steps, 0 <= delta < 1
        self.y = meas.y[inside]
        self.var0 = meas.var[inside]
        self.rate = meas.order[inside] == 1                             # measures x', not x
        # design rows in scaled states z = (x, h x', h^2 x''): x + delta x' + delta^2/2 x'' -> (1, delta,
        # delta^2/2); x' + delta x'' -> (0, 1, delta) / h
        value = np.stack([np.ones_like(self.delta), self.delta, 0.5 * self.delta**2], axis=1)
        rate = np.stack([np.zeros_like(self.delta), np.ones_like(self.delta), self.delta], axis=1) / self.h_s
        self.H = np.where(self.rate[:, None], rate, value)
        self.keep = np.ones(self.y.size, dtype=bool)
        self._pairs = [(a, c) for a in range(3) for c in range(a, 3)]
        self._HH = np.stack([self.H[:, a] * self.H[:, c] for a, c in self._pairs], axis=1)
        self._Hy = self.H * self.y[:, None]

    def variances(self, q: float, s: float = 0.0) -> np.ndarray:
        d = self.delta * self.h_s
        return self.var0 + np.where(self.rate, q * d**3 / 3.0 + s / self.h_s, q * d**5 / 20.0 + s * d)

    def information(self, q: float, s: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per step (N, 3, 3) information and (N, 3) vector of the kept measurements; their variances."""
        r = self.variances(q, s)
        w = np.where(self.keep, 1.0 / r, 0.0)
        info = np.zeros((self.n, 3, 3))
        vec = np.zeros((self.n, 3))
        for a in range(3):
            vec[:, a] = np.bincount(self.k, weights=w * self._Hy[:, a], minlength=self.n)
        for j, (a, c) in enumerate(self._pairs):
            info[:, a, c] = np.bincount(self.k, weights=w * self._HH[:, j], minlength=self.n)
            info[:, c, a] = info[:, a, c]
        return info, vec, r

    def prior_blocks(self, q: float, s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Diagonal blocks (N, 3, 3) and the constant sub-diagonal block of the process model's precision."""
        W = process_precision(q, s, self.h_s)[0]
        diag = np.zeros((self.n, 3, 3))
        diag[:-1] += _PHI.T @ W @ _PHI
        diag[1:] += W
        diag[0] += _PRIOR_PRECISION * np.eye(3)
        return diag, -W @ _PHI

    def _factor(self, info: np.ndarray, q: float, s: float) -> np.ndarray:
        """The banded Cholesky factor of A (the process model's precision plus the measurements' ``info``)."""
        diag, sub = self.prior_blocks(q, s)
        D = diag + info
        n3 = 3 * self.n
        ab = np.zeros((6, n3))
        for row in range(3):
            for col in range(row + 1):
                ab[row - col, col::3] = D[:, row, col]
        for row in range(3):
            for col in range(3):
                ab[3 + row - col, col: n3 - 3: 3] = sub[row, col]
        return cholesky_banded(ab, lower=True, check_finite=False)

    def solve(self, q: float, s: float = 0.0) -> tuple[np.ndarray, float, np.ndarray]:
        """Posterior mean z (N, 3), -2 log-likelihood (+ const), information blocks."""
        info, vec, r = self.information(q, s)
        z, m2ll = self._posterior(self._factor(info, q, s), vec, r, q, s, self.y)
        return z, m2ll, info

    def solve_many(self, q: float, s: float, ys: list[np.ndarray]) -> list[float]:
        """-2 log-likelihoods (+ const) of several value vectors at the same stamps, variances and kept set (the
        same measurements less different known inputs): one factorization, one banded solve each."""
        info, _, r = self.information(q, s)
        cb = self._factor(info, q, s)
        w = np.where(self.keep, 1.0 / r, 0.0)
        out = []
        for y in ys:
            vec = np.stack([np.bincount(self.k, weights=w * (self.H[:, a] * y), minlength=self.n)
                            for a in range(3)], axis=1)
            out.append(self._posterior(cb, vec, r, q, s, y)[1])
        return out

    def _posterior(self, cb: np.ndarray, vec: np.ndarray, r: np.ndarray, q: float, s: float, y: np.ndarray
                   ) -> tuple[np.ndarray, float]:
        z = cho_solve_banded((cb, True), vec.reshape(-1), check_finite=False)
        keep = self.keep
        zz = z.reshape(self.n, 3)
        logdet_A = 2.0 * float(np.sum(np.log(cb[0])))
        W, logdet_Q = process_precision(q, s, self.h_s)
        logdet_prior = -(self.n - 1) * logdet_Q + 3 * np.log(_PRIOR_PRECISION)
        # y'R^-1 y - b'A^-1 b, written as the posterior's residual and process terms (no cancellation of large
        # numbers when the signal is far larger than its noise)
        e = self.residuals(zz, y)
        w = zz[1:] - zz[:-1] @ _PHI.T
        quad = (float(np.sum(e[keep] ** 2 / r[keep])) + float(np.sum((w @ W) * w))
                + _PRIOR_PRECISION * float(zz[0] @ zz[0]))
        return zz, float(np.sum(np.log(r[keep]))) + quad + logdet_A - logdet_prior

    def residuals(self, z: np.ndarray, y: np.ndarray | None = None) -> np.ndarray:
        zk = z[self.k]
        fit = self.H[:, 0] * zk[:, 0] + self.H[:, 1] * zk[:, 1] + self.H[:, 2] * zk[:, 2]
        return (self.y if y is None else y) - fit


def _fit_q(problem: _Problem, q_bounds: tuple[float, float], s: float = 0.0) -> tuple[float, float]:
    """The maximum-likelihood q and its -2 log-likelihood (the optimizer's value there: no second solve)."""
    lo, hi = np.log10(q_bounds[0]), np.log10(q_bounds[1])

    def objective(lq: float) -> float:
        try:
            return problem.solve(10.0**lq, s)[1]
        except np.linalg.LinAlgError:
            return float("inf")

    res = minimize_scalar(objective, bounds=(lo, hi), method="bounded", options={"xatol": 0.05})
    if res.x - lo < 0.05 or hi - res.x < 0.05:
        log.info("smoother: maximum-likelihood process noise at the bound of [%g, %g]: q = %g",
                 q_bounds[0], q_bounds[1], 10.0**res.x)
    return float(10.0**res.x), float(res.fun)


def _fit_qs(problem: _Problem, q_bounds: tuple[float, float], s_bounds: tuple[float, float],
            rounds: int = 2) -> tuple[float, float]:
    """q and s by maximum likelihood, one coordinate at a time (each a Brent search on its log); s's lower
    bound stands for 0, kept when the input's error does not show."""
    (q, best), s = _fit_q(problem, q_bounds), 0.0
    lo, hi = np.log10(s_bounds[0]), np.log10(s_bounds[1])
    for _ in range(rounds):
        def objective(ls: float, q: float = q) -> float:
            try:
                return problem.solve(q, 10.0**ls)[1]
            except np.linalg.LinAlgError:
                return float("inf")

        res = minimize_scalar(objective, bounds=(lo, hi), method="bounded", options={"xatol": 0.05})
        if res.fun >= best - 1e-6:
            break
        s = float(10.0**res.x)
        q, best = _fit_q(problem, q_bounds, s)
    return q, s


def _median_interval(meas: Measurements) -> float:
    if meas.t_ns.size < 2:
        return 0.0
    step = np.diff(meas.t_ns)
    if step.min() < 0:  # several sources concatenated: sorting costs more than everything else here
        step = np.diff(np.sort(meas.t_ns))
    return float(np.median(step)) / 1e9


def _gate(problem: _Problem, z: np.ndarray, q: float, gate: float) -> bool:
    """Reject measurements whose residual exceeds ``gate`` robust SDs; True if the kept set changed."""
    e = problem.residuals(z) / np.sqrt(problem.variances(q))
    kept = e[problem.keep]
    scale = max(1.482602218505602 * float(np.median(np.abs(kept - np.median(kept)))), 1e-12)
    keep = np.abs(e) <= gate * max(scale, 1.0)
    if np.array_equal(keep, problem.keep):
        return False
    problem.keep = keep
    return True


def smooth(grid_ns: np.ndarray, meas: Measurements, *, q: float | None = None, gate: float = 5.0,
           q_bounds: tuple[float, float] = (1e-9, 1e3), gate_rounds: int = 2, ml_max_s: float = 300.0,
           ml_min_s: float = 60.0, ml_measurements: int = 5000, input_error: bool = False,
           s_bounds: tuple[float, float] = (1e-8, 1e2), s: float = 0.0) -> Smoothed:
    """Smoothed x and x' of one DOF on the uniform ``grid_ns`` from its measurements (see the module docstring).

    ``q``: the jerk's spectral density ((unit/s^3)^2 s); None: maximum likelihood within ``q_bounds`` times
    sigma^2 / h^5 (sigma: the measurements' median SD, h: the grid step), the range where the banded system
    stays well conditioned: from a process far smoother than the noise to one far rougher. The likelihood is
    maximized over the trial's middle stretch holding ``ml_measurements`` measurements (at least ``ml_min_s``,
    at most ``ml_max_s`` seconds; a longer stretch changes the estimate little and costs in proportion); the
    smoother then runs over the whole trial, gating its residuals once more.
    ``gate``: residuals beyond this many robust SDs (MAD of the normalized residuals) are rejected; 0: none.
    ``input_error``: the measurements had a known input taken out (:mod:`pipeline.estimation.forced`); fit, with
    q, the spectral density ``s`` of that input's error (within ``s_bounds`` times sigma^2 / h; the lower bound
    stands for none). ``s``: that spectral density when ``q`` is given.
    """
    grid_ns = np.asarray(grid_ns, dtype=np.int64)
    problem = _Problem(grid_ns, meas)
    if problem.y.size < 3:
        raise ValueError(f"the smoother needs at least 3 measurements within the grid, got {problem.y.size}")
    values = problem.var0[~problem.rate] if (~problem.rate).any() else problem.var0 * problem.h_s**2
    unit = float(np.median(values)) / problem.h_s**5
    q_bounds = (q_bounds[0] * unit, q_bounds[1] * unit)
    rounds = gate_rounds if gate > 0 else 0
    if q is None:
        ml = problem
        span_s = (grid_ns.size * problem.h_s) * ml_measurements / problem.y.size
        steps = int(np.clip(span_s, ml_min_s, ml_max_s) / problem.h_s)
        # q is a continuous-time quantity: for a sensor much slower than the grid (a DVL), the likelihood on a
        # grid of half its interval is the same to within the optimizer's tolerance, at a fraction of the cost
        interval = _median_interval(meas) or problem.h_s
        stride = int(np.clip(interval / (2 * problem.h_s), 1, 4))
        if grid_ns.size > steps or stride > 1:
            first = max((grid_ns.size - steps) // 2, 0)
            ml = _Problem(grid_ns[first: first + steps: stride], meas)
        s_fit = 0.0
        if input_error:
            s_unit = float(np.median(values)) / problem.h_s
            q_fit, s_fit = _fit_qs(ml, q_bounds, (s_bounds[0] * s_unit, s_bounds[1] * s_unit))
            if s_fit <= 1.5 * s_bounds[0] * s_unit:
                s_fit = 0.0
        else:
            q_fit = _fit_q(ml, q_bounds)[0]
        for _ in range(rounds):  # outliers inflate q: refit without them (when there are enough to matter)
            before = int(ml.keep.sum())
            if not _gate(ml, ml.solve(q_fit)[0], q_fit, gate) or before - int(ml.keep.sum()) < 0.001 * before:
                break
            q_fit = _fit_q(ml, q_bounds)[0]
    else:
        q_fit, s_fit = q, s
    z, m2ll, info = problem.solve(q_fit, s_fit)
    if rounds and _gate(problem, z, q_fit, gate):
        z, m2ll, info = problem.solve(q_fit, s_fit)
    h = problem.h_s
    kept = problem.inside.copy()
    kept[kept] = problem.keep
    return Smoothed(x=z[:, 0], xdot=z[:, 1] / h, q=q_fit, loglik=-0.5 * m2ll, used=int(problem.keep.sum()),
                    gated=int((~problem.keep).sum()), info=info, h_s=h, xddot=z[:, 2] / h**2, kept=kept, s=s_fit)


def logliks(grid_ns: np.ndarray, meas: Measurements, shifts: list[np.ndarray], *, q: float, s: float = 0.0
            ) -> np.ndarray:
    """Log-likelihoods of ``meas`` less each of ``shifts`` (per measurement: a known input at its stamp), with
    the process noises ``q`` and ``s`` given and no gate: what :func:`smooth` returns as ``loglik`` for each, from
    one factorization (a known input moves the mean, not the covariance), so a profile over inputs costs one
    banded solve per input."""
    problem = _Problem(np.asarray(grid_ns, dtype=np.int64), meas)
    if problem.y.size < 3:
        raise ValueError(f"the smoother needs at least 3 measurements within the grid, got {problem.y.size}")
    ys = [problem.y - np.asarray(shift, dtype=float)[problem.inside] for shift in shifts]
    return -0.5 * np.asarray(problem.solve_many(q, s, ys))


def smoothed_variances(results: list[Smoothed], *, burn_s: float = 2.0, burn_intervals: float = 40.0,
                       chunk_factor: float = 2.0, memory_burns: float = 12.0) -> None:
    """Fill ``x_sd``, ``xdot_sd`` and ``xddot_sd`` of smoother results on the same grid with the diagonal blocks
    of A^-1.

    Forward, an information filter: Y_k = Yp_k + J_k (J the measurements' information), and the prediction
    Yp_k+1 = (Phi Y_k^-1 Phi^T + Q)^-1 written as V (Phi + Q V)^-1 with V = Phi^-T Y_k, so Y is never inverted
    (a diffuse start is exact) and the process precision Q^-1, huge next to J for a smooth process, never enters.
    Backward, the RTS smoother Sigma_k = P_k + C_k (Sigma_k+1 - Pp_k+1) C_k^T, C_k = P_k Phi^T Yp_k+1, written
    with Phi P_k Phi^T Yp_k+1 = I - Q Yp_k+1 as C_k = Phi^-1 (I - Q Yp_k+1) and
    Sigma_k = (C_k Sigma_k+1 + Phi^-1 Q) C_k^T: a sum of positive terms, no difference of large covariances.
    Derivation and sources: docs/estimation.md, "The variances' recursion".

    To keep the number of Python-level steps small on long trials, the recursion runs for many chunks of the grid
    at once: each chunk is extended on both sides by a burn-in over which the effect of starting without
    information (forward) or of cutting the system (backward) dies out: ``burn_s`` seconds, ``burn_intervals``
    times the DOF's median interval between measurements, or ``memory_burns`` times the smoother's memory
    (:func:`memory_s`), whichever is longest, plus its longest stretch without measurements.
    DOFs with burn-ins within a factor of two (the DVL's axes, say) run together.
    Tests check the result against the single-chunk recursion and the textbook RTS smoother.
    """
    if not results:
        return
    h = results[0].h_s
    burns: dict[int, list[int]] = {}
    for j, res in enumerate(results):
        steps = np.flatnonzero(res.info[:, 0, 0] > 0)
        spacing = float(np.median(np.diff(steps))) if steps.size > 1 else float(res.x.size)
        longest = _longest_false_run(res.info[:, 0, 0] > 0)
        burn = int(np.ceil(max(burn_s / h, burn_intervals * spacing, memory_burns * memory_s(res) / h))) + longest
        burns.setdefault(burn, []).append(j)
    # a recursion's cost is its steps, nearly whatever its batch: DOFs whose burn-ins are within a factor of two
    # run together, with the longest of them
    groups: list[tuple[int, list[int]]] = []
    for burn, members in sorted(burns.items(), reverse=True):
        if groups and 2 * burn >= groups[-1][0]:
            groups[-1][1].extend(members)
        else:
            groups.append((burn, list(members)))
    for burn, members in reversed(groups):
        _variances([results[j] for j in sorted(members)], burn, chunk_factor)


def memory_s(res: Smoothed) -> float:
    """The smoother's memory, 1 / omega_c (seconds), omega_c = (q I)^(1/6) with I the information on x per second
    (the measurements' sum of 1 / variance over the trial's duration). The stationary smoother of a white-jerk
    process in white noise of density 1 / I is the Wiener filter 1 / (1 + (omega / omega_c)^6); a chunk's cold
    start is forgotten as exp(-omega_c t) in the variances (twice the decay rate, omega_c / 2, of its slowest
    pole). A known input's error (``s``) and rate measurements only shorten it. 0 without measurements of x."""
    rate = float(res.info[:, 0, 0].sum()) / (res.x.size * res.h_s)
    return float((res.q * rate) ** (-1 / 6)) if rate > 0 and res.q > 0 else 0.0


def _variances(results: list[Smoothed], burn: int, chunk_factor: float) -> None:
    n = results[0].x.size
    h = results[0].h_s
    dofs = len(results)
    Q = np.stack([process_covariance(res.q, res.s, h) for res in results])  # (dofs, 3, 3)
    J = np.stack([res.info for res in results], axis=1)                    # (n, dofs, 3, 3)
    burn = min(n, burn)
    core = max(int(chunk_factor * burn), 1)
    if n <= core + 2 * burn:
        starts = np.array([0])
        length = n
    else:
        chunks = int(np.ceil(n / core))
        length = core + 2 * burn
        starts = np.clip(np.arange(chunks) * core - burn, 0, n - length)
    idx = starts[:, None] + np.arange(length)[None, :]                     # (chunks, length)
    # struct of arrays: entry (i, j) of every chunk's and DOF's matrix as one contiguous (length, batch) array, so
    # each step is a few vectorized multiply-adds instead of per-matrix calls
    batch = len(starts) * dofs
    Jc = np.moveaxis(J[idx], 1, 0).reshape(length, batch, 3, 3)                               # (length, batch, 3, 3)
    Jc = np.ascontiguousarray(np.moveaxis(Jc, (2, 3), (0, 1)))                                # (3, 3, length, batch)
    Qb = np.ascontiguousarray(np.moveaxis(np.tile(Q, (len(starts), 1, 1)), (1, 2), (0, 1)))   # (3, 3, batch)
    piq = np.einsum("im,mjb->ijb", _PHI_INV, Qb)
    # forward: the predicted information Yp of each step, Yp' = V (Phi + Q V)^-1 with V = Phi^-T (Yp + J)
    yp = np.empty((3, 3, length, batch))
    yp[:, :, 0] = _PRIOR_PRECISION * np.eye(3)[:, :, None]
    for k in range(length - 1):
        v = np.einsum("mi,mjb->ijb", _PHI_INV, yp[:, :, k] + Jc[:, :, k], optimize=False)
        a = _PHI[:, :, None] + np.einsum("imb,mjb->ijb", Qb, v, optimize=False)
        yp[:, :, k + 1] = np.einsum("imb,mjb->ijb", v, _inv3_soa(a), optimize=False)
    # backward: C = Phi^-1 (I - Q Yp'), Sigma = (C Sigma' + Phi^-1 Q) C^T, cov(z_k, z_k+1) = C Sigma'; also the
    # (x, x') entry and cov(x_k, x_k+2) for the variance of a central difference of x
    var = np.empty((5, length, batch))
    var[4] = 0.0
    sigma = _inv3_soa(yp[:, :, -1] + Jc[:, :, -1])
    var[0, -1], var[1, -1], var[2, -1], var[3, -1] = sigma[0, 0], sigma[1, 1], sigma[2, 2], sigma[0, 1]
    cross = None  # column 0 of cov(z_k+1, z_k+2)
    for k in range(length - 2, -1, -1):
        c = _PHI_INV[:, :, None] - np.einsum("imb,mjb->ijb", piq, yp[:, :, k + 1], optimize=False)
        if cross is not None:
            var[4, k] = np.einsum("mb,mb->b", c[0], cross, optimize=False)
        cs = np.einsum("imb,mjb->ijb", c, sigma, optimize=False)
        cross = cs[:, 0]
        sigma = np.einsum("imb,jmb->ijb", cs + piq, c, optimize=False)
        var[0, k], var[1, k], var[2, k], var[3, k] = sigma[0, 0], sigma[1, 1], sigma[2, 2], sigma[0, 1]
    var = np.moveaxis(var.reshape(5, length, len(starts), dofs), (0, 1, 2), (3, 1, 0))  # (chunks, length, dofs, 5)
    out = np.empty((n, dofs, 5))
    # each step from the chunk whose window centre is nearest (its burn-in on both sides)
    centre = starts + length / 2.0
    owner = np.searchsorted((centre[1:] + centre[:-1]) / 2.0, np.arange(n), side="right")
    out[:] = var[owner, np.arange(n) - starts[owner]]
    out[..., :3] = np.maximum(out[..., :3], 0.0)
    for j, res in enumerate(results):
        res.x_sd = np.sqrt(out[:, j, 0])
        res.xdot_sd = np.sqrt(out[:, j, 1]) / h
        res.xddot_sd = np.sqrt(out[:, j, 2]) / h**2
        res.x_xdot_cov = out[:, j, 3] / h
        res.x_lag2_cov = out[:, j, 4]


def _inv3_soa(S: np.ndarray) -> np.ndarray:
    """Inverses of 3x3 matrices stored entry-first, ``S[i, j]`` an array over the batch (adjugate / determinant)."""
    a, b, c = S[0, 0], S[0, 1], S[0, 2]
    d, e, f = S[1, 0], S[1, 1], S[1, 2]
    g, h, i = S[2, 0], S[2, 1], S[2, 2]
    A, B, C = e * i - f * h, f * g - d * i, d * h - e * g
    inv_det = 1.0 / (a * A + b * B + c * C)
    return np.array([[A, c * h - b * i, b * f - c * e],
                     [B, a * i - c * g, c * d - a * f],
                     [C, b * g - a * h, a * e - b * d]]) * inv_det


def _longest_false_run(mask: np.ndarray) -> int:
    edges = np.diff(np.concatenate([[0], (~mask).astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return int((stops - starts).max()) if starts.size else 0
