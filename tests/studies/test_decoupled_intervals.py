"""The decoupled models' prediction intervals and the GP's band on a damping law with known, heteroscedastic noise:
fresh samples of the same process fall inside the 90 % interval ~90 % of the time, also where the noise is largest."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.models.decoupled import DampingGP
from pipeline.studies.decoupled import conformal_half_width, interval_half_width, run_study

SMALL = {"svr": {"gamma": [1, 10], "epsilon": [1.0], "C": [1e3]}}


def noise_sd(v: np.ndarray) -> np.ndarray:
    """The target's SD grows with speed, as a smoothed derivative's does on a fast trial."""
    return 0.5 + 6.0 * np.abs(v)


def trial(seed: int, n: int) -> pd.DataFrame:
    """A sway trial: d = 20 v + 60 v|v| plus noise of known SD (``d_std_v_N``), AR(1) in time (correlated, as
    smoothed targets are)."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 20.0
    v = 0.6 * np.sin(2 * np.pi * t / (9.0 + seed % 5)) * np.cos(2 * np.pi * t / 31.0)
    e = np.zeros(n)
    w = rng.standard_normal(n)
    for i in range(1, n):  # unit-variance AR(1), lag-1 correlation 0.6
        e[i] = 0.6 * e[i - 1] + 0.8 * w[i]
    sd = noise_sd(v)
    return pd.DataFrame({"t_ns": (t * 1e9).astype(np.int64), "trial": f"s{seed}", "v_mps": v,
                         "d_v_N": 20.0 * v + 60.0 * v * np.abs(v) + sd * e, "d_std_v_N": sd})


@pytest.fixture(scope="module")
def study():
    train = trial(1, 1600)
    fresh = pd.concat([trial(s, 2000) for s in (2, 3, 4)], ignore_index=True)
    result = run_study(train.iloc[:400], train.iloc[400:], dofs=["v"], models=["ls", "svr", "gp"], search=SMALL,
                       gp_max_samples=200, max_samples=None, curve_points=2, test=fresh)
    return result, fresh


def test_conformal_interval_covers_90_percent_of_fresh_samples(study) -> None:
    result, fresh = study
    for model in ("ls", "svr", "gp"):
        r = result.get("v", model)
        assert r.interval["level"] == 0.9 and r.interval["scale"] == "target_sd"
        assert r.test["trials"] == ["s2", "s3", "s4"] and r.test["rows"] == len(fresh)
        assert 0.86 <= r.test["interval_coverage"] <= 0.94, (model, r.test)


def test_interval_widens_with_the_targets_sd(study) -> None:
    """Where the noise is 3x larger the interval holds its coverage: a single half-width would not."""
    result, fresh = study
    r = result.get("v", "ls")
    v, y, sd = (fresh[c].to_numpy() for c in ("v_mps", "d_v_N", "d_std_v_N"))
    err = np.abs(y - r.estimator.predict(v[:, None]))
    fast = np.abs(v) > 0.3
    assert np.mean(err[fast] <= interval_half_width(r.interval, sd[fast])) >= 0.85
    assert np.mean(err[fast] <= r.interval["half_width"]) < 0.8  # the typical width alone misses there


def test_gp_band_is_a_prediction_interval_with_the_noise_and_the_targets_sd(study) -> None:
    result, fresh = study
    r = result.get("v", "gp")
    assert 0.92 <= r.test["band_coverage"] <= 0.98, r.test
    v, y, sd = (fresh[c].to_numpy() for c in ("v_mps", "d_v_N", "d_std_v_N"))
    gp = r.estimator
    mean, latent = gp.predict(v[:, None], return_std=True)
    _, full = gp.predict(v[:, None], return_std=True, include_noise=True, sample_sd=sd)
    np.testing.assert_allclose(full**2, latent**2 + gp.noise_std_**2 + sd**2, rtol=1e-9)
    assert np.mean(np.abs(y - mean) <= 2 * latent) < 0.5  # the latent band alone is no interval for a target
    fast = np.abs(v) > 0.3
    assert np.mean(np.abs(y - mean)[fast] <= 2 * full[fast]) >= 0.9


def test_gp_without_the_targets_sd_learns_one_average_noise() -> None:
    """Fitted with the SDs, the learned white noise is what they leave (little); without, it absorbs them."""
    df = trial(5, 1200)
    X, y, sd = df[["v_mps"]].to_numpy(), df["d_v_N"].to_numpy(), df["d_std_v_N"].to_numpy()
    with_sd = DampingGP(max_samples=200).fit(X, y, sample_sd=sd)
    without = DampingGP(max_samples=200).fit(X, y)
    assert with_sd.noise_std_ < 0.5 * float(np.sqrt(np.mean(sd**2))) < without.noise_std_
    assert with_sd.target_sd_ == pytest.approx(float(np.sqrt(np.mean(sd[::with_sd.stride_] ** 2))), rel=0.2)
    with pytest.raises(ValueError, match="sample_sd has 3 values"):
        with_sd.fit(X, y, sample_sd=sd[:3])


def test_conformal_half_width_is_the_finite_sample_quantile() -> None:
    r = np.arange(1.0, 20.0)  # 19 residuals: ceil(20 * 0.9) = 18th smallest
    assert conformal_half_width(r, 0.9) == 18.0
    assert conformal_half_width(np.arange(1.0, 5.0), 0.9) == 4.0  # too few: the largest
