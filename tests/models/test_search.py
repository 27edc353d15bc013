"""The fast hyperparameter search moves away from a bad warm start, and says so when it keeps a good one."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from pipeline.models.search import fast_search


def _two_of_six(n: int = 150, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A target that depends on inputs 0 and 1 only; inputs 2-5 are distractors on very different scales."""
    rng = np.random.default_rng(seed)
    X = rng.normal(size=(n, 6)) * np.array([1.0, 0.2, 3.0, 500.0, 0.01, 40.0])
    z0, z1 = X[:, 0], X[:, 1] / 0.2
    y = np.sin(1.5 * z0) + 0.5 * z1**2 + 0.05 * rng.normal(size=n)
    return X, y


BAD_WARM_START = {"gammas": [30.0] * 6, "C": 0.05, "epsilon": 0.001}  # far too narrow, far too little C


@pytest.fixture(scope="module")
def searched():
    X, y = _two_of_six()
    return X, y, fast_search("wdse_svr", X, y, max_evals=30, warm_start=BAD_WARM_START)


def test_search_leaves_a_bad_warm_start_and_beats_it(searched):
    _, _, res = searched
    assert not res.warm_start_kept and res.note == ""
    assert res.warm_start_score is not None and res.warm_start_score < 0.1
    assert res.best_score > 0.9 > res.warm_start_score + 0.8
    assert res.n_fits == 30 * 3 and len(res.trace) == 30
    assert {"seed", "warm_start", "explore", "model", "local"} <= {t["phase"] for t in res.trace}


def test_irrelevant_inputs_get_the_smaller_gammas(searched):
    # on three draws of the data: a search's path turns on a few candidates, so one draw says little of its rule
    gaps = []
    for seed in (0, 1, 2):
        X, y = _two_of_six(seed=seed)
        res = searched[2] if seed == 0 else fast_search("wdse_svr", X, y, max_evals=30, warm_start=BAD_WARM_START)
        g = np.log10(res.best_params["gammas"])
        gaps.append(g[:2].mean() - g[2:].mean())  # decades between the relevant inputs' gammas and the others'
    assert np.median(gaps) > np.log10(30.0) and min(gaps) > 1.0, gaps


def test_search_reports_a_warm_start_it_keeps(searched, caplog):
    X, y, res = searched
    # the previous optimum as warm start, and budget for the GP seeds only: nothing can beat it
    with caplog.at_level(logging.WARNING, logger="pipeline.models.search"):
        again = fast_search("wdse_svr", X, y, max_evals=3, warm_start=res.best_params)
    assert again.warm_start_kept and again.best_params == res.best_params
    assert again.best_score == pytest.approx(res.best_score)
    assert "none of 2 other candidates (2 seed" in again.note
    assert any("kept its warm start unchanged" in r.getMessage() for r in caplog.records)


def test_no_warm_start_no_report():
    X, y = _two_of_six(80, seed=1)
    res = fast_search("rbf_svr", X, y, max_evals=5)
    assert res.warm_start_score is None and not res.warm_start_kept and res.note == ""


def test_the_searchs_gp_fits_run_on_one_blas_thread(monkeypatch):
    """Its GPs fit <= 150 points: on a loaded 2-core machine two OpenBLAS threads made a 150x150 Cholesky 225 ms
    instead of 0.07 ms (the ship's tune + train 2 min instead of 10 s)."""
    from sklearn.gaussian_process import GaussianProcessRegressor
    from threadpoolctl import threadpool_info, threadpool_limits

    seen: list[int] = []
    fit = GaussianProcessRegressor.fit

    def recording_fit(self, X, y):
        seen.append(max(p["num_threads"] for p in threadpool_info() if p["user_api"] == "blas"))
        return fit(self, X, y)

    monkeypatch.setattr(GaussianProcessRegressor, "fit", recording_fit)
    X, y = _two_of_six(80, seed=2)
    with threadpool_limits(2, user_api="blas"):  # as on a 2-core machine, whatever this one has
        fast_search("wdse_svr", X, y, max_evals=6, n_explore=0)
    assert len(seen) >= 3 and set(seen) == {1}, seen


