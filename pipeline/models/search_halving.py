"""Successive halving for the fast search: candidates screened on some folds (or rows), survivors on all of them.

:func:`halving_search` runs :func:`pipeline.models.search.fast_search` (its whole budget of ``max_evals``
candidates: GP seeds, warm start, exploration, model steps, pattern search) on a screen, then scores its
``survivors`` best distinct candidates, and the warm start, on every fold and row it was given; the best of those
by the mean over all folds is the result, so the choice is made by the same score as without a screen.

* ``screen_folds`` (the default, ``coupled.screen_folds``): the screen scores each candidate on that many of the
  blocked folds (spread over the block, :func:`fold_subset`); a survivor then fits only the folds the screen left
  out. 30 candidates on 2 of 5 folds and 6 survivors on the other 3 are 78 fits instead of 150, each on as many
  rows as before (so C means what it meant).
* ``screen_rows`` (off by default, ``coupled.screen_samples``): the screen sees that many rows evenly spaced in
  time, the survivors every row. C moves between the rungs as the final fit moves it
  (:func:`pipeline.models.svr.scaled_C`, ``c_rate``): a candidate's C on the screen's rows becomes
  ``C (screen rows / rows) ** c_rate`` on all rows; the warm start (chosen on all rows) is moved the other way.

Why folds and not rows by default, and what each did to the demo: docs/models.md, "Successive halving".
"""

from __future__ import annotations

import logging
import time
from typing import Any

import numpy as np

from pipeline.errors import ModelError
from pipeline.evaluate import search_folds
from pipeline.models.search import (
    Rounds,
    SearchResult,
    _cap,
    _check_xy,
    _driven,
    _expand,
    _names,
    _to_params,
    fast_search_rounds,
    fit_task,
    with_C_rows,
)
from pipeline.models.search import search_rounds as plain_search
from pipeline.models.search_choice import smoothest_within
from pipeline.models.search_cost import ITER_CAP_RATIO, ITER_PER_ROW, candidate_entry, cost_summary
from pipeline.models.svr import scaled_C

log = logging.getLogger(__name__)

__all__ = ["HALVING_KEYS", "fold_subset", "halving_search", "halving_search_rounds", "screen_index", "search",
           "search_rounds"]

HALVING_KEYS = ("screen_rows", "screen_folds", "survivors", "c_rate")  # search(): the halving's own keywords


def search_rounds(model: str, X: np.ndarray, y: np.ndarray, method: str = "fast", **kw: Any) -> Rounds:
    """:func:`pipeline.models.search.search_rounds`, or with ``method="fast"`` and ``screen_rows`` or
    ``screen_folds`` given, :func:`halving_search_rounds` (its best parameters with ``C_rows`` as well). The
    halving's keywords (:data:`HALVING_KEYS`) are taken here; the others go to the search as they are."""
    halving = {k: kw.pop(k) for k in HALVING_KEYS if k in kw}
    if method != "fast" or (halving.get("screen_rows") is None and halving.get("screen_folds") is None):
        return (yield from plain_search(model, X, y, method, **kw))
    return with_C_rows((yield from halving_search_rounds(model, X, y, **halving, **kw)), len(X))


def screen_index(n_rows: int, screen_rows: int) -> np.ndarray:
    """``screen_rows`` row indices evenly spaced over ``n_rows`` (all of them when there are no more)."""
    return np.unique(np.linspace(0, n_rows - 1, min(screen_rows, n_rows)).round().astype(int))


def _train_rows(n_rows: int, n_folds: int, groups: np.ndarray | None) -> float:
    return float(np.mean([len(tr) for tr, _ in search_folds(n_rows, n_folds, groups)]))


def _key(model: str, params: dict[str, Any], n_features: int, n_velocity: int) -> tuple[float, ...]:
    return tuple(np.round(np.log(_expand(model, params, n_features, n_velocity)), 6))


def fold_subset(n_folds: int, k: int) -> list[int]:
    """``k`` of ``n_folds`` folds spread over the block (2 of 5: folds 1 and 3): blocked folds, or the trials'."""
    return sorted({int((i + 0.5) * n_folds / k) for i in range(k)})


