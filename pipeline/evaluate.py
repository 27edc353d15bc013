"""Evaluation protocol: split blocks, unshuffled blocked k-fold CV with a leakage guard, metrics, and the
split-conformal prediction interval from the CV's out-of-fold residuals (docs/models.md, "Decoupled models'
intervals" and "Coupled models' intervals").

Generic on purpose (the coupled and the decoupled studies both use it): an estimator, ``X``, ``y`` (1-D or
2-D), and optionally a ``keys`` frame that says where each row comes from (``trial`` + ``t_ns`` by default)
so that the guard can prove no test fold touches its training rows or the tuning block.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from scipy.optimize import nnls
from sklearn.base import clone
from sklearn.metrics import mean_absolute_error, r2_score
from sklearn.model_selection import KFold

from pipeline.errors import ModelError, PipelineError

log = logging.getLogger(__name__)

__all__ = ["SPLITS", "split_blocks", "blocked_folds", "trial_folds", "search_folds", "trial_groups",
           "MIN_TRIAL_ROWS", "check_no_leakage", "regression_scores", "base_predictor",
           "cross_validate_blocked", "fit_fold", "guarded_folds", "summarize_folds", "score_holdout", "MODEL_FAILURES",
           "model_failure", "INTERVAL_LEVEL", "conformal_half_width", "sd_floor", "interval_half_width",
           "scale_fit"]

#: What one model's fit or evaluation may raise without stopping a study: the pipeline's own errors and numerical
#: errors from numpy / scipy / scikit-learn (LinAlgError is a ValueError). Never KeyboardInterrupt or MemoryError.
MODEL_FAILURES: tuple[type[Exception], ...] = (PipelineError, ValueError, ArithmeticError, RuntimeError)


def model_failure(model: str, err: Exception, **where: str) -> dict[str, str]:
    """A failed model as a report entry: ``{"model", "error" (exception type), "reason"}`` (+ ``where``)."""
    return {"model": model, **where, "error": type(err).__name__, "reason": str(err)}

SPLITS = ("tuning", "train_test", "test")


def split_blocks(frame: pd.DataFrame, column: str = "split") -> dict[str, pd.DataFrame]:
    """The rows of each split label (``tuning``, ``train_test``, ``test``), original order kept."""
    if column not in frame.columns:
        raise ModelError(f"feature table has no {column!r} column; columns: {list(frame.columns)}")
    unknown = set(frame[column].unique()) - set(SPLITS)
    if unknown:
        raise ModelError(f"unknown split label(s) {sorted(unknown)}; expected {list(SPLITS)}")
    return {name: frame[frame[column] == name] for name in SPLITS}


def blocked_folds(n_samples: int, n_folds: int = 5) -> list[tuple[np.ndarray, np.ndarray]]:
    """Unshuffled k-fold on contiguous blocks (``KFold(shuffle=False)``): list of (train_idx, test_idx)."""
    if n_samples < 2 * n_folds:
        raise ModelError(f"{n_samples} samples are too few for {n_folds}-fold CV")
    return list(KFold(n_splits=n_folds, shuffle=False).split(np.arange(n_samples)))


#: A trial with fewer of a search's rows is no fold of its own (:func:`trial_folds`: it joins its neighbour) and
#: does not count towards ``coupled.tuning_cv: auto``'s two trials (:func:`trial_groups`).
MIN_TRIAL_ROWS = 20


def trial_groups(trials: Sequence[Any], mode: str = "auto", min_rows: int = MIN_TRIAL_ROWS) -> np.ndarray | None:
    """The search folds' groups of rows labelled ``trials`` (one label a row): each row's trial as an integer code
    in order of first appearance, or None for blocked folds. ``mode``: ``blocked`` (None), ``trials`` (the codes;
    a ModelError unless two trials have ``min_rows`` rows each), ``auto`` (the codes where two trials do, else
    None)."""
    if mode not in ("auto", "blocked", "trials"):
        raise ModelError(f"unknown search CV {mode!r}; expected 'auto', 'blocked' or 'trials'")
    if mode == "blocked":
        return None
    codes = pd.factorize(pd.Series(list(trials), dtype=object), sort=False)[0].astype(np.int64)
    enough = int(np.sum(np.bincount(codes) >= min_rows)) if codes.size else 0
    if enough >= 2:
        return codes
    if mode == "trials":
        raise ModelError(f"coupled.tuning_cv: trials needs two training trials with at least {min_rows} of the "
                         f"search's rows each; got {enough} (use auto or blocked)")
    return None


def trial_folds(groups: np.ndarray, n_folds: int = 5, min_rows: int = MIN_TRIAL_ROWS
                ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Folds that hold out whole trials: ``groups`` (one integer a row, its trial) taken in order of first
    appearance, a trial of fewer than ``min_rows`` rows joined to the one before it (the first to the next); one
    fold per trial (leave-one-trial-out) where there are no more than ``n_folds``, else the trials in ``n_folds``
    contiguous groups balanced by rows (a trial goes to the fold its middle row falls in). Each fold: (train_idx,
    test_idx), both sorted."""
    groups = np.asarray(groups)
    order = list(dict.fromkeys(groups.tolist()))
    rows = {g: int(np.sum(groups == g)) for g in order}
    units: list[list[Any]] = []
    for g in order:
        if units and (rows[g] < min_rows or sum(rows[h] for h in units[-1]) < min_rows):
            units[-1].append(g)
        else:
            units.append([g])
    if len(units) < 2:
        raise ModelError(f"trial folds need two trials of at least {min_rows} rows; got {rows}")
    if len(units) > n_folds:
        sizes = np.array([sum(rows[g] for g in u) for u in units], dtype=float)
        middle = np.cumsum(sizes) - sizes / 2.0
        which = np.minimum((middle * n_folds / sizes.sum()).astype(int), n_folds - 1)
        units = [[g for u, w in zip(units, which, strict=True) if w == k for g in u] for k in sorted(set(which))]
    folds = []
    for unit in units:
        held = np.isin(groups, unit)
        folds.append((np.flatnonzero(~held), np.flatnonzero(held)))
    return folds


