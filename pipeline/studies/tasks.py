"""The coupled study's independent units of work, run through one executor (:func:`pipeline.parallel.imap`).

* tune: one coroutine (:mod:`pipeline.rounds`) per output for the SVRs' warm-start chain (RBF -> 2-weights -> WDSE,
  each search started from the simpler kernel's optimum), and one per gray box and output for its residual's chain.
  Each asks for its searches' rounds of tasks (a GP's seeds or proposals; every candidate and fold of a round), and
  the rounds of all chains go to one executor at once: the stage's critical path is one chain's rounds, each as
  long as its slowest fit, not eighteen searches one after the other.
* train: one coroutine per model and CV fold: a nested fold's local searches in rounds, then one task for its fit,
  scores and test block's predictions (the conformal interval's out-of-fold residuals); one task per model's final
  fit (with its check on the test trials).

Every task runs under one BLAS thread, inline or in a worker, and takes contiguous copies of its arrays: the same
task gives the same bits serially, in a forked pool or on a Dask worker (``tests/studies/test_parallel_study.py``).
Each task's wall and CPU time go to :func:`pipeline.parallel.record_task` with the round it waited for
(``bench/span.py`` reads them).
"""

from __future__ import annotations

import copy
import hashlib
import json
import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from sklearn.base import clone

from pipeline.evaluate import MODEL_FAILURES, base_predictor, fit_fold, model_failure, regression_scores
from pipeline.models.search import Rounds, SearchResult, SearchSettings
from pipeline.models.search_halving import search_rounds
from pipeline.rounds import drive, run_inline

log = logging.getLogger(__name__)


def tune_chains(chains: Sequence[dict[str, Any]], settings: SearchSettings, jobs: int,
                progress: Callable[..., Any] | None = None) -> list[list[Any]]:
    """Run each chain of warm-started searches (``{"label", "models": [kernel, ...], "names": [each search's name
    on the progress bar, or None], "X", "y", "cache", "groups": each row's trial for folds that hold out whole
    trials, or None}``; other keys are carried), each through the chain's
    :class:`SearchCache`; returns, per chain in order, its searches'
    :class:`~pipeline.models.search.SearchResult` in chain order. ``jobs`` workers for the chains' tasks
    (1: inline, with each search's candidates on ``progress``; more, or -1 on a Dask cluster: ``progress`` moves as
    each chain ends)."""
    settings = replace(settings, n_jobs=1)  # the searches' tasks go to this function's executor
    items = [{**c, "X": np.ascontiguousarray(c["X"], dtype=float), "settings": settings,
              **({"y": np.ascontiguousarray(c["y"], dtype=float)} if "y" in c else {})} for c in chains]
    if jobs == 1:  # each search that has a name (``names``, None: a warm start only) moves the bar by its candidates
        total = sum(n is not None for item in items for n in item.get("names", item["models"]))
        k = 0
        for item in items:
            labels = []
            for name in item.get("names", item["models"]):
                k += name is not None
                labels.append(None if name is None else _labelled(progress, f"{name} ({k}/{total})"))
            item["progress"] = labels
    finished = [0]

    def chain_done(index: int, _: Any) -> None:
        finished[0] += 1
        if progress is not None and jobs > 1:
            progress(finished[0], len(items), f"{items[index]['label']} ({finished[0]}/{len(items)} chains)")

    return drive([_run_chain(item) for item in items], jobs=jobs, stage="tune",
                 labels=[item["label"] for item in items], on_done=chain_done)


def fitted(estimator: Any, X: np.ndarray, y: np.ndarray) -> Any:
    """``estimator.fit(X, y)``: a task of :mod:`pipeline.rounds` (a gray box's base, off the driver)."""
    return estimator.fit(X, y)


def _labelled(progress: Callable[..., Any] | None, label: str) -> Callable[..., Any] | None:
    if progress is None:
        return None
    return lambda done, total=None, desc=None: progress(done, total, f"{label} {desc or ''}".rstrip())


def _run_chain(item: dict[str, Any]) -> Any:
    """A chain's searches in order, each warm-started from the one before: a coroutine of :mod:`pipeline.rounds`
    returning their results."""
    cache = item.get("cache") or SearchCache()
    if "residual_of" in item:  # a gray box's residual: its base fitted (a task), then y = Y - base(X) of output k
        base, X_fit, Y_fit, X_base, Y, k = item["residual_of"]
        (base,) = yield [(fitted, (base, X_fit, Y_fit))]
        item["y"] = np.ascontiguousarray((Y - base.predict(X_base))[:, k], dtype=float)
    warm, out = None, []
    bars = item.get("progress") or [None] * len(item["models"])
    for model, bar in zip(item["models"], bars, strict=True):
        res = yield from cache.search_rounds(model, item["X"], item["y"], item["settings"], warm_start=warm,
                                             progress=bar, groups=item.get("groups"))
        warm = res.best_params if item["settings"].method == "fast" else None
        out.append(res)
    return out


