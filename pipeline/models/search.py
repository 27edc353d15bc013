"""Hyperparameter search for the SVR variants on the tuning block (unshuffled blocked CV, mean R²).

Two methods:

* ``"paper_grid"``: the paper's exhaustive grid, five candidates per hyperparameter (Table II style). For
  WDSE with 6 inputs + C + epsilon that is 5**8 = 390,625 candidates per fold; kept reproducible, not cheap.
* ``"fast"`` (default): gammas seeded from a Gaussian process's ARD length scales on a subsample
  (gamma_i = 1 / (2 l_i^2) on standardized inputs; anisotropic RBF + WhiteKernel), C and epsilon seeded from
  the target scale and the GP's noise level (Cherkassky & Ma 2004), plus the simpler kernel's optimum as a warm
  start; then a few scrambled-Sobol points within a decade of the GP seed (so the search never depends on the
  warm start alone), expected-improvement steps of a GP fitted to the CV scores so far (a model-based search),
  and an adaptive coordinate pattern search on log scale to finish (one step size per hyperparameter, doubled on
  success, halved on failure; Hooke-Jeeves moves), capped at ``max_evals`` candidates. A warm start
  that is still the best at the end is reported (``warm_start_kept``, ``note``) and logged.

The fast and local searches decide in rounds (:mod:`pipeline.rounds`): the GP seeds, the exploration, each batch of
expected-improvement proposals and each batch of the pattern search's poll are one round of independent tasks, one
per candidate and fold, all under the iteration cap of the round's start; ``fast_search`` / ``local_search`` run one
inline (or on ``n_jobs`` workers), the study's stages run all of theirs on one executor. The candidates tried do not
depend on where the tasks run.

Grids and seeds live on standardized inputs; C and epsilon are multiples of the target's SD (``y_scale``), so
the same grid fits surge, sway and yaw. ``n_fits`` counts SVR fits (candidates x folds); the GP fit of the
fast search is reported separately (``gp_fit_s``).
"""

from __future__ import annotations

import functools
import inspect
import itertools
import logging
import math
import time
import warnings
from collections.abc import Callable, Generator, Iterator
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from joblib import Parallel, delayed
from scipy.stats import qmc
from sklearn.base import clone
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from sklearn.metrics import r2_score

from pipeline.errors import ModelError
from pipeline.evaluate import search_folds
from pipeline.models.search_choice import kept_note, smoothest_within
from pipeline.models.search_cost import (
    ITER_CAP_RATIO,
    ITER_FLOOR_PER_ROW,
    ITER_PER_ROW,
    ITER_WARMUP_CANDIDATES,
    IterationCap,
    candidate_entry,
    cost_summary,
    iteration_cap,
    log_capped,
)
from pipeline.models.search_steps import model_steps, pattern_search
from pipeline.models.svr import RBFSVR, WDSESVR, TwoWeightsSVR
from pipeline.parallel import workers
from pipeline.rounds import drive

log = logging.getLogger(__name__)

Progress = Callable[..., Any]  # progress(done, total, desc): see stages.common
Rounds = Generator[Any, Any, "SearchResult"]  # a search as a coroutine of pipeline.rounds

__all__ = ["SVR_MODELS", "make_svr", "paper_grid", "grid_candidates", "cv_fold_scores", "cv_score", "grid_search",
           "fast_search", "fast_search_rounds", "local_search", "local_search_rounds", "search", "search_rounds",
           "with_C_rows", "SearchResult", "SearchSettings"]

