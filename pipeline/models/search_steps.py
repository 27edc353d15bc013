"""The fast search's step rules on log-scale hyperparameter vectors, in rounds: expected-improvement proposals of
a GP fitted to the scores so far (:func:`model_steps`, :func:`propose`) and an adaptive coordinate pattern search
with an opportunistic batched poll, Hooke-Jeeves moves and random restarts (:func:`pattern_search`).

Both are generators (:mod:`pipeline.rounds`): ``evaluate(pairs)`` is the search's own generator that scores a
round of ``(vector, phase)`` candidates at once (its cache counts the budget) and returns their scores in order; a
GP's proposals are a task of their own (:func:`propose`). A round holds at most :data:`BATCH` candidates: the
number is fixed, not the number of workers, so the same candidates are tried whatever runs them. Neither function
fits an SVR itself."""

from __future__ import annotations

import time
import warnings
from collections.abc import Callable, Generator
from typing import Any

import numpy as np
from scipy.stats import norm, qmc
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import ConstantKernel, Matern, WhiteKernel

__all__ = ["BATCH", "model_steps", "pattern_search", "propose"]

#: candidates per round of the model steps and of the pattern search's poll
BATCH = 4

Evaluate = Callable[[list[tuple[np.ndarray, str]]], Generator[Any, Any, list[float]]]


