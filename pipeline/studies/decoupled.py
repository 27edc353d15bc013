"""The decoupled damping study of paper 001: per DOF, d_i(nu_i) learned by LS, MLP, KRR, SVR and GP.

Protocol (DESIGN.md, "Models and evaluation"): hyperparameters are searched on the *tuning* split only
(``GridSearchCV`` over the paper's grid or the fast grid, ``KFold(folds, shuffle=False)``, scored on MAE); the GP
learns its kernel by marginal likelihood instead, and LS has nothing to tune (their "search score" is the same CV
on the tuning split). The *train_test* split is then scored by unshuffled k-fold CV (MAE and R^2, train and test,
mean and SD), learning curves (``learning_curve`` with the same KFold), and fit / predict times per fold (Fig. 3).
The final model of each (DOF, model) is fitted on the whole train_test split.

Prediction intervals (:func:`oof_interval`): each model's 90 % interval is its prediction +- ``q`` times the
target's own SD (the smoother's ``d_std_*`` column; +- ``q`` where the store has none), ``q`` per DOF the conformal
quantile of the normalized out-of-fold residuals of that same unshuffled k-fold CV.
Blocks, not shuffled folds: the targets' errors are correlated in time, and a shuffled fold's neighbours in the
training rows make its residuals too small. The GP also learns from each target's own SD (the smoother's
``d_std_*`` column, where the store has it) and gives a 2-sigma band of the target (``include_noise``). With
``test`` rows (the store's test split) each interval's and band's coverage on the unseen trial(s) is measured
(:func:`unseen_scores`); docs/models.md, "Decoupled models' intervals". :func:`decoupled_stage` is the work of
the stage shell ``stages/decoupled.py``, which reads and writes; the table and figures are in
:mod:`pipeline.report.decoupled`.

Kernel methods and the MLP are O(n^2)-O(n^3) in the samples; a full trial at 20 Hz holds far more samples than the
1-D damping curve needs, and neighbouring samples are strongly correlated (smoothed derivatives), so each split
is thinned to at most ``max_samples`` rows by an even stride in time (``None``: keep all). The GP additionally
keeps at most ``gp_max_samples`` points evenly spread in velocity (see ``bench/gp.py`` for the time-vs-n table).
"""

from __future__ import annotations

import logging
import platform
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import joblib
import numpy as np
import pandas as pd
import sklearn
from sklearn.base import BaseEstimator, clone
from sklearn.exceptions import ConvergenceWarning
from sklearn.model_selection import GridSearchCV, KFold, cross_validate, learning_curve
from threadpoolctl import threadpool_limits

from pipeline import __version__
from pipeline.config import Vehicle, config_hash
from pipeline.config.params import DecoupledParams
from pipeline.errors import ConfigError, ModelError
from pipeline.evaluate import (
    INTERVAL_LEVEL,
    MODEL_FAILURES,
    conformal_half_width,
    interval_half_width,
    model_failure,
    scale_fit,
    sd_floor,
)
from pipeline.models.decoupled import DampingGP, describe, make_estimator, paper_names, param_grid
from pipeline.parallel import imap, task_result, timed_task, workers
from pipeline.physics import weight_buoyancy_N
from pipeline.vocabulary import DAMPING_COLUMNS, VELOCITY_COLUMNS, force_column

log = logging.getLogger(__name__)

SCORING = {"mae": "neg_mean_absolute_error", "r2": "r2"}
#: Models whose ``fit`` takes the targets' own SDs (``sample_sd``).
TAKES_SD = ("gp",)
#: The models from the costliest unit (search, CV, final fit) to the cheapest on the fast grids (docs/benchmarks.md,
#: "The decoupled study's units, costliest first"): the order their units go to the workers.
COST_ORDER = ("svr", "gp", "krr", "mlp", "ls")
#: The log names a grid search whose slowest candidate's fit takes more than this many times its median one.
SLOW_CANDIDATE_RATIO = 20.0


