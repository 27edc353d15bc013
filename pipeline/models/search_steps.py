"""The fast search's step rules on log-scale hyperparameter vectors, given a scoring callback: expected-improvement
steps of a GP fitted to the scores so far (:func:`model_steps`) and an adaptive coordinate pattern search with
Hooke-Jeeves moves and random restarts (:func:`pattern_search`). ``evaluate(v, phase)`` scores a candidate (its
cache counts the budget); neither function fits an SVR itself."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from scipy.stats import norm, qmc
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

__all__ = ["model_steps", "pattern_search"]


def model_steps(evaluate: Any, x: np.ndarray, best: float, lo: np.ndarray, hi: np.ndarray, max_evals: int,
                cache: dict[tuple[float, ...], float], seed: int, share: float = 0.6) -> tuple[np.ndarray, float]:
    """Model-based steps: a GP (Matern 5/2, ARD) on the candidates scored so far (log scale, unit box) and the
    expected improvement over Sobol points and perturbations of the best; ``share`` of the remaining budget."""
    n_steps = int(share * max(0, max_evals - len(cache)))
    span = hi - lo
    rng = np.random.default_rng(seed + 1)
    sobol = qmc.Sobol(x.size, scramble=True, seed=seed + 2)
    for _ in range(n_steps):
        if len(cache) >= max_evals:
            break
        V = (np.array(list(cache.keys())) - lo) / span
        f = np.array(list(cache.values()))
        f = np.maximum(f, np.quantile(f, 0.25) if len(f) > 4 else f.min())  # cap the failures' pull
        kernel = ConstantKernel(1.0, (1e-3, 1e3)) * Matern(np.full(x.size, 0.3), (1e-2, 1e1), nu=2.5) + \
            WhiteKernel(1e-4, (1e-8, 1e-1))
        gp = GaussianProcessRegressor(kernel, normalize_y=True, random_state=seed, n_restarts_optimizer=1)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp.fit(V, f)
        xb = (x - lo) / span
        local_pts = np.clip(xb + rng.normal(0.0, 0.05, size=(512, x.size)), 0, 1)
        cands = np.vstack([sobol.random(512), local_pts])
        mu, sd = gp.predict(cands, return_std=True)
        z = (mu - best) / np.maximum(sd, 1e-9)
        ei = (mu - best) * norm.cdf(z) + sd * norm.pdf(z)
        cand = lo + cands[int(np.argmax(ei))] * span
        score = evaluate(cand, "model")
        if score > best:
            x, best = np.clip(cand, lo, hi), score
    return x, best


def pattern_search(evaluate: Any, x: np.ndarray, best: float, lo: np.ndarray, hi: np.ndarray,
                   rng: np.random.Generator, max_evals: int, cache: dict[tuple[float, ...], float],
                   initial_step: float, min_step: float, restarts: bool = True) -> tuple[np.ndarray, float, bool]:
    """Adaptive coordinate pattern search with Hooke-Jeeves moves and random restarts (see
    :func:`pipeline.models.search.fast_search`), until ``max_evals`` candidates are in ``cache``. Returns the best
    point, its score and whether the search converged (every step below ``min_step``) before the budget ran out;
    ``restarts=False`` stops there instead of perturbing the best point and going on."""
    steps = np.full(x.size, initial_step)
    direction = np.ones(x.size)
    converged = False

    def budget_left() -> bool:
        return len(cache) < max_evals

    while budget_left():
        if np.all(steps < min_step):  # converged: restart around the best point with a random perturbation
            converged = True
            if not restarts:
                break
            n_before = len(cache)
            for _ in range(20):
                cand = np.clip(x + rng.normal(0.0, initial_step / 2, size=x.size), lo, hi)
                score = evaluate(cand, "restart")
                if len(cache) > n_before:
                    break
            if len(cache) == n_before:
                break  # nothing new to try
            if score > best:
                x, best = cand, score
            steps[:] = initial_step / 2
            continue
        x_sweep = x.copy()
        for i in range(x.size):
            if steps[i] < min_step:
                continue
            moved = False
            for sign in (direction[i], -direction[i]):
                if not budget_left():
                    break
                cand = x.copy()
                cand[i] = np.clip(cand[i] + sign * steps[i], lo[i], hi[i])
                if cand[i] == x[i]:
                    continue
                score = evaluate(cand, "local")
                if score > best:
                    x, best, moved, direction[i] = cand, score, True, sign
                    while budget_left():  # extend the successful step while it keeps improving
                        further = x.copy()
                        further[i] = np.clip(x[i] + sign * steps[i], lo[i], hi[i])
                        if further[i] == x[i] or (s2 := evaluate(further, "local")) <= best:
                            break
                        x, best = further, s2
                    break
            steps[i] = min(2.0 * steps[i], 4.0 * initial_step) if moved else steps[i] / 2.0
        shift = x - x_sweep
        if np.any(shift != 0) and budget_left():  # Hooke-Jeeves: try the sweep's displacement once more
            cand = np.clip(x + shift, lo, hi)
            score = evaluate(cand, "local")
            if score > best:
                x, best = cand, score
    return x, best, converged or bool(np.all(steps < min_step))