@pytest.mark.parametrize("method", ["fast", "paper_grid"])
def test_the_best_params_name_the_rows_their_C_was_chosen_on(method):
    """3-fold blocked CV on 150 rows trains each candidate on 100: the tuned C is the C of 100 rows, and the
    tuned model fitted on all 150 uses C (100 / 150)^0.5."""
    from pipeline.models.search import make_svr, search

    X, y = _two_of_six()
    grid = {"gamma": [0.1, 1.0], "C": [1.0, 10.0], "epsilon": [0.01]}
    kw = {"max_evals": 4} if method == "fast" else {"grid": grid}
    res = search("rbf_svr", X, y, method, n_folds=3, **kw)
    assert res.best_params["C_rows"] == 100
    est = make_svr("rbf_svr", res.best_params, C_rate=0.5).fit(X, y)
    assert est.C_ == pytest.approx(res.best_params["C"] * (100 / 150) ** 0.5, rel=1e-12)


def test_one_se_keeps_the_smoothest_kernel_within_a_standard_error_of_the_best():
    """The one-standard-error rule: every candidate's fold scores give its standard error; the pick is the widest
    kernel (smallest sum of log gammas) among those whose mean is within one SE of the best mean."""
    # a noisy target (noise SD 0.4 on a signal of SD ~1): the fold scores spread, so several candidates of any
    # search path lie within one SE of the best (5-10 on seeds 0-3 here), and the best is not the widest of them
    X, y = _two_of_six(150, seed=0)
    y = y + 0.4 * np.random.default_rng(100).normal(size=len(y))
    plain = fast_search("wdse_svr", X, y, max_evals=20, n_folds=5)
    ruled = fast_search("wdse_svr", X, y, max_evals=20, n_folds=5, one_se=True)
    assert [t["params"] for t in ruled.trace] == [t["params"] for t in plain.trace]  # same search, another pick
    best = max(ruled.trace, key=lambda t: t["score"])
    assert best["se"] > 0 and plain.best_params == best["params"]
    near = [t for t in ruled.trace if t["score"] >= best["score"] - best["se"]]
    assert len(near) > 1
    widest = min(near, key=lambda t: np.sum(np.log(t["params"]["gammas"])))
    assert ruled.best_params == widest["params"] != best["params"]
    assert np.sum(np.log(ruled.best_params["gammas"])) < np.sum(np.log(best["params"]["gammas"]))


@pytest.mark.parametrize(("method", "key"), [("paper_grid", "max_evals"), ("paper_grid", "warm_start"),
                                             ("fast", "grid"), ("fast", "n_fold")])
def test_search_refuses_a_keyword_its_method_does_not_use(method, key):
    """search() passes its keywords to the method's function; one that function does not take is an error naming
    it, not a setting silently dropped."""
    from pipeline.models.search import search

    X, y = _two_of_six()
    with pytest.raises(TypeError, match=key):
        search("rbf_svr", X, y, method, n_folds=3, **{key: 1})


def test_the_iteration_cap_stops_candidates_and_the_trace_reports_it(caplog):
    """A cap of a tenth of an iteration per row stops the large-C candidates: their fits stop at the cap, are
    scored as they are (a finite R²), counted per candidate and per search, and logged once per search (not
    libsvm's warning once per fit); the same search without a cap stops none and its results agree wherever no
    fit was stopped. The cost names the slowest candidates, slowest first."""
    import warnings

    X, y = _two_of_six(n=240)
    kw = {"max_evals": 12, "n_folds": 3}
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ConvergenceWarning per fit
        with caplog.at_level(logging.INFO, logger="pipeline.models.search_cost"):
            capped = fast_search("rbf_svr", X, y, iter_per_row=0.1, iter_cap_ratio=None, **kw)
    free = fast_search("rbf_svr", X, y, iter_per_row=None, iter_cap_ratio=None, **kw)
    cap = capped.cost["max_iter"]
    assert cap == round(0.1 * 160)  # 3 blocked folds of 240 rows: 160 training rows each
    stopped = [t for t in capped.trace if t["capped"]]
    assert stopped and capped.cost["n_capped"] == len(stopped)
    assert all(t["n_iter"] == cap and np.isfinite(t["score"]) for t in stopped)
    assert all(t["n_iter"] < cap for t in capped.trace if not t["capped"])
    assert sum("stopped by libsvm's iteration cap" in r.getMessage() for r in caplog.records) == 1
    assert free.cost["max_iter"] is None and free.cost["n_capped"] == 0
    assert max(t["n_iter"] for t in free.trace) > cap
    first = capped.trace[0]  # the first seed: the same candidate in both; unstopped, the same score
    if not first["capped"]:
        assert first["score"] == free.trace[0]["score"]
    slow = [s["cpu_s"] for s in capped.cost["slowest_by_cpu"]]
    assert len(slow) == 3 and slow == sorted(slow, reverse=True) and slow[0] == capped.cost["max_candidate_cpu_s"]
    assert capped.cost["cpu_s"] >= capped.cost["fits_cpu_s"] > 0