class SearchCache:
    """The searches of one stage run by their inputs, the newest ``kept``: :meth:`search` runs each once.

    Nested tuning searches each CV fold once per model, and a model's fast search runs the simpler kernels' chain
    first: in one fold the WDSE's chain repeats the RBF and 2-weights searches that the RBF and 2-weights models of
    that fold ran, on the same rows with the same settings. A search is deterministic in its inputs, so the repeat
    gives the result the first gave (a copy of it; its log lines are not given twice). ``progress`` is not an input.

    A stage's function creates one and passes it down. The estimators of the CV folds hold it (:class:`NestedTuned`):
    ``clone``'s deep copy keeps this same cache, a pickled copy (a joblib worker's) starts empty.
    """

    def __init__(self, kept: int = 64) -> None:
        self.kept = kept
        self._results: dict[str, SearchResult] = {}

    def __deepcopy__(self, memo: dict[int, Any]) -> SearchCache:
        return self

    def __reduce__(self) -> tuple[type[SearchCache], tuple[int]]:
        return SearchCache, (self.kept,)

    def search(self, model: str, X: np.ndarray, y: np.ndarray, settings: SearchSettings, *,
               warm_start: dict[str, Any] | None = None, progress: Callable[..., Any] | None = None,
               groups: np.ndarray | None = None) -> SearchResult:
        """:meth:`search_rounds` run inline."""
        return run_inline(self.search_rounds(model, X, y, settings, warm_start=warm_start, progress=progress,
                                             groups=groups))

    def search_rounds(self, model: str, X: np.ndarray, y: np.ndarray, settings: SearchSettings, *,
                      warm_start: dict[str, Any] | None = None, progress: Callable[..., Any] | None = None,
                      groups: np.ndarray | None = None) -> Rounds:
        """:func:`~pipeline.models.search.search` with ``settings`` (and a simpler kernel's optimum as
        ``warm_start``: fast search only; ``groups``, each row's trial: folds that hold out whole trials), or the
        result of the same search run before; a coroutine of :mod:`pipeline.rounds`."""
        kw = settings.keywords()
        if warm_start is not None:
            kw["warm_start"] = warm_start
        if groups is not None:
            kw["groups"] = np.asarray(groups, dtype=np.int64).tolist()  # in the key; an array again below
        # the layout too: a strided column (a residual's) sums in another order than a contiguous copy of it, and a
        # search's choices can turn on the last bit
        layout = [(np.asarray(v).shape, np.asarray(v).strides, str(np.asarray(v).dtype)) for v in (X, y)]
        h = hashlib.sha256(json.dumps([model, settings.method, layout, kw], sort_keys=True, default=repr).encode())
        for values in (X, y):
            h.update(np.ascontiguousarray(values, dtype=float).tobytes())
        key = h.hexdigest()
        result = self._results.get(key)
        if result is None:
            if groups is not None:
                kw["groups"] = np.asarray(groups, dtype=np.int64)
            result = yield from search_rounds(model, X, y, settings.method, progress=progress, **kw)
            self._results[key] = result
            while len(self._results) > self.kept:
                del self._results[next(iter(self._results))]
        else:
            log.debug("%s search on %d rows: the same inputs as an earlier search of this run, its result", model,
                      len(X))
        return copy.deepcopy(result)


#: The train stage's tasks that fit on some rows and predict the others: a CV fold, a fit without whole trials.
_TASK_NAMES = {"fold": "fold", "trial": "without trials"}


def train_tasks(jobs_spec: Sequence[dict[str, Any]], jobs: int,
                progress: Callable[..., Any] | None = None,
                on_task: Callable[[int, dict[str, Any]], None] | None = None) -> list[dict[str, Any]]:
    """Run the train stage's tasks: each ``{"model", "kind": "fold" | "trial" | "final", "estimator", "X", "y",
    ...}`` (a fold, or a fit without whole trials: ``train`` / ``test`` row indices and ``fold``; the final fit:
    ``X_test`` / ``y_test`` or None).
    Returns per task in order ``{"fold": scores, "pred"}`` / ``{"pred"}`` / ``{"estimator", "final", "pred"}``
    (``pred``: the predictions of the fold's or the held-out trials' rows / of ``X_test``; a gray box's also
    ``base``: its base's ``pred`` alone, and a fold's base ``scores``), or ``{"failed":
    entry}`` when the model raised one of :data:`~pipeline.evaluate.MODEL_FAILURES` (:func:`model_failure`'s entry).
    ``on_task(index, result)`` as each task ends (completion order). Each is a coroutine of
    :mod:`pipeline.rounds`: a fold whose estimator searches its own hyperparameters (``tune_rounds``, the nested
    CV's) runs that search in rounds; a fit of one regressor per output (``output_tasks``: a nested fold's, or a
    final fit) fits each output as a task; then the fold's or the final fit's scores are one task; the rest are one
    task each."""
    names = [f"{s['model']} {_TASK_NAMES[s['kind']]} {s['fold'] + 1}/{s['folds']}" if s["kind"] in _TASK_NAMES
             else f"{s['model']} final fit" for s in jobs_spec]
    finished = [0]

    def task_done(index: int, res: dict[str, Any]) -> None:
        finished[0] += 1
        if progress is not None:
            progress(finished[0], len(jobs_spec), names[index])
        if on_task is not None:
            on_task(index, res)

    return drive([_train_rounds(dict(spec)) for spec in jobs_spec], jobs=jobs, stage="train", labels=names,
                 on_done=task_done)


