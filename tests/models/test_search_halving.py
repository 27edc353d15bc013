"""Successive halving over rows: a search screens its candidates on a few rows and chooses among the survivors on
all of them, so its cost is bounded by the screen, and its choice is the one all rows make."""

from __future__ import annotations

import math

import numpy as np
import pytest

import pipeline.models.search as search_mod
from pipeline.config.params import CoupledParams
from pipeline.errors import ModelError
from pipeline.evaluate import blocked_folds
from pipeline.models.search import cv_score, fast_search
from pipeline.models.search_halving import fold_subset, halving_search, search
from pipeline.sim.synthetic import synthetic_frame
from pipeline.studies.coupled import tune


def _two_of_six(n: int, seed: int = 0, noise: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """A target of inputs 0 and 1 only (inputs 2-5 distractors on very different scales), smooth in time."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 60.0, n)
    X = np.column_stack([np.sin(0.7 * t + k) * s for k, s in enumerate([1.0, 0.2, 3.0, 500.0, 0.01, 40.0])])
    X += rng.normal(size=X.shape) * np.array([0.3, 0.06, 1.0, 150.0, 0.003, 12.0])
    z0, z1 = X[:, 0], X[:, 1] / 0.2
    y = np.sin(1.5 * z0) + 0.5 * z1**2 + noise * rng.normal(size=n)
    return X, y


def test_the_choice_is_the_best_survivor_on_all_rows_and_near_the_known_best():
    X, y = _two_of_six(600)
    res = halving_search("wdse_svr", X, y, screen_rows=150, survivors=4, max_evals=16, n_folds=3)
    last = [t for t in res.trace if t["rung"] == 1]
    screen = [t for t in res.trace if t["rung"] == 0]
    assert len(screen) == 16 and len(last) == 4 and {t["n_rows"] for t in last} == {600}
    assert {t["n_rows"] for t in screen} == {150}
    # the choice is the survivor that scored best on all rows, with its score there (not the screen's)
    assert res.best_score == max(t["score"] for t in last)
    assert res.best_params == max(last, key=lambda t: t["score"])["params"]
    assert res.best_score == pytest.approx(cv_score("wdse_svr", res.best_params, X, y, blocked_folds(600, 3)))
    # the screen's own best is among the survivors: halving can only match or beat it on all rows
    best_screen = max(screen, key=lambda t: t["score"])["params"]
    moved = best_screen["C"] * (100 / 400) ** 0.5  # C as the all rows' fits use it (c_rate 0.5)
    assert any(t["params"]["C"] == pytest.approx(moved) and t["params"]["gammas"] == best_screen["gammas"]
               for t in last)
    # the known answer: the noise-free target explains all but 0.05² of the variance; a kernel that found inputs
    # 0 and 1 (larger gammas than the distractors) gets near it
    ceiling = 1.0 - 0.05**2 / float(np.var(y))
    assert res.best_score > ceiling - 0.1
    gammas = res.best_params["gammas"]
    assert min(gammas[:2]) > max(gammas[2:])


def test_the_rows_each_candidate_is_scored_on_are_bounded_whatever_the_block_length(svr_fold_fits):
    # a block 10x the bound: the screen sees screen_samples rows, only the survivors (and the warm start) see the
    # max_samples rows, however long the trials
    params = CoupledParams(models=["two_weights_svr"], outputs=["udot_mps2"], inputs=["u_mps", "v_mps", "r_radps"],
                           max_evals=8, tuning_folds=3, max_samples=300, screen_samples=90, screen_folds=None,
                           survivors=2)
    counts = []
    for n in (1500, 6000):
        svr_fold_fits.clear()
        _, trace = tune(synthetic_frame(n, seed=3, split="train_test"), params, split="train_test")
        small = [tr + te for tr, te in svr_fold_fits if tr + te <= 90]
        large = [tr + te for tr, te in svr_fold_fits if tr + te > 90]
        assert max(large) <= 300
        # 2 survivors per search (+ the warm start for 2-weights, whose chain starts with RBF), 3 folds each
        assert len(large) <= 2 * (params.survivors + 1) * params.tuning_folds
        assert len(small) == 2 * params.max_evals * params.tuning_folds
        assert trace["two_weights_svr"]["udot_mps2"]["halving"]["screen_rows"] == 90
        counts.append(set(svr_fold_fits))
    assert counts[0] == counts[1]  # fits on the same numbers of rows for a block 4x longer


def test_a_richer_kernel_is_not_chosen_below_its_warm_start_on_all_rows():
    X, y = _two_of_six(480, seed=1)
    rbf = search("rbf_svr", X, y, "fast", screen_rows=120, survivors=2, max_evals=8, n_folds=3)
    wdse = search("wdse_svr", X, y, "fast", screen_rows=120, survivors=2, max_evals=8, n_folds=3,
                  warm_start=rbf.best_params)
    # the warm start went through the screen with its C moved to the screen's rows and back
    warm = next(t for t in wdse.trace if t["rung"] == 1
                and t["params"]["gammas"] == pytest.approx([rbf.best_params["gamma"]] * 6, rel=1e-5))
    assert warm["params"]["C"] == pytest.approx(rbf.best_params["C"], rel=1e-5)
    assert wdse.warm_start_score == warm["score"]
    assert warm["score"] == pytest.approx(rbf.best_score, abs=1e-4)  # the same kernel, the same rows and folds
    assert wdse.best_score >= rbf.best_score - 1e-6
    assert wdse.best_params["C_rows"] == 320  # C of the last rung: 3 folds of all 480 rows


def test_halving_is_deterministic_and_a_short_block_is_the_fast_search_itself():
    X, y = _two_of_six(300, seed=2)
    kw = {"screen_rows": 100, "survivors": 3, "max_evals": 6, "n_folds": 3}

    def stable(res):
        d = res.to_dict()
        for k in ("elapsed_s", "gp_fit_s", "cost"):
            d.pop(k)
        for t in d["trace"]:
            t.pop("cpu_s")
        return d

    assert stable(search("rbf_svr", X, y, "fast", **kw)) == stable(search("rbf_svr", X, y, "fast", **kw))
    folds = {"screen_folds": 2, "survivors": 3, "max_evals": 6, "n_folds": 5}
    assert stable(search("rbf_svr", X, y, "fast", **folds)) == stable(search("rbf_svr", X, y, "fast", **folds))
    short = halving_search("rbf_svr", X[:100], y[:100], **kw)
    plain = fast_search("rbf_svr", X[:100], y[:100], max_evals=6, n_folds=3)
    assert short.halving == {} and stable(short) == stable(plain)
    with pytest.raises(ModelError, match="survivors"):
        halving_search("rbf_svr", X, y, screen_rows=100, survivors=0)
    assert math.isfinite(short.best_score)


KNOWN_BEST = {"gamma": 0.5, "C": 3.0, "epsilon": 0.01}


def _bowl_fits(monkeypatch, tilt: float = 1.0):
    """Replace the SVR fits by a known score: a bowl in log-hyperparameters with its top at KNOWN_BEST (steep in C,
    shallow in gamma and epsilon, so that C decides the ranking), tilted in log C per fold so that the tilts cancel
    over all 5 folds but not over the screen's folds 1 and 3 (whose optimum C lies higher). Records each fold
    scored."""
    scored: list[int] = []
    slope = {0: -2 * tilt, 1: tilt, 2: -tilt, 3: tilt, 4: tilt}  # sums to 0 over 5 folds, +2 tilt over {1, 3}

    def fake(est, X, y, train, test):  # noqa: ANN001, ANN202  (a fold fit: R², CPU seconds, iterations)
        ys = float(np.std(y))
        c = math.log(est.C / ys) - math.log(KNOWN_BEST["C"])
        bowl = 0.95 - 0.02 * c**2 - 0.002 * ((math.log(est.gamma) - math.log(KNOWN_BEST["gamma"])) ** 2
                                             + (math.log(est.epsilon / ys) - math.log(KNOWN_BEST["epsilon"])) ** 2)
        i = int(round(test[0] / len(test)))  # blocked folds: the test block's index
        scored.append(i)
        return bowl + slope[i] * c * 0.02, 0.0, 1

    monkeypatch.setattr(search_mod, "_fold_fit", fake)
    return scored


def test_a_fold_screen_keeps_the_best_over_all_folds_and_reuses_its_fits(monkeypatch):
    scored = _bowl_fits(monkeypatch)
    X, y = _two_of_six(500)
    X = X[:, :1]
    res = halving_search("rbf_svr", X, y, screen_folds=2, survivors=6, max_evals=30, n_folds=5)
    screen = [t for t in res.trace if t["rung"] == 0]
    last = [t for t in res.trace if t["rung"] == 1]
    assert fold_subset(5, 2) == [1, 3] and res.halving["screen_folds"] == [1, 3]
    # the screen scored folds 1 and 3 only; a survivor fitted only the three others (its screen fits kept)
    assert scored.count(1) == scored.count(3) == len(screen)
    assert scored.count(0) == scored.count(2) == scored.count(4) == len(last) == 6
    assert res.n_fits == 2 * len(screen) + 3 * len(last) < 5 * 30
    # the choice is the survivor with the best mean over all 5 folds (the screen's tilt cancels there), and it
    # is closer to the known best C than the screen's own choice, which the tilt pulled towards a larger C
    assert res.best_score == max(t["score"] for t in last)
    screen_best = max(screen, key=lambda t: t["score"])["params"]
    assert not res.halving["screen_choice_kept"]
    ys = float(np.std(y))
    assert abs(math.log(res.best_params["C"] / ys / 3.0)) < abs(math.log(screen_best["C"] / ys / 3.0))


def test_a_warm_start_that_wins_on_all_folds_is_reported_kept(monkeypatch, caplog):
    _bowl_fits(monkeypatch)
    X, y = _two_of_six(500)
    X = X[:, :1]
    ys = float(np.std(y))
    warm = {"gamma": KNOWN_BEST["gamma"], "C": KNOWN_BEST["C"] * ys, "epsilon": KNOWN_BEST["epsilon"] * ys}
    with caplog.at_level("WARNING", logger="pipeline.models.search_halving"):
        res = halving_search("rbf_svr", X, y, screen_folds=2, survivors=3, max_evals=12, n_folds=5,
                             warm_start=warm)
    # the top of the bowl: no candidate beats it over all folds, though the screen's tilt preferred another
    assert res.warm_start_kept and res.best_params["C"] == pytest.approx(warm["C"], rel=1e-5)
    assert res.warm_start_score == res.best_score
    assert "on all 5 folds" in res.note and "the screen's best" in res.note
    assert sum("kept its warm start" in r.getMessage() for r in caplog.records) == 1