def test_the_relative_cap_holds_each_fit_near_the_median_of_the_fits_before_it(monkeypatch):
    """Once a search has scored its first five candidates, a fit stops at ``iter_cap_ratio`` x the median
    iterations of the search's fits so far, but never below twice the iterations of the best candidate so far (nor
    the floor): each candidate's cap is that rule applied to the fits before it, the costly candidates far from
    the best are stopped, and the same search without the relative cap has fits many times its median."""
    import math

    from pipeline.models import search as search_module
    from pipeline.models.search_cost import IterationCap

    X, y = _two_of_six(n=240)
    calls: list[tuple[int | None, float, int]] = []
    real = search_module._fold_fit

    def spy(est, *args):  # noqa: ANN001, ANN002, ANN202
        r2, cpu, n_iter = real(est, *args)
        calls.append((None if est.max_iter == -1 else est.max_iter, r2, n_iter))
        return r2, cpu, n_iter

    monkeypatch.setattr(search_module, "_fold_fit", spy)
    monkeypatch.setattr(search_module, "ITER_FLOOR_PER_ROW", 1.0)  # the floor: 160 iterations on these folds
    ratio, kw = 2.0, {"max_evals": 20, "n_folds": 3, "iter_per_row": None}
    capped = fast_search("rbf_svr", X, y, iter_cap_ratio=ratio, **kw)
    # the fits in trace order, three folds a candidate; a round's candidates run at once, under the cap of the
    # rounds before it
    fits = [calls[j:j + 3] for j in range(0, len(calls), 3)]
    rounds = [t["round"] for t in capped.trace]
    assert len(fits) == len(rounds) and rounds == sorted(rounds) and len(set(rounds)) > 4
    relative = 0
    for k, r in enumerate(rounds):
        before = [f for f, rr in zip(fits, rounds, strict=True) if rr < r]
        if len(before) < 5:  # the first five candidates: no cap but the absolute one
            assert all(cap is None for cap, _, _ in fits[k])
            continue
        best = max(before, key=lambda fits: np.mean([r2 for _, r2, _ in fits]))
        expected = max(160, math.ceil(ratio * float(np.median([n for c in before for _, _, n in c]))),
                       2 * max(n for _, _, n in best))
        assert all(cap == expected and n <= expected for cap, _, n in fits[k])
        relative += 1
    assert relative >= 8
    stopped = [t for t in capped.trace if t["capped"]]
    assert stopped and capped.cost["n_capped"] == len(stopped) and capped.cost["iter_cap_ratio"] == ratio
    assert all(t["n_iter"] == t["max_iter"] for t in stopped)
    assert capped.n_fits == 3 * len(capped.trace)

    calls.clear()
    free = fast_search("rbf_svr", X, y, iter_cap_ratio=None, **kw)
    iters = [n for _, _, n in calls]
    assert max(iters) > 3 * ratio * float(np.median(iters))  # what the cap is for
    assert free.cost["n_capped"] == 0 and free.cost["slowest_fit_over_median"] > 0
    with pytest.raises(Exception, match="ratio must be a number >= 1"):
        IterationCap(None, 0.5)


def test_the_pattern_search_ends_when_its_last_room_holds_only_candidates_scored_before():
    """One candidate of room left and the poll's first candidate already scored (no better): the poll used to come
    back unchanged forever (its other candidate never scored, so no step halved). Found on two trials' folds."""
    from pipeline.models.search_steps import pattern_search
    from pipeline.rounds import run_inline

    lo, hi = np.array([-10.0]), np.array([10.0])
    cache = {(1.0,): 0.1, (-1.0,): 0.2, (5.0,): 0.0}  # x = 0 (score 0.5) +- its step 1, and one more
    calls = []

    def evaluate(pairs):
        calls.append(len(pairs))
        assert len(calls) < 50, "the pattern search polls the same scored candidates again and again"
        keys = [tuple(np.round(np.clip(v, lo, hi), 6)) for v, _ in pairs]
        for key in keys:
            cache.setdefault(key, 0.0)
        return [cache[k] for k in keys]
        yield  # a generator, as the search's evaluator is

    x, best, _ = run_inline(pattern_search(evaluate, np.array([0.0]), 0.5, lo, hi, np.random.default_rng(0), 4,
                                           cache, 1.0, 0.2))
    assert len(cache) == 4 and best == 0.5 and x.tolist() == [0.0]
    assert len(calls) <= 3