def search_folds(n_samples: int, n_folds: int, groups: np.ndarray | None = None
                 ) -> list[tuple[np.ndarray, np.ndarray]]:
    """A search's folds: :func:`trial_folds` of ``groups`` (one a row) where given, else :func:`blocked_folds`."""
    if groups is None:
        return blocked_folds(n_samples, n_folds)
    if len(groups) != n_samples:
        raise ModelError(f"{len(groups)} trial labels for {n_samples} rows")
    return trial_folds(groups, n_folds)


def _key_frame(keys: pd.DataFrame, group: str, time_col: str) -> pd.DataFrame:
    missing = [c for c in (group, time_col) if c not in keys.columns]
    if missing:
        raise ModelError(f"leakage guard needs key columns {missing}; got {list(keys.columns)}")
    return keys[[group, time_col]].reset_index(drop=True)


def check_no_leakage(train: pd.DataFrame, test: pd.DataFrame, tuning: pd.DataFrame | None = None, *,
                     group: str = "trial", time_col: str = "t_ns") -> None:
    """Raise :class:`ModelError` if the test rows overlap the training rows or the tuning block.

    Two checks, per ``group`` (trial): no (group, time) row id is shared, and no training / tuning sample lies
    inside the time span of the test rows (which catches shuffled or interleaved folds).
    """
    test_k = _key_frame(test, group, time_col)
    others = [("training", train)] + ([("tuning", tuning)] if tuning is not None else [])
    spans = test_k.groupby(group, sort=False)[time_col].agg(["min", "max"])
    test_ids = pd.MultiIndex.from_frame(test_k)
    for label, other in others:
        other_k = _key_frame(other, group, time_col)
        shared = test_ids.intersection(pd.MultiIndex.from_frame(other_k))
        if len(shared):
            raise ModelError(f"leakage: {len(shared)} test row(s) also in the {label} data, e.g. {shared[0]}")
        merged = other_k.merge(spans, left_on=group, right_index=True, how="inner")
        inside = merged[(merged[time_col] >= merged["min"]) & (merged[time_col] <= merged["max"])]
        if len(inside):
            row = inside.iloc[0]
            raise ModelError(f"leakage: {len(inside)} {label} sample(s) inside the test time span of "
                             f"{group} {row[group]!r} (t={row[time_col]} in [{row['min']}, {row['max']}])")


def regression_scores(y_true: np.ndarray, y_pred: np.ndarray, outputs: Sequence[str] | None = None
                      ) -> dict[str, dict[str, float]]:
    """R² and MAE per output column: ``{output: {"r2": .., "mae": ..}}``."""
    yt = np.asarray(y_true, dtype=float).reshape(len(y_true), -1)
    yp = np.asarray(y_pred, dtype=float).reshape(len(y_pred), -1)
    names = list(outputs) if outputs is not None else [f"y{k}" for k in range(yt.shape[1])]
    if len(names) != yt.shape[1]:
        raise ModelError(f"{len(names)} output names for {yt.shape[1]} output columns")
    return {name: {"r2": float(r2_score(yt[:, k], yp[:, k])), "mae": float(mean_absolute_error(yt[:, k], yp[:, k]))}
            for k, name in enumerate(names)}