SVR_MODELS = ("rbf_svr", "two_weights_svr", "wdse_svr")
GAMMA_GRID = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
C_GRID = (0.1, 1.0, 10.0, 100.0, 1000.0)  # x y_scale
EPSILON_GRID = (1e-3, 1e-2, 3e-2, 1e-1, 3e-1)  # x y_scale
GAMMA_BOUNDS = (1e-5, 1e2)
C_BOUNDS = (1e-2, 1e3)  # x y_scale (fast search)
EPSILON_BOUNDS = (1e-3, 0.5)  # x y_scale (fast search)
@dataclass
class SearchResult:
    model: str
    method: str
    best_params: dict[str, Any]
    best_score: float
    n_candidates: int
    n_fits: int
    n_folds: int
    elapsed_s: float
    gp_fit_s: float = 0.0
    trace: list[dict[str, Any]] = field(default_factory=list)
    warm_start_score: float | None = None  # fast search with a warm start: its tuning score
    warm_start_kept: bool = False  # fast search: the warm start was still the best at the end
    note: str = ""  # why (when warm_start_kept)
    budget_exhausted: bool = False  # the budget ran out before the local steps converged (all below min_step)
    n_rows: int = 0  # the rows the search scored its candidates on (its folds' training and test rows)
    cost: dict[str, Any] = field(default_factory=dict)  # CPU, the iteration cap and the slowest candidates
    halving: dict[str, Any] = field(default_factory=dict)  # successive halving: each rung's rows (search_halving)
    folds: str = "blocked"  # "blocked" (contiguous blocks of the rows) or "trials" (whole trials held out)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class SearchSettings:
    """The settings of a search, passed whole: its method and the keywords of :func:`search` that method uses
    (:meth:`keywords`); the fast search's own keys are left out of a ``paper_grid`` search's."""

    method: str = "fast"  # "fast" or "paper_grid"
    n_folds: int = 3
    n_jobs: int | None = 1
    n_velocity: int = 3
    iter_per_row: float | None = ITER_PER_ROW  # libsvm's iterations per candidate fit / training row (None: no cap)
    iter_cap_ratio: float | None = ITER_CAP_RATIO  # fast and local: x the median fit's iterations (None: no cap)
    max_evals: int = 30  # fast search only, as the three below
    seed: int = 0
    smooth_tolerance: float = 0.0
    one_se: bool = False
    screen_rows: int | None = None  # successive halving (search_halving.search): rows and folds of the screen
    screen_folds: int | None = None  # (None: all), survivors, C's rate
    survivors: int = 6
    c_rate: float = 0.5

    def keywords(self) -> dict[str, Any]:
        """The keywords of :func:`search` for this method."""
        kw: dict[str, Any] = {"n_folds": self.n_folds, "n_jobs": self.n_jobs, "n_velocity": self.n_velocity,
                              "iter_per_row": self.iter_per_row}
        if self.method == "fast":
            kw.update(max_evals=self.max_evals, seed=self.seed, smooth_tolerance=self.smooth_tolerance,
                      one_se=self.one_se, iter_cap_ratio=self.iter_cap_ratio)
            if self.screen_rows is not None or self.screen_folds is not None:
                kw.update(screen_rows=self.screen_rows, screen_folds=self.screen_folds, survivors=self.survivors,
                          c_rate=self.c_rate)
        return kw


def make_svr(model: str, params: dict[str, Any], n_velocity: int = 3, C_rate: float = 0.5,
             max_iter: int | None = None, max_rows: int | None = None) -> Any:
    """An unfitted SVR variant from a flat hyperparameter dict (as stored in the tuning JSON). Its ``C_rows``
    (written by :func:`search`; absent in older files: C kept) and ``C_rate`` scale C to the rows it is fitted on
    (:func:`pipeline.models.svr.scaled_C`). ``max_iter``: libsvm's iteration cap (None: none, libsvm's -1).
    ``max_rows``: fitted on at most this many rows, evenly spaced (None: all)."""
    scale = {"C_rows": params.get("C_rows"), "C_rate": C_rate, "max_iter": -1 if max_iter is None else int(max_iter),
             "max_rows": max_rows}
    if model == "rbf_svr":
        return RBFSVR(gamma=params["gamma"], C=params["C"], epsilon=params["epsilon"], **scale)
    if model == "two_weights_svr":
        return TwoWeightsSVR(gamma_velocity=params["gamma_velocity"], gamma_actuator=params["gamma_actuator"],
                             C=params["C"], epsilon=params["epsilon"], n_velocity=n_velocity, **scale)
    if model == "wdse_svr":
        return WDSESVR(gammas=list(params["gammas"]), C=params["C"], epsilon=params["epsilon"], **scale)
    raise ModelError(f"unknown SVR model {model!r}; expected one of {list(SVR_MODELS)}")


# -- parameter vectors (log scale) ---------------------------------------------------------------------

def _names(model: str, n_features: int) -> list[str]:
    if model == "rbf_svr":
        return ["gamma", "C", "epsilon"]
    if model == "two_weights_svr":
        return ["gamma_velocity", "gamma_actuator", "C", "epsilon"]
    if model == "wdse_svr":
        return [f"gamma_{i}" for i in range(n_features)] + ["C", "epsilon"]
    raise ModelError(f"unknown SVR model {model!r}; expected one of {list(SVR_MODELS)}")


def _to_params(model: str, names: list[str], values: np.ndarray | tuple[float, ...]) -> dict[str, Any]:
    flat = {n: float(v) for n, v in zip(names, values, strict=True)}
    if model != "wdse_svr":
        return flat
    return {"gammas": [flat[n] for n in names if n.startswith("gamma_")], "C": flat["C"], "epsilon": flat["epsilon"]}