def propose(V: np.ndarray, f: np.ndarray, x: np.ndarray, best: float, lo: np.ndarray, hi: np.ndarray, seed: int,
            round_: int, q: int) -> tuple[list[np.ndarray], float]:
    """``q`` candidates by expected improvement over ``best``: a GP (Matern 5/2, ARD) on the candidates scored so
    far (``V`` log scale, ``f`` their scores), maximized over Sobol points and perturbations of the best ``x``;
    after each pick the GP believes its own mean there (the kriging believer, Ginsbourger et al. 2010) and picks
    again. Returns the candidates and the CPU seconds it took (a task of its own)."""
    cpu0 = time.process_time()
    span = hi - lo
    rng = np.random.default_rng([seed + 1, round_])
    sobol = qmc.Sobol(x.size, scramble=True, seed=np.random.default_rng([seed + 2, round_]))
    V = (V - lo) / span
    f = np.maximum(f, np.quantile(f, 0.25) if len(f) > 4 else f.min())  # cap the failures' pull
    kernel = ConstantKernel(1.0, (1e-3, 1e3)) * Matern(np.full(x.size, 0.3), (1e-2, 1e1), nu=2.5) + \
        WhiteKernel(1e-4, (1e-8, 1e-1))
    gp = GaussianProcessRegressor(kernel, normalize_y=True, random_state=seed, n_restarts_optimizer=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        gp.fit(V, f)
    xb = (x - lo) / span
    cands = np.vstack([sobol.random(512), np.clip(xb + rng.normal(0.0, 0.05, size=(512, x.size)), 0, 1)])
    picks: list[np.ndarray] = []
    for j in range(q):
        mu, sd = gp.predict(cands, return_std=True)
        z = (mu - best) / np.maximum(sd, 1e-9)
        ei = (mu - best) * norm.cdf(z) + sd * norm.pdf(z)
        k = int(np.argmax(ei))
        picks.append(lo + cands[k] * span)
        if j + 1 < q:  # the believer: the pick's predicted mean as if scored, the kernel kept
            V, f = np.vstack([V, cands[k]]), np.append(f, mu[k])
            cands = np.delete(cands, k, axis=0)
            gp = GaussianProcessRegressor(gp.kernel_, normalize_y=True, optimizer=None).fit(V, f)
    return picks, time.process_time() - cpu0


def model_steps(evaluate: Evaluate, x: np.ndarray, best: float, lo: np.ndarray, hi: np.ndarray, max_evals: int,
                cache: dict[tuple[float, ...], float], seed: int, share: float = 0.6,
                cpu: list[float] | None = None) -> Generator[Any, Any, tuple[np.ndarray, float]]:
    """Model-based steps: ``share`` of the remaining budget, rounded to whole rounds of :data:`BATCH` candidates,
    each round proposed by :func:`propose` on everything scored so far. ``cpu`` (optional): the proposals' CPU is
    added to its first element."""
    n_steps = BATCH * int(round(share * max(0, max_evals - len(cache)) / BATCH))  # whole rounds only
    done = round_ = 0
    while done < n_steps and len(cache) < max_evals:
        q = min(BATCH, n_steps - done, max_evals - len(cache))
        V = np.array(list(cache.keys()))
        f = np.array(list(cache.values()))
        (cands, took), = yield [(propose, (V, f, x, best, lo, hi, seed, round_, q))]
        if cpu is not None:
            cpu[0] += took
        scores = yield from evaluate([(c, "model") for c in cands])
        for cand, score in zip(cands, scores, strict=True):
            if score > best:
                x, best = np.clip(cand, lo, hi), score
        done += q
        round_ += 1
    return x, best


def pattern_search(evaluate: Evaluate, x: np.ndarray, best: float, lo: np.ndarray, hi: np.ndarray,
                   rng: np.random.Generator, max_evals: int, cache: dict[tuple[float, ...], float],
                   initial_step: float, min_step: float, restarts: bool = True
                   ) -> Generator[Any, Any, tuple[np.ndarray, float, bool]]:
    """Adaptive coordinate pattern search (see :func:`pipeline.models.search.fast_search`) until ``max_evals``
    candidates are in ``cache``. Each poll lists, coordinate by coordinate, a step in the direction that last
    succeeded and one the other way, and scores them :data:`BATCH` at a time; the first round with a better
    candidate moves there (the best of the round; its coordinate's step doubles, and the next poll starts with
    the Hooke-Jeeves move along the displacement), a coordinate whose two steps both failed halves its step.
    When every step is below ``min_step``: with ``restarts``, a round of random log-scale perturbations of the
    best, then on; else stop. Returns the best point, its score and whether the steps converged."""
    steps = np.full(x.size, initial_step)
    direction = np.ones(x.size)
    converged = False
    move: np.ndarray | None = None  # the Hooke-Jeeves move the next poll starts with
    first_i = 0  # the coordinate the next poll starts from

    while len(cache) < max_evals:
        if np.all(steps < min_step):  # converged: restart around the best point with random perturbations
            converged = True
            if not restarts:
                break
            n_before = len(cache)
            cands = [np.clip(x + rng.normal(0.0, initial_step / 2, size=x.size), lo, hi)
                     for _ in range(min(BATCH, max_evals - len(cache)))]
            scores = yield from evaluate([(c, "restart") for c in cands])
            if len(cache) == n_before:
                break  # nothing new to try
            for cand, score in zip(cands, scores, strict=True):
                if score > best:
                    x, best = cand, score
            steps[:] = initial_step / 2
            continue
        poll: list[tuple[int, float, np.ndarray]] = [] if move is None else [(-1, 0.0, move)]
        for i in (np.arange(x.size) + first_i) % x.size:  # on from the coordinate after the last move
            if steps[i] < min_step:
                continue
            for sign in (direction[i], -direction[i]):
                cand = x.copy()
                cand[i] = np.clip(cand[i] + sign * steps[i], lo[i], hi[i])
                if cand[i] != x[i]:
                    poll.append((i, sign, cand))
        move, start, n_start = None, x.copy(), len(cache)
        if not poll:  # every active coordinate at its bounds both ways
            steps[steps >= min_step] /= 2.0
            continue
        moved, moved_i, tried = False, -1, 0  # tried: the poll's candidates scored
        for first in range(0, len(poll), BATCH):
            room = max_evals - len(cache)
            if room <= 0:
                break
            chunk = poll[first:first + min(BATCH, room)]
            scores = yield from evaluate([(c, "local") for _, _, c in chunk])
            tried = first + len(chunk)
            k_best = max(range(len(chunk)), key=lambda k: scores[k])  # the first of equal scores
            if scores[k_best] > best:
                moved_i, sign, x = chunk[k_best]
                best, moved = scores[k_best], True
                if moved_i >= 0:
                    direction[moved_i] = sign
                    steps[moved_i] = min(2.0 * steps[moved_i], 4.0 * initial_step)
                    first_i = (moved_i + 1) % x.size
                break
        halved = False
        for j in {j for j, _, _ in poll if j >= 0 and j != moved_i}:  # all its steps scored, none better
            if all(k < tried for k, (jj, _, _) in enumerate(poll) if jj == j):
                steps[j] /= 2.0
                halved = True
        if not (moved or halved) and len(cache) == n_start:  # the budget's last room held only candidates scored
            for j in {j for j, _, _ in poll[:tried] if j >= 0}:  # before: as failed, or the same poll comes back
                steps[j] /= 2.0
        if moved:
            shift = x - start
            if np.any(shift != 0):
                move = np.clip(x + shift, lo, hi)
    return x, best, converged or bool(np.all(steps < min_step))