def dof_columns(dof: str) -> tuple[str, str]:
    """(velocity column, damping target column) of a DOF, e.g. ``("v_mps", "d_v_N")``."""
    if dof not in VELOCITY_COLUMNS:
        raise ModelError(f"unknown DOF {dof!r}; expected one of {list(VELOCITY_COLUMNS)}")
    return VELOCITY_COLUMNS[dof], DAMPING_COLUMNS[dof]


def sd_column(dof: str) -> str:
    """The damping target's own SD (the derive stage's, kalman method only): ``d_std_v_N``."""
    return force_column(dof, "d_std")


def dof_data(df: pd.DataFrame, dof: str, max_samples: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """``X (n, 1)`` and ``y (n,)`` of a DOF, finite rows only, in table order, thinned by an even stride."""
    X, y, _ = dof_samples(df, dof, max_samples)
    return X, y


def dof_samples(df: pd.DataFrame, dof: str, max_samples: int | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """:func:`dof_data` and the targets' own SDs of those rows (None where the table has no :func:`sd_column`;
    a row's non-finite SD becomes the median of the others, with a warning)."""
    x_col, y_col = dof_columns(dof)
    missing = [c for c in (x_col, y_col) if c not in df.columns]
    if missing:
        raise ModelError(f"columns {missing} missing for DOF {dof!r}; have {sorted(df.columns)[:20]}...")
    x = df[x_col].to_numpy(dtype=float)
    y = df[y_col].to_numpy(dtype=float)
    ok = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    if max_samples is not None and ok.size > max_samples:
        ok = ok[np.linspace(0, ok.size - 1, max_samples).round().astype(int)]
    sd = df[sd_column(dof)].to_numpy(dtype=float)[ok] if sd_column(dof) in df.columns else None
    if sd is not None:
        bad = ~(np.isfinite(sd) & (sd >= 0))
        if bad.all():
            sd = None
        elif bad.any():
            log.warning("%s: %d of %d rows have no finite SD; they take the median SD", sd_column(dof),
                        int(bad.sum()), bad.size)
            sd[bad] = float(np.median(sd[~bad]))
    return x[ok, None], y[ok], sd


def net_buoyancy(result: ModelResult, configured_N: float | None) -> dict[str, Any]:
    """B - W (N) of a heave ``ls`` model with a constant, ``{}`` for any other: derive took the configured B - W out
    of d_w (as g_w, times cos(pitch) cos(roll)), so the constant is what it left, and B - W = configured + constant,
    with the constant's SD (None where not defined). Without the configured value (None) only the constant."""
    if result.dof != "w" or result.model != "ls" or result.estimator is None:
        return {}
    learned = describe("ls", result.estimator)
    if "intercept" not in learned:
        return {}
    out = {"intercept_N": learned["intercept"], "sd_N": learned["intercept_sd"], "configured_N": configured_N}
    if configured_N is not None:
        out["B_minus_W_N"] = configured_N + learned["intercept"]
    return out


@dataclass
class ModelResult:
    """Everything the study learned about one (DOF, model)."""

    dof: str
    model: str
    best_params: dict[str, Any]
    search_mae: float
    cv: dict[str, float]
    learning_curve: dict[str, list[float]]
    fit_time_s: float
    predict_time_s: float
    estimator: BaseEstimator | None = field(default=None, repr=False)
    #: the prediction interval (:func:`evaluate`): level, half_width, method, rows; the GP's CV band coverage
    interval: dict[str, Any] = field(default_factory=dict)
    #: on the unseen test rows (:func:`unseen_scores`); {} without test rows
    test: dict[str, Any] = field(default_factory=dict)
    #: what the grid search's candidates cost (:func:`grid_cost`; wall-clock, so in timings.json); {} without a grid
    search_cost: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"dof": self.dof, "model": self.model, "best_params": self.best_params,
                "search_mae": self.search_mae, "cv": self.cv, "learning_curve": self.learning_curve,
                "learned": describe(self.model, self.estimator) if self.estimator is not None else {},
                "interval": self.interval, "test": self.test}


@dataclass
class StudyResult:
    results: list[ModelResult]
    #: (DOF, model) pairs that failed: :func:`pipeline.evaluate.model_failure` entries with ``dof``
    failed: list[dict[str, str]] = field(default_factory=list)
    #: the vehicle's B - W (N, from its config) that derive took out of the heave damping target; None: not known
    configured_net_buoyancy_N: float | None = None

    def get(self, dof: str, model: str) -> ModelResult:
        for r in self.results:
            if r.dof == dof and r.model == model:
                return r
        raise KeyError((dof, model))

    def metrics(self) -> dict[str, Any]:
        """Deterministic metrics (no timings): per DOF and model."""
        out: dict[str, Any] = {}
        for r in self.results:
            out.setdefault(r.dof, {})[r.model] = r.as_dict()
            buoyancy = net_buoyancy(r, self.configured_net_buoyancy_N)
            if buoyancy:
                out[r.dof][r.model]["net_buoyancy"] = buoyancy
        for f in self.failed:
            out.setdefault(f["dof"], {})[f["model"]] = {"failed": f"{f['error']}: {f['reason']}"}
        return out

    def timings(self) -> dict[str, Any]:
        return {f"{r.dof}/{r.model}": {"fit_time_s": r.fit_time_s, "predict_time_s": r.predict_time_s,
                                       **({"search": r.search_cost} if r.search_cost else {})}
                for r in self.results}


@contextmanager
def _quiet() -> Iterator[None]:
    """Silence convergence warnings (MLP lbfgs, GP bounds) inside searches and CV; they are expected."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        yield


def _fit_params(name: str, sd: np.ndarray | None) -> dict[str, Any] | None:
    """The targets' SDs as a fit parameter of the models that take them (:data:`TAKES_SD`), else None."""
    return {"sample_sd": sd} if sd is not None and name in TAKES_SD else None


def tune(name: str, X: np.ndarray, y: np.ndarray, *, search: str | dict[str, list[Any]] = "fast", folds: int = 5,
         seed: int = 0, gp_max_samples: int = 500, gp_warp: str = "signed_square", sd: np.ndarray | None = None,
         intercept: bool = False) -> tuple[BaseEstimator, dict[str, Any], float, dict[str, Any]]:
    """Best hyperparameters on the tuning data: ``(unfitted estimator, params in paper names, CV MAE, what the
    grid's candidates cost)`` (:func:`grid_cost`; {} for a model without a grid); ``intercept``: the ``ls`` model
    with a constant."""
    estimator = make_estimator(name, seed=seed, gp_max_samples=gp_max_samples, gp_warp=gp_warp, intercept=intercept)
    grid = param_grid(name, search)
    cv = KFold(n_splits=folds, shuffle=False)
    if len(y) < 2 * folds:
        raise ModelError(f"{len(y)} tuning samples are too few for {folds}-fold CV of {name!r}")
    with _quiet():
        if not grid:
            scores = cross_validate(estimator, X, y, cv=cv, scoring="neg_mean_absolute_error",
                                    params=_fit_params(name, sd))["test_score"]
            return estimator, {}, float(-scores.mean()), {}
        gs = GridSearchCV(estimator, grid, scoring="neg_mean_absolute_error", cv=cv, refit=False, n_jobs=1)
        gs.fit(X, y)
    return (clone(estimator).set_params(**gs.best_params_), paper_names(name, gs.best_params_),
            float(-gs.best_score_), grid_cost(name, gs.cv_results_, folds))


def grid_cost(name: str, cv_results: dict[str, Any], folds: int, n_slowest: int = 3) -> dict[str, Any]:
    """What a grid search's candidates cost, from ``GridSearchCV.cv_results_``: their number, the search's fit
    seconds in all, a candidate's median fit (one fold's), and its ``n_slowest`` candidates (paper names) with
    their fit and its ratio to the median, slowest first. The paper's grids hold C up to 1e4 beside small epsilons,
    and libsvm's cost grows with C: this says how far the slowest candidates stand from the rest."""
    fit = np.asarray(cv_results["mean_fit_time"], dtype=float)
    median = float(np.median(fit))
    slowest = np.argsort(-fit, kind="stable")[:n_slowest]
    return {"candidates": int(fit.size), "fit_s": float(fit.sum() * folds), "median_fit_s": median,
            "slowest": [{"params": paper_names(name, cv_results["params"][i]), "fit_s": float(fit[i]),
                         "ratio": float(fit[i] / median) if median > 0 else None} for i in slowest]}


def evaluate(estimator: BaseEstimator, X: np.ndarray, y: np.ndarray, *, folds: int = 5, curve_points: int = 5,
             sd: np.ndarray | None = None, name: str = ""
             ) -> tuple[dict[str, float], dict[str, list[float]], float, float, dict[str, Any]]:
    """Unshuffled k-fold CV (MAE, R^2, train and test, mean and SD), learning curve, mean fit / predict time, and
    the prediction interval from the same folds' out-of-fold residuals (:func:`oof_interval`). ``sd``: the
    targets' own SDs, passed to the models that take them (``name`` in :data:`TAKES_SD`)."""
    cv = KFold(n_splits=folds, shuffle=False)
    params = _fit_params(name, sd)
    with _quiet():
        res = cross_validate(estimator, X, y, cv=cv, scoring=SCORING, return_train_score=True, params=params,
                             return_estimator=True, return_indices=True)
        sizes, train, test = learning_curve(estimator, X, y, cv=cv, train_sizes=np.linspace(0.1, 1.0, curve_points),
                                            scoring="neg_mean_absolute_error", shuffle=False, params=params)
    metrics: dict[str, float] = {}
    for split in ("train", "test"):
        for key in SCORING:
            vals = res[f"{split}_{key}"] * (-1 if key == "mae" else 1)
            metrics[f"{split}_{key}_mean"] = float(vals.mean())
            metrics[f"{split}_{key}_sd"] = float(vals.std())
    curve = {"train_sizes": [int(s) for s in sizes],
             "train_mae_mean": (-train.mean(axis=1)).tolist(), "train_mae_sd": train.std(axis=1).tolist(),
             "test_mae_mean": (-test.mean(axis=1)).tolist(), "test_mae_sd": test.std(axis=1).tolist()}
    interval = oof_interval(res["estimator"], res["indices"]["test"], X, y, sd)
    return metrics, curve, float(res["fit_time"].mean()), float(res["score_time"].mean()), interval


def oof_interval(estimators: Sequence[BaseEstimator], test_folds: Sequence[np.ndarray], X: np.ndarray,
                 y: np.ndarray, sd: np.ndarray | None) -> dict[str, Any]:
    """The :data:`INTERVAL_LEVEL` interval from the out-of-fold residuals of the blocked folds (each fold's rows
    predicted by the model fitted without them); for a GP also the share of out-of-fold targets inside its 2-sigma
    band (``cv_band_coverage``).

    With the targets' own SDs ``sd`` the score is normalized: ``q`` (``half_width_sd``) is the conformal quantile
    of ``|residual| / sd`` and a row's interval is ``+- q sd``, so it widens where the target is noisier (a faster
    trial); ``half_width`` is then ``q`` times the training rows' RMS SD, the typical width. Without ``sd``: one
    half-width, the quantile of ``|residual|``. Saved beside it, not used (measured on validation seeds and not
    taken: docs/models.md, "Decoupled models' intervals"): ``alternatives``, spreads that grow with the
    prediction p (:func:`pipeline.evaluate.scale_fit`): ``prediction`` c_0 + c_1 |p| and ``sd_prediction``
    c_0 sd + c_1 |p|."""
    resid, inside, preds = [], [], []
    for est, rows in zip(estimators, test_folds, strict=True):
        if isinstance(est, DampingGP):
            mean, std = est.predict(X[rows], return_std=True, include_noise=True,
                                    sample_sd=None if sd is None else sd[rows])
            inside.append(np.abs(y[rows] - mean) <= 2 * std)
        else:
            mean = est.predict(X[rows])
        resid.append(np.abs(y[rows] - np.ravel(mean)))
        preds.append(np.abs(np.ravel(mean)))
    r = np.concatenate(resid)
    out: dict[str, Any] = {"level": INTERVAL_LEVEL, "rows": int(r.size),
                           "method": "split conformal on the blocked CV's out-of-fold residuals"}
    if sd is None:
        out.update(scale="none", half_width=conformal_half_width(r))
    else:
        scale = sd_floor(np.concatenate([sd[rows] for rows in test_folds]))
        q = conformal_half_width(r / scale)
        out.update(scale="target_sd", half_width_sd=q, half_width=q * float(np.sqrt(np.mean(sd**2))))
    if inside:
        out["cv_band_coverage"] = float(np.concatenate(inside).mean())
    covariates = _spread_covariates(np.concatenate(preds),
                                    None if sd is None else np.concatenate([sd[rows] for rows in test_folds]))
    out["alternatives"] = {}
    for name, Z in covariates.items():
        c, q = scale_fit([r], [Z])
        out["alternatives"][name] = {"spread": c, "half_width_scaled": q}
    return out


def _spread_covariates(abs_pred: np.ndarray, sd: np.ndarray | None) -> dict[str, np.ndarray]:
    """The covariates of :func:`oof_interval`'s alternatives at rows of |prediction| ``abs_pred`` and target SD
    ``sd``: ``prediction`` [1, |p|] and, with SDs, ``sd_prediction`` [sd, |p|]."""
    out = {"prediction": np.column_stack([np.ones(abs_pred.size), abs_pred])}
    if sd is not None:
        out["sd_prediction"] = np.column_stack([sd_floor(sd), abs_pred])
    return out


def unseen_scores(result: ModelResult, X: np.ndarray, y: np.ndarray, sd: np.ndarray | None,
                trials: Sequence[str]) -> dict[str, Any]:
    """The final model on unseen rows: MAE, the share inside its interval (``interval_coverage``) and, for a GP,
    inside its 2-sigma band of the target (``band_coverage``, with the rows' own SDs where known)."""
    est = result.estimator
    out: dict[str, Any] = {"trials": sorted(trials), "rows": int(y.size)}
    if est is None or y.size == 0:
        return out
    if isinstance(est, DampingGP):
        mean, std = est.predict(X, return_std=True, include_noise=True, sample_sd=sd)
        out["band_coverage"] = float(np.mean(np.abs(y - mean) <= 2 * std))
    else:
        mean = np.ravel(est.predict(X))
    err = np.abs(y - mean)
    out["mae"] = float(err.mean())
    if "half_width" in result.interval:
        out["interval_coverage"] = float(np.mean(err <= interval_half_width(result.interval, sd)))
    covariates = _spread_covariates(np.abs(mean), sd)
    for name, alt in result.interval.get("alternatives", {}).items():
        if name in covariates:
            half = alt["half_width_scaled"] * (covariates[name] @ alt["spread"])
            out[f"interval_coverage_{name}"] = float(np.mean(err <= half))
    return out


def run_study(tuning: pd.DataFrame, train_test: pd.DataFrame, *, dofs: Sequence[str] = ("u", "v", "r"),
              models: Sequence[str] = ("ls", "mlp", "krr", "svr", "gp"), folds: int = 5,
              search: str | dict[str, dict[str, list[Any]]] = "fast", gp_max_samples: int = 500,
              max_samples: int | None = 3000, curve_points: int = 5, seed: int = 0,
              dof_trials: Mapping[str, Sequence[str]] | None = None, gp_warp: str = "signed_square",
              on_result: Callable[[ModelResult | None, dict[str, str] | None], None] | None = None,
              test: pd.DataFrame | None = None, n_jobs: int | str | None = 1, intercept: Sequence[str] = ()
              ) -> StudyResult:
    """The whole study; ``search`` may also map a model name to an explicit grid in the paper's names.
    ``intercept``: the DOFs whose ``ls`` model fits a constant (:func:`net_buoyancy` for w).

    A (DOF, model) that fails (:data:`pipeline.evaluate.MODEL_FAILURES`, e.g. too few samples of a DOF) is logged
    and listed in :attr:`StudyResult.failed`; the others go on. ``on_result(result, None)`` or ``on_result(None,
    failure)`` is called as each one ends, so a stage can write it at once.

    ``dof_trials`` (optional): per DOF, the trials (``trial`` column) its models learn from; as in paper 001, where
    each DOF's damping comes from experiments exciting that DOF alone. DOFs not named use every trial.

    ``test`` (optional): unseen rows (every row of the store's test split, all its trials, for every DOF), on which
    each final model's interval and band coverage are measured (:attr:`ModelResult.test`); nothing is chosen on
    them.

    ``n_jobs``: workers for the (DOF, model) units (``"auto"``: every usable core; results in the same order and
    the same bytes whatever the number).
    """
    with threadpool_limits(1, user_api="blas"):  # small problems: parallelism belongs to models, not BLAS
        return _run_study(tuning, train_test, dofs, models, folds, search, gp_max_samples, max_samples, curve_points,
                          seed, dof_trials, gp_warp, on_result, test, n_jobs, intercept)


def _run_study(tuning: pd.DataFrame, train_test: pd.DataFrame, dofs: Sequence[str], models: Sequence[str], folds: int,
               search: str | dict[str, dict[str, list[Any]]], gp_max_samples: int, max_samples: int | None,
               curve_points: int, seed: int, dof_trials: Mapping[str, Sequence[str]] | None, gp_warp: str,
               on_result: Callable[[ModelResult | None, dict[str, str] | None], None] | None = None,
               test: pd.DataFrame | None = None, n_jobs: int | str | None = 1, intercept: Sequence[str] = ()
               ) -> StudyResult:
    study = StudyResult([])
    known = set(tuning["trial"]) | set(train_test["trial"]) if dof_trials else set()
    for dof, names in (dof_trials or {}).items():  # a misspelt name would shrink the DOF's data without a word
        if set(names) - known:
            raise ConfigError(f"decoupled.trials.{dof} names {sorted(set(names) - known)}, which are not tuning or "
                              f"train_test trials of the feature store: {sorted(known)}",
                              field=f"decoupled.trials.{dof}")

    def failed(entry: dict[str, str]) -> None:
        log.error("%s/%s failed, the others go on: %s: %s", entry["dof"], entry["model"], entry["error"],
                  entry["reason"])
        study.failed.append(entry)
        if on_result is not None:
            on_result(None, entry)

    units: list[dict[str, Any]] = []
    for dof in dofs:
        try:
            rows = _dof_rows(tuning, train_test, dof, folds, max_samples, dof_trials)
        except MODEL_FAILURES as err:
            for name in models:
                failed(model_failure(name, err, dof=dof))
            continue
        unseen = None if test is None or test.empty else dof_samples(test, dof)
        trials = sorted(set(test["trial"])) if unseen is not None and "trial" in test else []
        units += [{"dof": dof, "name": name, "rows": rows, "unseen": unseen, "trials": trials,
                   "kw": {"folds": folds, "search": search, "seed": seed, "gp_max_samples": gp_max_samples,
                          "gp_warp": gp_warp, "curve_points": curve_points, "intercept": dof in intercept}}
                  for name in models]
    # every (DOF, model) is an independent task (search, CV, final fit) for the run's workers, the costliest
    # models first so that none of them starts last; results are kept in DOF-then-model order whatever order they
    # finish in
    cost_rank = {name: i for i, name in enumerate(COST_ORDER)}
    order = sorted(range(len(units)), key=lambda i: (cost_rank.get(units[i]["name"], len(cost_rank)), i))
    finished: dict[int, ModelResult] = {}
    for position, timed in imap(timed_task(_unit, "decoupled"), [units[i] for i in order], jobs=workers(n_jobs)):
        index = order[position]
        unit = units[index]
        out = task_result(timed, "decoupled", f"{unit['dof']}/{unit['name']}")
        if "failed" in out:
            failed(out["failed"])
            continue
        finished[index] = out["result"]
        if on_result is not None:
            on_result(out["result"], None)
    study.results = [finished[i] for i in sorted(finished)]
    rank = {**{d: i for i, d in enumerate(dofs)}, **{m: i for i, m in enumerate(models)}}
    study.failed.sort(key=lambda f: (rank.get(f.get("dof"), -1), rank.get(f.get("model"), -1)))
    return study


def _unit(unit: dict[str, Any]) -> dict[str, Any]:
    """One (DOF, model): :func:`_study_one` and its scores on the unseen rows, or ``{"failed": entry}``."""
    try:
        result = _study_one(unit["dof"], unit["name"], *unit["rows"], **unit["kw"])
        if unit["unseen"] is not None:
            result.test = unseen_scores(result, *unit["unseen"], unit["trials"])
    except MODEL_FAILURES as err:
        return {"failed": model_failure(unit["name"], err, dof=unit["dof"])}
    return {"result": result}


def _dof_rows(tuning: pd.DataFrame, train_test: pd.DataFrame, dof: str, folds: int, max_samples: int | None,
              dof_trials: Mapping[str, Sequence[str]] | None) -> tuple[np.ndarray, ...]:
    """``(X_tune, y_tune, sd_tune, X, y, sd)`` of a DOF (its own trials if ``dof_trials`` names them; ``sd``: the
    targets' own SDs or None, :func:`dof_samples`)."""
    tune_rows, tt_rows = tuning, train_test
    if dof_trials and dof_trials.get(dof):
        wanted = set(dof_trials[dof])
        tune_rows = tuning[tuning["trial"].isin(wanted)]
        tt_rows = train_test[train_test["trial"].isin(wanted)]
    X_tune, y_tune, sd_tune = dof_samples(tune_rows, dof, max_samples)
    X, y, sd = dof_samples(tt_rows, dof, max_samples)
    if len(y) < 2 * folds:
        raise ModelError(f"{len(y)} train_test samples are too few for {folds}-fold CV", field=dof)
    return X_tune, y_tune, sd_tune, X, y, sd


def _study_one(dof: str, name: str, X_tune: np.ndarray, y_tune: np.ndarray, sd_tune: np.ndarray | None,
               X: np.ndarray, y: np.ndarray, sd: np.ndarray | None, *, folds: int,
               search: str | dict[str, dict[str, list[Any]]], seed: int, gp_max_samples: int, gp_warp: str,
               curve_points: int, intercept: bool = False) -> ModelResult:
    model_search = search.get(name, "fast") if isinstance(search, dict) else search
    t0 = time.perf_counter()
    est, best, score, cost = tune(name, X_tune, y_tune, search=model_search, folds=folds, seed=seed,
                                  gp_max_samples=gp_max_samples, gp_warp=gp_warp, sd=sd_tune, intercept=intercept)
    cv, curve, fit_s, pred_s, interval = evaluate(est, X, y, folds=folds, curve_points=curve_points, sd=sd,
                                                  name=name)
    with _quiet():
        final = clone(est).fit(X, y, **(_fit_params(name, sd) or {}))
    log.info("%s/%s: search MAE %.3f, CV test MAE %.3f, %.0f %% interval +-%.3g (%.1f s)", dof, name, score,
             cv["test_mae_mean"], 100 * interval["level"], interval["half_width"], time.perf_counter() - t0)
    if cost and (cost["slowest"][0]["ratio"] or 0.0) > SLOW_CANDIDATE_RATIO:
        log.info("%s/%s: the search's slowest candidate %s took %.0fx its median fit (%.3g s a fold)", dof, name,
                 cost["slowest"][0]["params"], cost["slowest"][0]["ratio"], cost["slowest"][0]["fit_s"])
    return ModelResult(dof, name, best, score, cv, curve, fit_s, pred_s, final, interval, search_cost=cost)


def damping_curves(study: StudyResult, ranges: dict[str, tuple[float, float]], n_points: int = 101
                   ) -> dict[str, Any]:
    """Each final model's d_i(nu_i) on a grid over ``ranges[dof]`` (GP: with its latent sd)."""
    out: dict[str, Any] = {}
    for r in study.results:
        if r.estimator is None or r.dof not in ranges:
            continue
        grid = np.linspace(*ranges[r.dof], n_points)
        entry: dict[str, Any] = {"nu": grid.tolist()}
        if r.model == "gp":
            mean, std = r.estimator.predict(grid[:, None], return_std=True)
            entry.update(d=mean.tolist(), sd=std.tolist())
        else:
            entry["d"] = np.asarray(r.estimator.predict(grid[:, None])).tolist()
        out.setdefault(r.dof, {})[r.model] = entry
    return out


# -- the stage -----------------------------------------------------------------------------------------------

def stage_columns(params: DecoupledParams, available: Sequence[str] | None = None) -> list[str]:
    """The feature-store columns the decoupled stage reads: with ``available`` (the store's columns), also the
    damping targets' SDs it has (:func:`sd_column`)."""
    sds = [sd_column(d) for d in params.dofs if available is not None and sd_column(d) in available]
    return ["t_ns", "segment", "split"] + [c for d in params.dofs for c in dof_columns(d)] + sds


def run_lineage(vehicle: Vehicle, params: DecoupledParams, tuning: pd.DataFrame, train_test: pd.DataFrame
                ) -> dict[str, Any]:
    """What a run learned from: the vehicle and params (hashes, params), the trials and the rows of each split."""
    weight, buoyancy = weight_buoyancy_N(vehicle.rigid_body)
    return {"vehicle": vehicle.name, "vehicle_hash": config_hash(vehicle), "params_hash": config_hash(params),
            "params": params.model_dump(), "trials": sorted(set(tuning["trial"]) | set(train_test["trial"])),
            "rows": {"tuning": len(tuning), "train_test": len(train_test)},
            "configured_net_buoyancy_N": buoyancy - weight}


def versions() -> dict[str, str]:
    return {"auvid": __version__, "scikit-learn": sklearn.__version__, "numpy": np.__version__,
            "joblib": joblib.__version__, "python": platform.python_version()}


def model_card(result: ModelResult, lineage: dict[str, Any]) -> dict[str, Any]:
    """The card of one (DOF, model): it names the file's inputs and output."""
    x_col, y_col = dof_columns(result.dof)
    return {"kind": "decoupled_damping", "dof": result.dof, "model": result.model, "inputs": [x_col],
            "output": y_col, "hyperparameters": result.best_params, "learned": describe(result.model, result.estimator),
            "search_mae": result.search_mae, "scores": result.cv, "interval": result.interval, "test": result.test,
            **({"net_buoyancy": b} if (b := net_buoyancy(result, lineage.get("configured_net_buoyancy_N"))) else {}),
            "lineage": lineage, "versions": versions()}


def decoupled_stage(tuning: pd.DataFrame, train_test: pd.DataFrame, params: DecoupledParams, *,
                    lineage: dict[str, Any], test: pd.DataFrame | None = None,
                    on_result: Callable[[ModelResult | None, dict[str, str] | None, dict[str, Any] | None], None]
                    | None = None) -> tuple[StudyResult, dict[str, Any]]:
    """The decoupled stage's work: :func:`run_study` with ``params``, then each final model's damping curve over the
    train_test velocities (:func:`damping_curves`). ``on_result(result, None, card)`` as each (DOF, model) finishes
    (its :func:`model_card`), ``on_result(None, failure, None)`` as one fails, so the stage writes it at once.
    ``test``: the store's test split, for the intervals' coverage on unseen trials (:func:`run_study`).
    Returns ``(study, curves)``; a ModelError when every model failed."""

    def finished(result: ModelResult | None, failure: dict[str, str] | None) -> None:
        if on_result is not None:
            on_result(result, failure, None if result is None else model_card(result, lineage))

    p = params
    study = run_study(tuning, train_test, dofs=p.dofs, models=p.models, folds=p.folds, search=p.search,
                      gp_max_samples=p.gp_max_samples, max_samples=p.max_samples, curve_points=p.curve_points,
                      seed=p.seed, dof_trials=p.trials, gp_warp=p.gp_warp, on_result=finished, test=test,
                      n_jobs=p.n_jobs, intercept=p.intercept)
    study.configured_net_buoyancy_N = lineage.get("configured_net_buoyancy_N")
    if not study.results:
        raise ModelError("every decoupled model failed: " + "; ".join(
            f"{f['dof']}/{f['model']}: {f['reason']}" for f in study.failed))
    ranges = {d: (float(train_test[dof_columns(d)[0]].min()), float(train_test[dof_columns(d)[0]].max()))
              for d in p.dofs}
    return study, damping_curves(study, ranges)