def paper_grid(model: str, n_features: int, y_scale: float = 1.0) -> dict[str, list[float]]:
    """Five candidates per hyperparameter (gammas on standardized inputs; C, epsilon relative to y's SD)."""
    grid: dict[str, list[float]] = {}
    for name in _names(model, n_features):
        if name.startswith("gamma"):
            grid[name] = list(GAMMA_GRID)
        elif name == "C":
            grid[name] = [c * y_scale for c in C_GRID]
        else:
            grid[name] = [e * y_scale for e in EPSILON_GRID]
    return grid


def grid_candidates(model: str, grid: dict[str, list[float]]) -> Iterator[dict[str, Any]]:
    """Every combination of the grid (lazily, in a fixed order)."""
    names = list(grid)
    for values in itertools.product(*(grid[n] for n in names)):
        yield _to_params(model, names, values)


# -- scoring ------------------------------------------------------------------------------------------

def _fold_fit(est: Any, X: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray
              ) -> tuple[float, float, int]:
    """One candidate on one fold: its test R², the fit's CPU seconds (of the process that ran it) and libsvm's
    iterations. A fit stopped by ``max_iter`` is scored as it is (see :func:`fast_search`); libsvm's warning
    about it is the search's to report, once per search, not once per fit."""
    t0 = time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        fitted = clone(est).fit(X[train], y[train])
    r2 = float(r2_score(y[test], fitted.predict(X[test])))
    return r2, time.process_time() - t0, int(getattr(fitted, "n_iter_", 0))


def cv_fold_scores(model: str, params: dict[str, Any], X: np.ndarray, y: np.ndarray,
                   folds: list[tuple[np.ndarray, np.ndarray]], n_jobs: int | None = 1, n_velocity: int = 3,
                   max_iter: int | None = None) -> list[float]:
    """Test R² of one candidate on each of the given (blocked) folds."""
    return [r2 for r2, _, _ in _cv_fits(model, params, X, y, folds, n_jobs, n_velocity, max_iter)]


def _cv_fits(model: str, params: dict[str, Any], X: np.ndarray, y: np.ndarray,
             folds: list[tuple[np.ndarray, np.ndarray]], n_jobs: int | None, n_velocity: int,
             max_iter: int | None) -> list[tuple[float, float, int]]:
    """:func:`_fold_fit` of one candidate on each fold: (test R², CPU seconds, libsvm iterations)."""
    est = make_svr(model, params, n_velocity, max_iter=max_iter)
    if n_jobs == 1:
        return [_fold_fit(est, X, y, tr, te) for tr, te in folds]
    return list(Parallel(n_jobs=n_jobs)(delayed(_fold_fit)(est, X, y, tr, te) for tr, te in folds))


def _cap(iter_per_row: float | None, ratio: float | None, folds: list[tuple[np.ndarray, np.ndarray]],
         scored_folds: int | None = None) -> IterationCap:
    """A search's :class:`~pipeline.models.search_cost.IterationCap` on these folds' training rows; with
    ``scored_folds`` (the folds each candidate fits), relative once ITER_WARMUP_CANDIDATES candidates are scored."""
    rows = float(np.mean([len(tr) for tr, _ in folds]))
    warmup = 1 if scored_folds is None else ITER_WARMUP_CANDIDATES * scored_folds
    return IterationCap(iteration_cap(iter_per_row, folds), ratio, floor=int(round(ITER_FLOOR_PER_ROW * rows)),
                        warmup=warmup)


def cv_score(model: str, params: dict[str, Any], X: np.ndarray, y: np.ndarray,
             folds: list[tuple[np.ndarray, np.ndarray]], n_jobs: int | None = 1, n_velocity: int = 3,
             max_iter: int | None = None) -> float:
    """Mean test R² of one candidate over the given (blocked) folds."""
    return float(np.mean(cv_fold_scores(model, params, X, y, folds, n_jobs, n_velocity, max_iter)))


def _check_xy(X: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float).ravel()
    if X.ndim != 2 or len(X) != len(y):
        raise ModelError(f"search needs X (n, d) and y (n,), got {X.shape} and {y.shape}")
    if not (np.all(np.isfinite(X)) and np.all(np.isfinite(y))):
        raise ModelError("search input contains NaN or inf")
    return X, y