def _seconds(fn: Callable[..., Any], *args: Any) -> tuple[Any, float]:
    """``fn(*args)`` and its wall seconds (a fold's fit time, summed over its outputs' tasks)."""
    t0 = time.perf_counter()
    return fn(*args), time.perf_counter() - t0


def _train_rounds(spec: dict[str, Any]) -> Any:
    est = spec["estimator"]
    if spec["kind"] == "fold" and hasattr(est, "tune_rounds"):
        X = np.ascontiguousarray(spec["X"], dtype=float)[spec["train"]]
        y = np.ascontiguousarray(spec["y"], dtype=float)[spec["train"]]
        groups = spec.get("groups")  # the fold's training rows' trials: its search's folds
        try:
            preset = yield from est.tune_rounds(X, y, None if groups is None else np.asarray(groups)[spec["train"]])
            spec["estimator"] = clone(est).set_params(preset=preset)
            inner = spec["estimator"].built(preset[0])
            if hasattr(inner, "output_tasks"):  # the fold's fit, one task per output, as fit_fold would fit it
                done = yield [(_seconds, (fn, *args)) for fn, args in inner.output_tasks(X, y)]
                spec["fitted"] = (inner.join(X, y, [e for e, _ in done]), float(sum(s for _, s in done)))
        except MODEL_FAILURES as err:
            return {"failed": model_failure(spec["model"], err)}
    elif spec["kind"] == "final" and hasattr(est, "output_tasks"):  # one task per output, then its scores
        X = np.ascontiguousarray(spec["X"], dtype=float)
        y = np.ascontiguousarray(spec["y"], dtype=float)
        whole = clone(est)
        try:
            spec["estimator"] = whole.join(X, y, (yield whole.output_tasks(X, y)))
        except MODEL_FAILURES as err:
            return {"failed": model_failure(spec["model"], err)}
        spec["final_fitted"] = True
    elif spec["kind"] == "final" and hasattr(est, "interval_tasks"):  # the fit, then its bootstrap in chunks
        X = np.ascontiguousarray(spec["X"], dtype=float)
        y = np.ascontiguousarray(spec["y"], dtype=float)
        try:
            whole, = yield [(fitted, (clone(est), X, y))]
            plan, tasks = whole.interval_tasks(X, y)
            spec["estimator"] = whole.join_intervals(plan, (yield tasks))
        except MODEL_FAILURES as err:
            return {"failed": model_failure(spec["model"], err)}
        spec["final_fitted"] = spec["intervals_fitted"] = True
    done, = yield [(_run_train_task, (spec,))]
    return done


def _run_train_task(spec: dict[str, Any]) -> dict[str, Any]:
    X, y = np.ascontiguousarray(spec["X"], dtype=float), np.ascontiguousarray(spec["y"], dtype=float)
    try:
        if spec["kind"] == "trial":  # a fit without whole trials: only its held-out rows' predictions (interval)
            est = clone(spec["estimator"]).fit(X[spec["train"]], y[spec["train"]])
            return {"pred": _rows(est.predict(X[spec["test"]]), len(spec["test"])),
                    **_base(est, X[spec["test"]], len(spec["test"]))}
        if spec["kind"] == "fold":  # its test block's predictions calibrate the conformal interval
            scores = fit_fold(spec["estimator"], X, y, spec["train"], spec["test"], spec["outputs"], predictions=True,
                              fitted=spec.get("fitted"))
            pred = scores.pop("test_pred")
            base = scores.pop("base", None)
            return {"fold": {**scores, "fold": spec["fold"]}, "pred": pred,
                    **({} if base is None else {"base": {"scores": base, "pred": base["test_pred"]}})}
        est = spec["estimator"] if spec.get("final_fitted") else spec["estimator"].fit(X, y)
        if hasattr(est, "fit_intervals") and not spec.get("intervals_fitted"):  # block-bootstrap intervals (card)
            est.fit_intervals(X, y)
        if spec["X_test"] is None:
            return {"estimator": est, "final": None, "pred": None}
        X_test = np.ascontiguousarray(spec["X_test"], dtype=float)
        pred = est.predict(X_test)
        final = regression_scores(np.ascontiguousarray(spec["y_test"], dtype=float), pred, spec["outputs"])
        return {"estimator": est, "final": final, "pred": pred, **_base(est, X_test, len(X_test))}
    except MODEL_FAILURES as err:
        return {"failed": model_failure(spec["model"], err)}


def _rows(pred: Any, n: int) -> np.ndarray:
    return np.asarray(pred, dtype=float).reshape(n, -1)


def _base(estimator: Any, X: np.ndarray, n: int) -> dict[str, Any]:
    """``{"base": {"pred": ...}}``: a fitted gray box's base alone on ``X`` (the paired verdict's, which puts it in
    place of the gray box on an output whose residual it drops); {} for other models."""
    base = base_predictor(estimator)
    return {} if base is None else {"base": {"pred": _rows(base(X), n)}}
