"""The coupled models' 90 % prediction intervals on a plant with a known answer: the targets are an explicit
model's accelerations (so McFarland-Whitcomb's family holds the truth) plus independent Gaussian noise of known
SD (the store's ``*dot_std_*`` columns). The scores |residual| / SD are then |N(0, 1)|: the half-width is its 90 %
quantile, 1.645 SD, and a fresh trial of the same process falls inside ~90 % of the time. With noise whose SD grows
with speed, the normalized alternative keeps the coverage where the noise is largest.

Tolerances: with n = 1500 calibration rows and 2000 fresh rows, the coverage of a conformal band varies by
sqrt(0.09 / 1500 + 0.09 / 2000) ~ 0.010 (the calibration quantile's own spread plus the fresh rows' binomial
spread), so 0.86-0.94 is 4 SD; the sample quantile's SD is sqrt(0.09 / 1500) / (2 phi(1.645)) ~ 0.038, so
1.645 +- 0.15 is 4 SD."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.optimize import nnls
from sklearn.base import clone

from pipeline import store
from pipeline.config import Params
from pipeline.config.params import CoupledParams
from pipeline.evaluate import blocked_folds, interval_half_width
from pipeline.models.explicit import EXPLICIT_INPUTS, McFarlandWhitcomb
from pipeline.sim import load_example_vehicle
from pipeline.sim.synthetic import synthetic_frame
from pipeline.studies.coupled import build_model, evaluate_models
from stages import train as train_stage

OUTPUTS = ["udot_mps2", "vdot_mps2", "rdot_radps2"]
SD = ["udot_std_mps2", "vdot_std_mps2", "rdot_std_radps2"]
Z90 = 1.6449  # the 90 % quantile of |N(0, 1)|


@pytest.fixture(scope="module")
def truth() -> McFarlandWhitcomb:
    base = synthetic_frame(3000, seed=1, trial="a", rate_hz=5.0, noise=0.0, split="train_test")
    model = McFarlandWhitcomb(solver="ols").fit(base[list(EXPLICIT_INPUTS)].to_numpy(), base[OUTPUTS].to_numpy())
    model.scale_ = base[OUTPUTS].to_numpy().std(axis=0)  # every trial's noise in units of these (test data only)
    return model


def trial(truth: McFarlandWhitcomb, seed: int, name: str, n: int, split: str = "train_test", *,
          hetero: bool = False, gain: bool = False) -> pd.DataFrame:
    """Exact inputs; targets = the truth's accelerations + N(0, sd²), sd 2 % of a reference trial's target SD or,
    ``hetero``, 1-4 % growing with |u| (a faster manoeuvre's targets are noisier) or, ``gain``, 1 % plus 10 % of
    the row's own |acceleration| (an error that grows with how hard the vehicle is driven, a thrust map's gain
    error, say)."""
    f = synthetic_frame(n, seed=seed, trial=name, rate_hz=5.0, noise=0.0, split=split)
    rng = np.random.default_rng(100 + seed)
    clean = truth.predict(f[list(EXPLICIT_INPUTS)].to_numpy())
    speed = np.abs(f["u_mps"].to_numpy())
    for k, (out, sd_col) in enumerate(zip(OUTPUTS, SD, strict=True)):
        sd = 0.01 * truth.scale_[k] * ((1 + 3 * speed / speed.max()) if hetero else np.full(len(f), 2.0))
        if gain:
            sd = 0.01 * truth.scale_[k] + 0.1 * np.abs(clean[:, k])
        f[out] = clean[:, k] + sd * rng.standard_normal(len(f))
        f[sd_col] = sd
    return f


@pytest.fixture(scope="module")
def study(truth: McFarlandWhitcomb) -> tuple[dict, pd.DataFrame, pd.DataFrame, CoupledParams]:
    tt, fresh = trial(truth, 2, "a", 1500), trial(truth, 3, "b", 2000, split="test")
    params = CoupledParams(models=["mcfarland_whitcomb"], folds=5)
    return evaluate_models(tt, fresh, {}, params), tt, fresh, params


@pytest.fixture(scope="module")
def hetero_study(truth: McFarlandWhitcomb) -> tuple[dict, pd.DataFrame, pd.DataFrame, CoupledParams]:
    tt, fresh = trial(truth, 2, "a", 1500, hetero=True), trial(truth, 3, "b", 2000, split="test", hetero=True)
    params = CoupledParams(models=["mcfarland_whitcomb"], folds=5)
    return evaluate_models(tt, fresh, {}, params), tt, fresh, params


def test_interval_covers_90_percent_of_a_fresh_trial(study) -> None:
    results, tt, _, _ = study
    res = results["mcfarland_whitcomb"]
    for j, out in enumerate(OUTPUTS):
        interval = res["interval"][out]
        assert interval["level"] == 0.9 and interval["scale"] == "prediction" and interval["rows"] == 1500
        assert abs(interval["half_width_sd"] - Z90) < 0.15, (out, interval)
        assert interval["half_width_constant"] == pytest.approx(interval["half_width_sd"] * tt[SD[j]].iloc[0])
        assert 0.86 <= res["final"][out]["interval_coverage"] <= 0.94, (out, res["final"][out])


def test_half_width_is_the_conformal_quantile_of_the_out_of_fold_residuals(study) -> None:
    """By hand: the blocked folds' models, their held-out rows' |residual| (and / SD, the alternative), the
    spread a + b |p| of those residuals by non-negative least squares on the out-of-fold |prediction| p, the
    ceil((n + 1) 0.9)-th smallest |residual| / spread; then the fresh trial's share inside the final model's
    prediction +- q (a + b |p|)."""
    results, tt, fresh, params = study
    res = results["mcfarland_whitcomb"]
    X, y = tt[list(EXPLICIT_INPUTS)].to_numpy(), tt[OUTPUTS].to_numpy()
    est = build_model("mcfarland_whitcomb", None, params, train=tt)
    folds = blocked_folds(len(tt), 5)
    oof = np.concatenate([clone(est).fit(X[train], y[train]).predict(X[test]) for train, test in folds])
    scores = np.abs(np.concatenate([y[test] for _, test in folds]) - oof)
    sd = np.concatenate([tt[SD].to_numpy()[test] for _, test in folds])
    k = int(np.ceil((len(scores) + 1) * 0.9))  # 1351st of 1500
    pred = res["estimator"].predict(fresh[list(EXPLICIT_INPUTS)].to_numpy())
    for j, out in enumerate(OUTPUTS):
        interval = res["interval"][out]
        assert interval["half_width_constant"] == pytest.approx(np.sort(scores[:, j])[k - 1], rel=1e-12)
        assert interval["half_width_sd"] == pytest.approx(np.sort(scores[:, j] / sd[:, j])[k - 1], rel=1e-12)
        a, b = nnls(np.column_stack([np.ones(len(oof)), np.abs(oof[:, j])]), scores[:, j])[0]
        assert interval["spread"] == pytest.approx([a, b], rel=1e-9)
        q = np.sort(scores[:, j] / (a + b * np.abs(oof[:, j])))[k - 1]
        assert interval["half_width_scaled"] == pytest.approx(q, rel=1e-9)
        inside = np.abs(fresh[out].to_numpy() - pred[:, j]) <= q * (a + b * np.abs(pred[:, j]))
        assert res["final"][out]["interval_coverage"] == pytest.approx(inside.mean(), abs=1e-12)


def test_interval_widens_where_the_target_is_noisier(hetero_study) -> None:
    """Where the residual is noise of known SD (not the coupled models' usual model error), the normalized
    alternative keeps the coverage of the fresh trial's fast quarter (4x the noise of the slow rows); one half-width
    for all rows misses there and is too wide where the noise is small."""
    results, _, fresh, _ = hetero_study
    res = results["mcfarland_whitcomb"]
    pred = res["estimator"].predict(fresh[list(EXPLICIT_INPUTS)].to_numpy())
    speed = np.abs(fresh["u_mps"].to_numpy())
    fast, slow = speed > np.quantile(speed, 0.75), speed < np.quantile(speed, 0.25)
    for j, out in enumerate(OUTPUTS):
        err = np.abs(fresh[out].to_numpy() - pred[:, j])
        band = res["interval"][out]["half_width_sd"] * fresh[SD[j]].to_numpy()
        assert np.mean(err[fast] <= band[fast]) >= 0.85
        one = res["interval"][out]["half_width_constant"]
        assert np.mean(err[fast] <= one) < 0.8 and np.mean(err[slow] <= one) > 0.97


def test_interval_grows_with_the_predicted_acceleration(truth: McFarlandWhitcomb) -> None:
    """Noise of SD a + b |acceleration| (a = 1 % of the target's SD, b = 0.1): the spread fitted to the out-of-fold
    |residuals| grows with |prediction| at E|N(0, 1)| b, and the band covers ~90 % of the fresh trial's gently
    driven quarter (smallest |prediction|) and of its hardest driven quarter alike, where one half-width for all
    rows is far too wide on the first and misses on the second.

    Tolerances: E|residual| = sqrt(2 / pi) (a + b |a_true|) (the model's own error adds to the intercept, not the
    slope): the fitted slope within 20 %; a quarter of 2000 fresh rows has a binomial SD of 0.013, plus the
    quantile's spread and the straight line's misfit at the ends: 0.80-0.98.
    """
    tt = trial(truth, 11, "a", 1500, gain=True)
    fresh = trial(truth, 12, "b", 2000, split="test", gain=True)
    res = evaluate_models(tt, fresh, {}, CoupledParams(models=["mcfarland_whitcomb"], folds=5))["mcfarland_whitcomb"]
    pred = res["estimator"].predict(fresh[list(EXPLICIT_INPUTS)].to_numpy())
    for j, out in enumerate(OUTPUTS):
        interval = res["interval"][out]
        q, (a, b) = interval["half_width_scaled"], interval["spread"]
        assert b == pytest.approx(np.sqrt(2 / np.pi) * 0.1, rel=0.2) and q * a > 0, (out, interval)
        err, p = np.abs(fresh[out].to_numpy() - pred[:, j]), np.abs(pred[:, j])
        band = interval_half_width(interval, None, pred[:, j])
        gentle, hard = p < np.quantile(p, 0.25), p > np.quantile(p, 0.75)
        assert 0.8 <= np.mean(err[gentle] <= band[gentle]) <= 0.98 and 0.8 <= np.mean(err[hard] <= band[hard]) <= 0.98
        one = interval["half_width_constant"]
        assert np.mean(err[gentle] <= one) > 0.99 and np.mean(err[hard] <= one) < 0.78, (out, one)


def test_without_sd_columns_one_half_width(truth: McFarlandWhitcomb) -> None:
    """A store without the smoother's SDs (gaussian / savgol differentiation): one half-width per output, the
    quantile of |residual| in the output's unit."""
    tt, fresh = (trial(truth, s, n, 1000, split=sp).drop(columns=SD) for s, n, sp in ((4, "c", "train_test"),
                                                                                      (5, "d", "test")))
    res = evaluate_models(tt, fresh, {}, CoupledParams(models=["mcfarland_whitcomb"], folds=5))["mcfarland_whitcomb"]
    for out in OUTPUTS:
        interval = res["interval"][out]
        assert interval["scale"] == "prediction" and interval["half_width"] > 0 and "half_width_sd" not in interval
        assert 0.8 <= res["final"][out]["interval_coverage"] <= 0.99  # heteroscedastic: right on average only


def test_train_stage_writes_the_interval_and_its_coverage(tmp_path: Path, truth: McFarlandWhitcomb) -> None:
    """The card, metrics.json and Table III (md and JSON) carry each output's interval and the final check's share
    of the test trial inside it."""
    vehicle = load_example_vehicle()
    params = Params(features={"test_trials": ["b"]}, coupled={"models": ["mcfarland_whitcomb"], "folds": 3})
    for name, seed, n in (("a", 6, 900), ("b", 7, 900)):
        frame = trial(truth, seed, name, n).drop(columns=["split"])
        frame = frame[[c for c in frame.columns if c in ("t_ns", "segment") or store._column_type(c) is not None]]
        fill = {c: 0.0 for c, _ in store.FIXED_COLUMNS if c != "split" and c not in frame.columns}
        store.write_trial(tmp_path, vehicle.name, name, frame.assign(**fill), params.features, {})
    train_stage.run(tmp_path, vehicle, params)
    card = json.loads((tmp_path / "data/models/coupled/mcfarland_whitcomb.card.json").read_text())
    metrics = json.loads((tmp_path / "data/evaluation/coupled/metrics.json").read_text())["mcfarland_whitcomb"]
    t3 = json.loads((tmp_path / "data/evaluation/coupled/table3.json").read_text())["mcfarland_whitcomb"]
    md = (tmp_path / "data/evaluation/coupled/table3.md").read_text()
    for out in OUTPUTS:
        interval, final = card["interval"][out], card["scores"]["final_check"][out]
        assert interval["scale"] == "prediction" and interval == t3["interval"][out]
        assert 0.8 <= final["interval_coverage"] <= 0.98 and final == t3["final"][out]
        assert metrics[out]["final_interval_coverage"] == final["interval_coverage"]
        assert metrics[out]["interval_half_width"] == interval["half_width"]
    assert "| 90 % interval ± | final check: inside 90 % |" in md
    a, b = (card["interval"]["udot_mps2"]["half_width_scaled"] * c for c in card["interval"]["udot_mps2"]["spread"])
    assert f"| {a:.3g} + {b:.3g}·abs(p) | " in md


def test_with_two_training_trials_the_wider_of_the_blocked_and_the_held_out_trials_quantiles(
        truth: McFarlandWhitcomb) -> None:
    """Two training trials, the second's targets three times noisier: a model fitted on one trial predicts the
    other (by hand: fit on a, residuals of b; fit on b, residuals of a), its quantile of those |residuals| beside
    the blocked folds'; the interval takes the wider, and says both."""
    a, b = trial(truth, 8, "a", 700), trial(truth, 9, "b", 800)
    b[OUTPUTS] += 2.0 * (b[OUTPUTS].to_numpy() - truth.predict(b[list(EXPLICIT_INPUTS)].to_numpy()))
    tt, fresh = pd.concat([a, b], ignore_index=True), trial(truth, 10, "c", 500, split="test")
    params = CoupledParams(models=["mcfarland_whitcomb"], folds=5)
    res = evaluate_models(tt, fresh, {}, params)["mcfarland_whitcomb"]
    X, y = tt[list(EXPLICIT_INPUTS)].to_numpy(), tt[OUTPUTS].to_numpy()
    est = build_model("mcfarland_whitcomb", None, params, train=tt)
    held = [(np.flatnonzero(tt["trial"] != t), np.flatnonzero(tt["trial"] == t)) for t in ("a", "b")]
    by_trial = np.concatenate([np.abs(y[te] - clone(est).fit(X[tr], y[tr]).predict(X[te])) for tr, te in held])
    blocked = np.concatenate([np.abs(y[te] - clone(est).fit(X[tr], y[tr]).predict(X[te]))
                              for tr, te in blocked_folds(len(tt), 5)])
    k = int(np.ceil((len(tt) + 1) * 0.9))
    for j, out in enumerate(OUTPUTS):
        interval = res["interval"][out]
        q_trials, q_blocked = np.sort(by_trial[:, j])[k - 1], np.sort(blocked[:, j])[k - 1]
        assert interval["half_width_trials"] == pytest.approx(q_trials, rel=1e-12)
        assert interval["half_width_blocked"] == pytest.approx(q_blocked, rel=1e-12)
        assert interval["half_width_constant"] == max(q_trials, q_blocked) and interval["trials_held_out"] == 2
        assert interval["method"].startswith("split conformal: the wider")
    # the fit on the quiet trial a alone is worse on b than the blocked folds (which saw b's noise), on some output
    assert any(res["interval"][o]["half_width_trials"] > res["interval"][o]["half_width_blocked"] for o in OUTPUTS)


def test_one_training_trial_has_no_held_out_trials(study) -> None:
    """One training trial (the module's study): the blocked CV's quantile alone, no across-trial part."""
    for interval in study[0]["mcfarland_whitcomb"]["interval"].values():
        assert "half_width_trials" not in interval and interval["method"].startswith("split conformal on the blocked")