def grid_search(model: str, X: np.ndarray, y: np.ndarray, *, grid: dict[str, list[float]] | None = None,
                n_folds: int = 3, n_jobs: int | None = 1, n_velocity: int = 3,
                iter_per_row: float | None = ITER_PER_ROW, keep_trace: bool = False,
                progress: Progress | None = None, groups: np.ndarray | None = None) -> SearchResult:
    """Exhaustive search (the paper's protocol). Candidates run in parallel through joblib; ``progress(done,
    total, desc)`` (optional) is called as their scores arrive, in candidate order. ``groups``: each row's trial,
    for folds that hold out whole trials (:func:`pipeline.evaluate.search_folds`; None: blocked folds)."""
    X, y = _check_xy(X, y)
    grid = grid or paper_grid(model, X.shape[1], float(np.std(y)))
    folds = search_folds(len(X), n_folds, groups)
    n_folds = len(folds)
    max_iter = iteration_cap(iter_per_row, folds)  # the absolute cap only: a grid's candidates run at once
    t0 = time.perf_counter()
    candidates = list(grid_candidates(model, grid))
    log.info("grid search %s: %d candidates x %d folds", model, len(candidates), n_folds)
    jobs = (delayed(_cv_fits)(model, c, X, y, folds, 1, n_velocity, max_iter) for c in candidates)
    entries: list[dict[str, Any]] = []
    if progress is None:
        fits = Parallel(n_jobs=n_jobs, batch_size="auto")(jobs)
        entries = [candidate_entry(c, f, max_iter) for c, f in zip(candidates, fits, strict=True)]
    else:  # the same work, its results taken as they come (in order) to move the bar
        for f in Parallel(n_jobs=n_jobs, batch_size="auto", return_as="generator")(jobs):
            entries.append(candidate_entry(candidates[len(entries)], f, max_iter))
            progress(len(entries), len(candidates), f"{model} grid")
    scores = [e["score"] for e in entries]
    best = int(np.argmax(scores))
    result = SearchResult(model, "paper_grid", candidates[best], float(scores[best]), len(candidates),
                          len(candidates) * n_folds, n_folds, time.perf_counter() - t0,
                          trace=entries if keep_trace else [], cost=cost_summary(entries, max_iter), n_rows=len(X),
                          folds="blocked" if groups is None else "trials")
    log_capped(model, result.n_candidates, result.cost)
    return result


def _gp_seed(model: str, X: np.ndarray, y: np.ndarray, n_velocity: int, gp_samples: int, seed: int
             ) -> tuple[list[np.ndarray], float]:
    """Log-scale seed vectors from GP ARD length scales (and their isotropic mean), and the GP fit time."""
    t0 = time.perf_counter()
    idx = np.unique(np.linspace(0, len(X) - 1, min(gp_samples, len(X))).round().astype(int))
    Xs = (X[idx] - X.mean(0)) / np.where(X.std(0) > 0, X.std(0), 1.0)
    y_sd = float(np.std(y)) or 1.0
    ys = (y[idx] - y.mean()) / y_sd
    d = X.shape[1]

    def fit_gp(length_scale: float | np.ndarray) -> tuple[np.ndarray, float]:
        kernel = (ConstantKernel(1.0, (1e-2, 1e2)) * RBF(length_scale, (1e-2, 1e3))
                  + WhiteKernel(0.05, (1e-6, 1.0)))
        gp = GaussianProcessRegressor(kernel, normalize_y=False, random_state=seed, n_restarts_optimizer=0)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)
            gp.fit(Xs, ys)
        return (np.atleast_1d(gp.kernel_.k1.k2.length_scale).astype(float),
                math.sqrt(gp.kernel_.k2.noise_level) * y_sd)

    # isotropic first (robust), then ARD started from the isotropic length scale
    ls_iso, noise_sd = fit_gp(math.sqrt(d))
    gam_iso = float(np.clip(1.0 / (2.0 * ls_iso[0] ** 2), *GAMMA_BOUNDS))
    gam_seeds: list[list[float]] = [[gam_iso]]
    if model != "rbf_svr":
        ls, noise_sd = fit_gp(np.full(d, ls_iso[0]))
        gam = np.clip(1.0 / (2.0 * ls**2), *GAMMA_BOUNDS)
        if model == "two_weights_svr":
            k = min(n_velocity, d)
            ard = [float(np.exp(np.mean(np.log(gam[:k])))), float(np.exp(np.mean(np.log(gam[k:])))) if k < d else 1.0]
        else:
            ard = gam.tolist()
        gam_seeds = [ard, [gam_iso] * len(ard)]
    n = len(X)
    C = max(abs(y.mean() + 3 * y_sd), abs(y.mean() - 3 * y_sd))  # Cherkassky & Ma (2004)
    eps = max(3.0 * noise_sd * math.sqrt(math.log(n) / n), EPSILON_BOUNDS[0] * y_sd)
    log.debug("GP seeds %s: gammas %s, noise sd %.3g", model, gam_seeds, noise_sd)
    seeds = [np.log(np.array([*g, C, eps], dtype=float)) for g in gam_seeds]
    return seeds, time.perf_counter() - t0