def fit_fold(estimator: Any, X: np.ndarray, y: np.ndarray, train: np.ndarray, test: np.ndarray,
             outputs: Sequence[str] | None, *, predictions: bool = False,
             fitted: tuple[Any, float] | None = None) -> dict[str, Any]:
    """A clone of ``estimator`` fitted on the ``train`` rows: its scores on them and on the ``test`` rows, times,
    sizes and the test block's span; with ``predictions`` also its predictions of the ``test`` rows
    (``test_pred``, the out-of-fold predictions a conformal interval is calibrated on) and, for a gray box, its
    base's scores and test predictions (``base``: ``train``, ``test``, ``test_pred``). ``fitted``: ``(the
    estimator fitted on the train rows elsewhere, its fit's seconds)`` instead of a fit here."""
    if fitted is None:
        est = clone(estimator)
        t0 = time.perf_counter()
        est.fit(X[train], y[train])
        fit_s = time.perf_counter() - t0
    else:
        est, fit_s = fitted
    t1 = time.perf_counter()
    pred_test = est.predict(X[test])
    t2 = time.perf_counter()
    pred_train = est.predict(X[train])
    out = {"train": regression_scores(y[train], pred_train, outputs),
           "test": regression_scores(y[test], pred_test, outputs),
           "fit_time_s": fit_s, "predict_time_s": t2 - t1,
           "n_train": int(train.size), "n_test": int(test.size),
           "test_start": int(test[0]), "test_stop": int(test[-1]) + 1}
    if predictions:
        out["test_pred"] = np.asarray(pred_test, dtype=float).reshape(int(test.size), -1)
        base = base_predictor(est)
        if base is not None:  # a gray box's base alone, fitted inside it: the paired verdict's other half
            base_test = np.asarray(base(X[test]), dtype=float).reshape(int(test.size), -1)
            out["base"] = {"train": regression_scores(y[train], base(X[train]), outputs),
                           "test": regression_scores(y[test], base_test, outputs), "test_pred": base_test}
    return out


def base_predictor(estimator: Any) -> Callable[[np.ndarray], np.ndarray] | None:
    """A fitted gray box's ``base_predict`` (its own, or a nested fold's inner model's); None for other models."""
    return getattr(getattr(estimator, "estimator_", estimator), "base_predict", None)


def guarded_folds(n_samples: int, n_folds: int, keys: pd.DataFrame | None = None,
                  tuning_keys: pd.DataFrame | None = None, *, group: str = "trial", time_col: str = "t_ns"
                  ) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`blocked_folds`, each passed by the leakage guard (:func:`check_no_leakage`) when ``keys`` (one row per
    sample) are given."""
    folds = blocked_folds(n_samples, n_folds)
    if keys is not None:
        if len(keys) != n_samples:
            raise ModelError(f"keys have {len(keys)} rows, X has {n_samples}")
        keys = keys.reset_index(drop=True)
        for train, test in folds:
            check_no_leakage(keys.iloc[train], keys.iloc[test], tuning_keys, group=group, time_col=time_col)
    return folds


def cross_validate_blocked(estimator: Any, X: np.ndarray, y: np.ndarray, *, n_folds: int = 5,
                           keys: pd.DataFrame | None = None, tuning_keys: pd.DataFrame | None = None,
                           outputs: Sequence[str] | None = None, n_jobs: int | None = 1,
                           group: str = "trial", time_col: str = "t_ns",
                           progress: Callable[..., Any] | None = None) -> list[dict[str, Any]]:
    """Unshuffled blocked k-fold CV. Every fold passes the leakage guard (when ``keys`` are given) first.
    ``progress(done, total, desc)`` (optional) is called as each fold's result arrives (in fold order).

    Returns one dict per fold: ``train`` / ``test`` scores per output, fit / predict time, sizes, test block.
    """
    X = np.asarray(X, dtype=float)
    y = np.asarray(y, dtype=float)
    folds = guarded_folds(len(X), n_folds, keys, tuning_keys, group=group, time_col=time_col)
    jobs = (delayed(fit_fold)(estimator, X, y, tr, te, outputs) for tr, te in folds)
    if progress is None:
        results = Parallel(n_jobs=n_jobs)(jobs)
    else:  # the same work, results taken as they come (in order) to move the bar
        results = []
        for res in Parallel(n_jobs=n_jobs, return_as="generator")(jobs):
            results.append(res)
            progress(len(results), len(folds), f"fold {len(results)}/{len(folds)}")
    for k, res in enumerate(results):
        res["fold"] = k
    return list(results)


def summarize_folds(folds: Sequence[dict[str, Any]]) -> dict[str, dict[str, dict[str, float]]]:
    """Mean and SD (ddof=1) over folds: ``{output: {"train_r2": {"mean", "sd"}, "test_r2": .., "train_mae": ..}}``."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    for output in folds[0]["test"]:
        out[output] = {}
        for part in ("train", "test"):
            for metric in ("r2", "mae"):
                vals = np.array([f[part][output][metric] for f in folds])
                out[output][f"{part}_{metric}"] = {"mean": float(vals.mean()),
                                                   "sd": float(vals.std(ddof=1)) if vals.size > 1 else 0.0}
    return out