def halving_search_rounds(model: str, X: np.ndarray, y: np.ndarray, *, screen_rows: int | None = None,
                          screen_folds: int | None = None, survivors: int = 6, c_rate: float = 0.5,
                          **kw: Any) -> Rounds:
    """The fast search's candidates screened on ``screen_rows`` rows and/or ``screen_folds`` of its folds, its
    ``survivors`` best (and the warm start) then scored on all rows of ``X`` and all folds; ``kw``:
    :func:`~pipeline.models.search.fast_search`'s keywords (its ``groups``, each row's trial: the folds hold out
    whole trials, the screen's rows keep their trials, ``screen_folds`` counts the trials' folds). With nothing to
    screen (no more rows than ``screen_rows``, no fewer folds than ``n_folds``) it is the fast search itself. A fold
    screen on all rows keeps its fits: a survivor fits only the folds the screen left out.

    The result's ``best_score`` and choice are the last rung's; its ``trace`` holds both rungs (``rung`` 0 and 1,
    each entry's ``n_rows``), ``halving`` says what each rung saw, ``warm_start_kept`` whether the warm start won
    the last rung, ``budget_exhausted`` the screen's (its pattern search ran out of candidates). A coroutine of
    :mod:`pipeline.rounds` (:func:`halving_search` runs it): the survivors are one round."""
    X, y = _check_xy(X, y)
    n_velocity, groups = kw.get("n_velocity", 3), kw.get("groups")
    folds = search_folds(len(X), kw.get("n_folds", 3), groups)
    n_folds = len(folds)  # the trials' folds may be fewer than asked
    if (screen_rows is not None and screen_rows < 2) or survivors < 1 or (screen_folds is not None
                                                                          and screen_folds < 1):
        raise ModelError(f"successive halving needs screen_rows >= 2, screen_folds >= 1 and survivors >= 1, got "
                         f"{screen_rows}, {screen_folds} and {survivors}")
    by_rows = screen_rows is not None and len(X) > screen_rows
    by_folds = screen_folds is not None and screen_folds < n_folds
    if not (by_rows or by_folds):
        return (yield from fast_search_rounds(model, X, y, **kw))
    t0 = time.perf_counter()
    iter_per_row = kw.get("iter_per_row", ITER_PER_ROW)
    idx = screen_index(len(X), screen_rows) if by_rows else np.arange(len(X))
    screen_groups = None if groups is None else np.asarray(groups)[idx]
    n_screen = len(search_folds(len(idx), kw.get("n_folds", 3), screen_groups)) if by_rows else n_folds
    subset = fold_subset(n_screen, screen_folds) if by_folds and screen_folds < n_screen else None
    rows_screen = _train_rows(len(idx), kw.get("n_folds", 3), screen_groups)
    rows_all = float(np.mean([len(tr) for tr, _ in folds]))
    warm = kw.get("warm_start")
    if warm is not None and by_rows:  # chosen on all rows (C_rows): its C as the screen's rows would use it
        warm = {**warm, "C": scaled_C(warm["C"], warm.get("C_rows") or round(rows_all), round(rows_screen), c_rate)}
        warm.pop("C_rows", None)
        kw = {**kw, "warm_start": warm}
    kw = {**kw, "groups": screen_groups}
    screen = yield from fast_search_rounds(model, X[idx], y[idx], report_kept=False, fold_subset=subset, **kw)

    # the survivors: the screen's best distinct candidates in score order (the first of equal scores first), then
    # the warm start, so that the richer kernel is never chosen below the simpler one on all rows either
    d = X.shape[1]
    order = sorted(range(len(screen.trace)), key=lambda k: -screen.trace[k]["score"])
    picked: dict[tuple[float, ...], dict[str, Any]] = {}
    for k in order:
        if len(picked) >= survivors:
            break
        picked.setdefault(_key(model, screen.trace[k]["params"], d, n_velocity), screen.trace[k])
    warm_key = None
    if warm is not None:
        warm_key = _key(model, warm, d, n_velocity)
        picked.setdefault(warm_key, next((t for t in screen.trace if _key(model, t["params"], d, n_velocity)
                                          == warm_key), {"params": _to_params(model, _names(model, d),
                                                                               np.exp(np.array(warm_key)))}))

    # the survivors' relative cap from the screen's candidates (their largest fold's iterations, on all rows)
    cap = _cap(iter_per_row, kw.get("iter_cap_ratio", ITER_CAP_RATIO), folds)
    for t in screen.trace:
        cap.record([(t["score"], 0.0, int(round(t["n_iter"] * rows_all / rows_screen)))])
    final: list[dict[str, Any]] = []
    n_new = 0
    max_iter = cap()  # the screen's fits decide it: the same for every survivor
    runs = []  # per survivor: its params, the screen's fold scores it keeps, the folds it fits now
    for seen in picked.values():
        params = seen["params"]
        if by_rows:
            params = {**params, "C": scaled_C(params["C"], round(rows_screen), round(rows_all), c_rate)}
        kept = dict(zip(subset, seen["fold_r2"], strict=True)) if not by_rows and "fold_r2" in seen else {}
        runs.append((params, kept, [i for i in range(n_folds) if i not in kept]))
    fits_all = yield [fit_task(model, params, X, y, folds[i], n_velocity, max_iter)
                      for params, _, rest in runs for i in rest]  # the survivors: one round
    at, last_round = 0, 1 + max((t.get("round", -1) for t in screen.trace), default=-1)
    for key, (params, kept, rest) in zip(picked, runs, strict=True):
        fits = dict(zip(rest, fits_all[at:at + len(rest)], strict=True))
        at += len(rest)
        seen = picked[key]
        new_cpu = [fits[i] for i in rest]
        n_new += len(rest)
        all_fits = [fits[i] if i in fits else (kept[i], 0.0, 0) for i in range(n_folds)]
        entry = candidate_entry(params, all_fits, max_iter, phase="survivor", rung=1, n_rows=len(X),
                                round=last_round)
        entry["cpu_s"] = round(float(sum(c for _, c, _ in new_cpu)), 6)  # the screen's fits are in its entry
        entry["n_fits"] = len(new_cpu)
        entry["n_iter"] = max([n for _, _, n in new_cpu] + [seen.get("n_iter", 0)])
        entry["screen_key"] = list(key)
        final.append(entry)
    best = max(final, key=lambda e: e["score"])  # max keeps the first of equal scores: deterministic
    best_params, best_score = best["params"], best["score"]
    tolerance = kw.get("smooth_tolerance", 0.0)
    if kw.get("one_se"):
        tolerance = max(tolerance, best["se"])
    if tolerance > 0:
        best_params, best_score = smoothest_within(final, best_score, tolerance)
    chosen = next(e for e in final if e["params"] == best_params)

    trace = [{**t, "rung": 0, "n_rows": len(idx)} for t in screen.trace] + final
    n_fits = screen.n_fits + n_new
    result = SearchResult(model, "fast", best_params, float(best_score), len(trace), n_fits, n_folds, 0.0,
                          gp_fit_s=screen.gp_fit_s, trace=trace, warm_start_score=screen.warm_start_score,
                          budget_exhausted=screen.budget_exhausted, n_rows=len(X), folds=screen.folds)
    result.halving = {"screen_rows": len(idx), "screen_folds": subset or list(range(n_folds)), "rows": len(X),
                      "survivors": len(final), "screen_best_score": screen.best_score,
                      "screen_choice_kept": chosen["screen_key"] == list(_key(model, screen.best_params, d,
                                                                              n_velocity))}
    if warm_key is not None:
        warm_entry = next(e for e in final if e["screen_key"] == list(warm_key))
        result.warm_start_score = warm_entry["score"]
        if chosen is warm_entry:
            result.warm_start_kept = True
            others = [e["score"] for e in final if e is not warm_entry]
            screen_warm = screen.warm_start_score if screen.warm_start_score is not None else float("nan")
            result.note = (f"on all {n_folds} folds and {len(X)} rows the warm start (tuning R2 "
                           f"{warm_entry['score']:.4f}) beat the screen's {len(others)} best candidates (best of "
                           f"them {max(others, default=float('nan')):.4f}); on the screen ({len(idx)} rows, folds "
                           f"{result.halving['screen_folds']}) it scored {screen_warm:.4f}, the screen's best "
                           f"{screen.best_score:.4f}")
            log.warning("fast search %s kept its warm start unchanged: %s", model, result.note)
    cost = cost_summary(trace, cap)
    result.cost = {"cpu_s": round(cost["fits_cpu_s"] + screen.cost["cpu_s"] - screen.cost["fits_cpu_s"], 4), **cost}
    result.elapsed_s = time.perf_counter() - t0
    return result


halving_search = _driven(halving_search_rounds)
search = _driven(search_rounds)