def _expand(model: str, params: dict[str, Any], n_features: int, n_velocity: int) -> np.ndarray:
    """A simpler variant's hyperparameters as a parameter vector of ``model``."""
    if "gammas" in params:
        gam = list(params["gammas"])
    elif "gamma_velocity" in params:
        k = min(n_velocity, n_features)
        gam = [params["gamma_velocity"]] * k + [params["gamma_actuator"]] * (n_features - k)
    else:
        gam = [params["gamma"]] * n_features
    if model == "rbf_svr":
        gam = [float(np.exp(np.mean(np.log(gam))))]
    elif model == "two_weights_svr":
        k = min(n_velocity, n_features)
        gam = [float(np.exp(np.mean(np.log(gam[:k])))), float(np.exp(np.mean(np.log(gam[k:])))) if k < n_features
               else 1.0]
    return np.array([*gam, params["C"], params["epsilon"]], dtype=float)


def _log_bounds(n_gammas: int, y_sd: float) -> tuple[np.ndarray, np.ndarray]:
    y_sd = y_sd or 1.0
    lo = [GAMMA_BOUNDS[0]] * n_gammas + [C_BOUNDS[0] * y_sd, EPSILON_BOUNDS[0] * y_sd]
    hi = [GAMMA_BOUNDS[1]] * n_gammas + [C_BOUNDS[1] * y_sd, EPSILON_BOUNDS[1] * y_sd]
    return np.log(lo), np.log(hi)


def _evaluator(model: str, names: list[str], X: np.ndarray, y: np.ndarray, folds: list[tuple[np.ndarray, np.ndarray]],
               n_velocity: int, cap: IterationCap, bounds: tuple[np.ndarray, np.ndarray],
               cache: dict[tuple[float, ...], float], trace: list[dict[str, Any]], *, fold_r2: bool = False,
               from_key: bool = False, progress: Progress | None = None, budget: int = 0) -> Any:
    """A search's ``evaluate(pairs)``: a generator that scores a round of ``(log-scale vector, phase)``
    candidates (clipped to ``bounds``; those already in ``cache`` are not fitted again) with one task per
    candidate and fold (:func:`fit_task`), all under the iteration cap of the round's start, and returns their
    scores in order. Each new candidate goes to ``trace`` (with its ``round``, and its folds' R² when
    ``fold_r2``) and ``cache``, in the order asked.
    ``from_key``: the candidate's hyperparameters from its rounded key (the local search's), not the vector."""
    lo, hi = bounds
    rounds = [0]  # the rounds that fitted something: each new candidate's ``round`` in the trace

    def evaluate(pairs: list[tuple[np.ndarray, str]]) -> Any:
        keys, new = [], {}
        for v, phase in pairs:
            v = np.clip(v, lo, hi)
            key = tuple(np.round(v, 6))
            keys.append(key)
            if key not in cache and key not in new:
                new[key] = (_to_params(model, names, np.exp(np.array(key) if from_key else v)), phase)
        if new:
            max_iter = cap()
            fits = yield [fit_task(model, params, X, y, fold, n_velocity, max_iter)
                          for params, _ in new.values() for fold in folds]
            for j, (key, (params, phase)) in enumerate(new.items()):
                mine = fits[j * len(folds):(j + 1) * len(folds)]
                cap.record(mine)
                entry = candidate_entry(params, mine, max_iter, phase=phase, round=rounds[0])
                if fold_r2:
                    entry["fold_r2"] = [r2 for r2, _, _ in mine]
                cache[key] = entry["score"]
                trace.append(entry)
                if progress is not None:
                    progress(min(len(cache), budget), budget, f"{model} {phase}")
            rounds[0] += 1
        return [cache[k] for k in keys]

    return evaluate


def fit_task(model: str, params: dict[str, Any], X: np.ndarray, y: np.ndarray,
             fold: tuple[np.ndarray, np.ndarray], n_velocity: int, max_iter: int | None) -> tuple[Any, tuple[Any, ...]]:
    """One candidate's fit on one fold as a task of :mod:`pipeline.rounds`: ``(_fold_fit, its arguments)``."""
    return _fold_fit, (make_svr(model, params, n_velocity, max_iter=max_iter), X, y, *fold)