def score_holdout(model: Any, X: np.ndarray, y: np.ndarray, outputs: Sequence[str] | None = None
                  ) -> dict[str, dict[str, float]]:
    """Scores of a fitted model on a held-out block (the final check on an unseen trial)."""
    return regression_scores(y, model.predict(np.asarray(X, dtype=float)), outputs)


#: The prediction intervals' nominal coverage.
INTERVAL_LEVEL = 0.9


def conformal_half_width(abs_residuals: np.ndarray, level: float = INTERVAL_LEVEL) -> float:
    """The split-conformal half-width: the ``ceil((n + 1) level)``-th smallest of ``n`` absolute out-of-fold
    residuals (the largest where ``n`` is too small for ``level``, with a warning)."""
    r = np.sort(np.asarray(abs_residuals, dtype=float))
    if r.size == 0:
        raise ModelError("no out-of-fold residuals to calibrate an interval with")
    k = int(np.ceil((r.size + 1) * level))
    if k > r.size:
        log.warning("%d residuals are too few for a %.0f %% conformal interval; the largest is used", r.size,
                    100 * level)
    return float(r[min(k, r.size) - 1])


def sd_floor(sd: np.ndarray) -> np.ndarray:
    """SDs kept away from 0 (a thousandth of their median), so a normalized score stays finite."""
    return np.maximum(sd, 1e-3 * float(np.median(sd)) + 1e-300)


def scale_fit(scores: Sequence[np.ndarray], covariates: Sequence[np.ndarray]) -> tuple[list[float], float]:
    """A locally weighted split-conformal interval (Lei, G'Sell, Rinaldo, Tibshirani & Wasserman, JASA 113 (2018)
    1094, §5.2): a row's spread s = z' c, c >= 0, fitted by non-negative least squares of the out-of-fold
    ``scores`` (|residual|) on the rows' ``covariates`` z (rows, m; >= 0: a column of ones for a constant part,
    |prediction| for a part that grows with it), then q the conformal quantile of ``|residual| / s``, the wider
    over the residual sets given (one array each: blocked folds, held-out trials). Returns (c, q); a row's
    half-width is q z' c. The first coefficient is kept above 0 so that no spread is 0."""
    r = np.concatenate(list(scores))
    c = nnls(np.concatenate(list(covariates)), r)[0]
    c[0] = max(float(c[0]), 1e-3 * float(np.mean(r)) + 1e-300)
    q = max(conformal_half_width(sc / (z @ c)) for sc, z in zip(scores, covariates, strict=True))
    return [float(x) for x in c], q


def interval_half_width(interval: dict[str, Any], sd: np.ndarray | None, pred: np.ndarray | None = None
                        ) -> np.ndarray | float:
    """The half-width of each row's interval: ``half_width_sd * sd`` for a normalized interval
    (``scale == "target_sd"``) where the rows' SDs are known; ``half_width_scaled * (c_0 + c_1 |pred|)`` for one
    whose spread grows with the prediction (``scale == "prediction"``, ``spread`` = [c_0, c_1]) where the rows'
    predictions are given; else the typical ``half_width``."""
    if interval.get("scale") == "target_sd" and sd is not None:
        return interval["half_width_sd"] * sd_floor(sd)
    if interval.get("scale") == "prediction" and pred is not None:
        c0, c1 = interval["spread"]
        return interval["half_width_scaled"] * (c0 + c1 * np.abs(np.asarray(pred, dtype=float)))
    return float(interval["half_width"])