def _driven(rounds: Callable[..., Rounds]) -> Callable[..., SearchResult]:
    """``rounds`` run to its end (:func:`pipeline.rounds.drive`): inline, or its tasks on ``n_jobs`` workers."""

    @functools.wraps(rounds)
    def run(*args: Any, **kw: Any) -> SearchResult:
        n_jobs = kw.get("n_jobs", 1)
        jobs = 1 if n_jobs in (None, 1) else workers(n_jobs)
        return drive([rounds(*args, **kw)], jobs=jobs)[0]

    run.__doc__ = f"{rounds.__name__} run to its end: inline, or its tasks on ``n_jobs`` workers.\n\n{rounds.__doc__}"
    return run


def fast_search_rounds(model: str, X: np.ndarray, y: np.ndarray, *, n_folds: int = 3, n_jobs: int | None = 1,
                n_velocity: int = 3, max_evals: int = 30, gp_samples: int = 150, seed: int = 0,
                initial_step: float = math.log(4.0), min_step: float = math.log(1.25),
                warm_start: dict[str, Any] | None = None, max_fits: int | None = None,
                iter_per_row: float | None = ITER_PER_ROW, iter_cap_ratio: float | None = ITER_CAP_RATIO,
                smooth_tolerance: float = 0.0, one_se: bool = False, n_explore: int | None = None,
                local: str = "model", model_share: float = 0.6, progress: Progress | None = None,
                report_kept: bool = True, fold_subset: list[int] | None = None,
                groups: np.ndarray | None = None) -> Rounds:
    """GP-seeded adaptive pattern search on log scale (see module docstring), in rounds (a coroutine of
    :mod:`pipeline.rounds`: :func:`fast_search` runs it; ``n_jobs`` is that function's).

    Budget: ``max_evals`` candidates, or ``max_fits`` SVR fits (candidates x folds) when given. Phases, each
    candidate tagged in the trace (``phase``): ``seed`` (GP ARD and isotropic), ``warm_start``, ``explore``
    (``n_explore`` scrambled-Sobol points within a decade of the first GP seed, the ARD one, deterministic, scored
    in the seeds' round; default a quarter of the budget left after the seeds, at most one per hyperparameter),
    ``model`` (``local="model"``, the default: ``model_share`` of the remaining budget on expected-improvement steps
    of a GP fitted to the scores so far, see :func:`pipeline.models.search_steps.model_steps`), ``local`` (pattern
    search from the best point, one step size per coordinate: a step that improves is extended and its size doubled,
    a coordinate on which both directions fail halves its step; after each sweep a Hooke-Jeeves move along the
    sweep's displacement) and ``restart`` (random log-scale perturbations of the best once every step is below
    ``min_step``), so the budget is used.

    ``warm_start``: best hyperparameters of a simpler variant (RBF for 2-weights, 2-weights for WDSE), added
    as a seed, so that the richer kernel's tuning score is never below the simpler one's. When it is still the
    best at the end, the result says so (``warm_start_kept``, ``note``: how many candidates of which phases were
    tried and how close they came) and a warning is logged.

    ``smooth_tolerance`` > 0: return the smoothest candidate within that much R² of the best (see
    :func:`~pipeline.models.search_choice.smoothest_within`) rather than the best itself. ``one_se``: the same
    within one standard error of the best candidate's mean fold score (its fold scores' SD / sqrt(folds); the
    one-standard-error rule of Breiman et al. 1984, Hastie et al. 2009 §7.10), or ``smooth_tolerance`` if that is
    larger.

    ``progress(done, total, desc)`` (optional) is called after each new candidate (``total``: the budget).
    ``report_kept=False``: no warning for a kept warm start (a halving screen's: its last rung decides).
    ``fold_subset``: score the candidates on these of the ``n_folds`` folds only (a halving screen's; each trace
    entry then holds its folds' R², ``fold_r2``, for the next rung).
    ``groups``: each row's trial: the folds hold out whole trials (:func:`pipeline.evaluate.search_folds`: one per
    trial up to ``n_folds``, so ``n_folds`` is then the trials' count or less); None: blocked folds.
    """
    X, y = _check_xy(X, y)
    if local not in ("model", "pattern"):
        raise ModelError(f"unknown local search {local!r}; expected 'model' or 'pattern'")
    folds = search_folds(len(X), n_folds, groups)
    n_folds = len(folds)
    cap = _cap(iter_per_row, iter_cap_ratio, folds, len(folds) if fold_subset is None else len(fold_subset))
    if fold_subset is not None:
        folds = [folds[i] for i in fold_subset]
    names = _names(model, X.shape[1])
    if max_fits is not None:
        max_evals = max(1, max_fits // n_folds)
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    (seeds, gp_s), = yield [(_gp_seed, (model, X, y, n_velocity, gp_samples, seed))]
    phases = ["seed"] * len(seeds)
    if warm_start is not None:
        seeds.append(np.log(_expand(model, warm_start, X.shape[1], n_velocity)))
        phases.append("warm_start")
    lo, hi = _log_bounds(len(names) - 2, float(np.std(y)))
    cache: dict[tuple[float, ...], float] = {}
    trace: list[dict[str, Any]] = []
    evaluate = _evaluator(model, names, X, y, folds, n_velocity, cap, (lo, hi), cache, trace,
                          fold_r2=fold_subset is not None, progress=progress, budget=max_evals)

    if n_explore is None:
        n_explore = min(len(names), max(0, max_evals - len(seeds)) // 4)
    n_explore = min(n_explore, max(0, max_evals - len(seeds)))
    explore: list[np.ndarray] = []
    if n_explore > 0:  # a few candidates away from both seeds and warm start, around the ARD seed: same round
        unit = qmc.Sobol(len(names), scramble=True, seed=seed).random_base2(math.ceil(math.log2(n_explore)))
        centre = np.clip(seeds[0], lo, hi)
        explore = [np.clip(centre + (2.0 * u - 1.0) * math.log(10.0), lo, hi) for u in unit[:n_explore]]
    scores = yield from evaluate([*zip(seeds, phases, strict=True), *((c, "explore") for c in explore)])
    best, k_best = max((score, k) for k, score in enumerate(scores[:len(seeds)]))
    x = np.clip(seeds[k_best], lo, hi)
    for cand, score in zip(explore, scores[len(seeds):], strict=True):
        if score > best:
            x, best = cand, score
    warm_key = tuple(np.round(np.clip(seeds[-1], lo, hi), 6)) if warm_start is not None else None
    own_cpu = [gp_s]  # the GP seeds' and proposals' CPU: tasks of their own
    if local == "model":
        x, best = yield from model_steps(evaluate, x, best, lo, hi, max_evals, cache, seed, model_share, own_cpu)
    x, best, converged = yield from pattern_search(evaluate, x, best, lo, hi, rng, max_evals, cache, initial_step,
                                                   min_step)
    result = SearchResult(model, "fast", _to_params(model, names, np.exp(x)), float(best), len(cache),
                          sum(t["n_fits"] for t in trace), n_folds, 0.0, gp_fit_s=gp_s, trace=trace, n_rows=len(X),
                          budget_exhausted=not converged, folds="blocked" if groups is None else "trials")
    if warm_key is not None:
        result.warm_start_score = float(cache[warm_key])
        if tuple(np.round(x, 6)) == warm_key:
            result.warm_start_kept = True
            result.note = kept_note(trace, cache[warm_key], n_folds)
            if report_kept:
                log.warning("fast search %s kept its warm start unchanged: %s", model, result.note)
    tolerance = smooth_tolerance
    if one_se:  # the one-standard-error rule: the best candidate's fold scores say how sure its lead is
        tolerance = max(tolerance, next(t["se"] for t in trace if t["score"] == best))
    if tolerance > 0:
        result.best_params, result.best_score = smoothest_within(trace, best, tolerance)
    result.elapsed_s = time.perf_counter() - t0
    cost = cost_summary(trace, cap)
    result.cost = {"cpu_s": round(cost["fits_cpu_s"] + own_cpu[0], 4), **cost}
    log_capped(model, result.n_candidates, result.cost)
    return result


def local_search_rounds(model: str, X: np.ndarray, y: np.ndarray, *, start: dict[str, Any], n_folds: int = 3,
                        n_jobs: int | None = 1, n_velocity: int = 3, max_evals: int = 8,
                        iter_per_row: float | None = ITER_PER_ROW, iter_cap_ratio: float | None = ITER_CAP_RATIO,
                        initial_step: float = math.log(2.0),
                        min_step: float = math.log(1.25), fold_subset: list[int] | None = None,
                        groups: np.ndarray | None = None) -> Rounds:
    """A small search around ``start`` (another search's optimum, e.g. the tune stage's on the rows these are cut
    from): ``start`` scored, then the pattern search of :func:`fast_search` from it, steps of ``initial_step``
    (x2), no restarts, at most ``max_evals`` candidates in all. The nested CV's folds use it, so a fold re-tunes
    on its own training rows at a fraction of a whole search's cost. ``warm_start_kept``/``note`` say whether
    ``start`` stayed the best; ``budget_exhausted`` whether the budget ran out before the steps converged.
    ``fold_subset``: score on these of the ``n_folds`` folds only (as a halving screen does); ``groups`` as
    :func:`fast_search`'s. A coroutine of :mod:`pipeline.rounds` (:func:`local_search` runs it)."""
    X, y = _check_xy(X, y)
    folds = search_folds(len(X), n_folds, groups)
    n_folds = len(folds)
    cap = _cap(iter_per_row, iter_cap_ratio, folds, len(folds) if fold_subset is None else len(fold_subset))
    if fold_subset is not None:
        folds = [folds[i] for i in fold_subset]
    names = _names(model, X.shape[1])
    lo, hi = _log_bounds(len(names) - 2, float(np.std(y)))
    t0 = time.perf_counter()
    cache: dict[tuple[float, ...], float] = {}
    trace: list[dict[str, Any]] = []
    evaluate = _evaluator(model, names, X, y, folds, n_velocity, cap, (lo, hi), cache, trace, from_key=True)
    x0 = np.clip(np.log(_expand(model, start, X.shape[1], n_velocity)), lo, hi)
    start_score, = yield from evaluate([(x0, "warm_start")])
    x, best, converged = yield from pattern_search(evaluate, x0, start_score, lo, hi, np.random.default_rng(0),
                                                   max(1, max_evals), cache, initial_step, min_step, restarts=False)
    result = SearchResult(model, "local", _to_params(model, names, np.exp(x)), float(best), len(cache),
                          sum(t["n_fits"] for t in trace), n_folds, time.perf_counter() - t0, trace=trace,
                          warm_start_score=float(start_score), budget_exhausted=not converged, n_rows=len(X),
                          folds="blocked" if groups is None else "trials")
    if tuple(np.round(x, 6)) == tuple(np.round(x0, 6)):
        result.warm_start_kept = True
        result.note = kept_note(trace, start_score, n_folds)
    cost = cost_summary(trace, cap)
    result.cost = {"cpu_s": cost["fits_cpu_s"], **cost}
    return result


fast_search = _driven(fast_search_rounds)
local_search = _driven(local_search_rounds)


def search_rounds(model: str, X: np.ndarray, y: np.ndarray, method: str = "fast", **kw: Any) -> Rounds:
    """Dispatch to :func:`fast_search_rounds`, :func:`grid_search` (``method="paper_grid"``, not in rounds: its
    candidates are one joblib fan-out) or :func:`local_search_rounds` (``"local"``) with the keywords ``kw`` of
    that function; one it does not take is refused (TypeError naming it). The best parameters carry ``C_rows``:
    the mean training rows of the search's folds, the rows its C was chosen on (see
    :func:`pipeline.models.svr.scaled_C`). Successive halving: :mod:`pipeline.models.search_halving` (its
    ``search_rounds`` takes the halving's keywords too). A coroutine of :mod:`pipeline.rounds`."""
    methods = {"fast": fast_search_rounds, "paper_grid": grid_search, "local": local_search_rounds}
    if method not in methods:
        raise ModelError(f"unknown search method {method!r}; expected 'fast', 'paper_grid' or 'local'")
    takes = [n for n, a in inspect.signature(methods[method]).parameters.items()
             if a.kind is inspect.Parameter.KEYWORD_ONLY and n not in ("keep_trace", "report_kept")]
    unknown = sorted(set(kw) - set(takes))
    if unknown:
        raise TypeError(f"search(method={method!r}) does not use {unknown}; it takes {takes}")
    if method == "paper_grid":
        res = grid_search(model, X, y, keep_trace=False, **kw)
    else:
        res = yield from methods[method](model, X, y, **kw)
    return with_C_rows(res, len(X))


search = _driven(search_rounds)


def with_C_rows(res: SearchResult, n_rows: int) -> SearchResult:
    """``res`` with ``C_rows`` in its best parameters: the mean training rows of its ``res.n_folds`` folds on ``n_rows``
    rows (any k folds that test each row once train on n (k - 1) / k rows on average: the trials' folds too)."""
    train_rows = [len(train) for train, _ in search_folds(n_rows, res.n_folds)]
    res.best_params = {**res.best_params, "C_rows": int(round(float(np.mean(train_rows))))}
    return res
