"""Free-run bands that carry the model's force error, on a 1-DOF vehicle with a known AR(1) force disturbance:
the decoupled study's out-of-fold residuals give the disturbance's SD and time constant, and the band of fresh
trials' free runs covers their measured velocity 90-98 % of the time (a band without the force error far less)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline.rollout import DecoupledDynamics, band_tables, damping_tables, run_model, table_range
from pipeline.rollout.force_error import ForceError, fit_ar1
from pipeline.studies.decoupled import run_study

MASS_KG, DT_S, DURATION_S = 60.0, 0.1, 400.0
FORCE_SD_N, FORCE_TC_S = 4.0, 3.0
M = np.diag([MASS_KG, 1.0, 1.0, 1.0, 1.0, 1.0])


def damping(u: np.ndarray | float) -> np.ndarray | float:
    return 20.0 * u + 40.0 * u * np.abs(u)


def trial(seed: int) -> pd.DataFrame:
    """Surge alone: ``m u' = tau + f - d(u)`` by RK4 with inputs held over each step, f an AR(1) of SD 4 N and
    time constant 3 s; the damping target ``tau - m u'`` = d(u) - f exactly; the velocity measured with 5 mm/s
    white noise."""
    rng = np.random.default_rng(seed)
    n = int(DURATION_S / DT_S)
    t = np.arange(n) * DT_S
    p1, p2 = 9.0 + seed % 5, 23.0 + seed % 7
    tau = 30.0 * np.sin(2 * np.pi * t / p1) + 20.0 * np.sin(2 * np.pi * t / p2 + seed)
    a = np.exp(-DT_S / FORCE_TC_S)
    f = np.empty(n)
    f[0] = FORCE_SD_N * rng.standard_normal()
    for i in range(1, n):
        f[i] = a * f[i - 1] + FORCE_SD_N * np.sqrt(1 - a * a) * rng.standard_normal()
    u = np.zeros(n)
    for i in range(n - 1):
        def rhs(x: float, i: int = i) -> float:
            return (tau[i] + f[i] - damping(x)) / MASS_KG
        k1 = rhs(u[i])
        k2 = rhs(u[i] + DT_S / 2 * k1)
        k3 = rhs(u[i] + DT_S / 2 * k2)
        k4 = rhs(u[i] + DT_S * k3)
        u[i + 1] = u[i] + DT_S / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return pd.DataFrame({"t_ns": np.round(t * 1e9).astype(np.int64), "trial": f"s{seed}",
                         "u_mps": u + 0.005 * rng.standard_normal(n), "d_u_N": damping(u) - f, "tau_u_N": tau})


@pytest.fixture(scope="module")
def fitted():
    train = trial(1)
    study = run_study(train.iloc[:800], train.iloc[800:], dofs=["u"], models=["ls", "gp"], gp_max_samples=200,
                      max_samples=None, curve_points=2)
    return {m: study.get("u", m) for m in ("ls", "gp")}


def free_runs(result, frame: pd.DataFrame, *, force_error: bool = True, seed: int = 0, members: int = 64):
    u = frame[["u_mps"]].to_numpy()
    tau = frame[["tau_u_N"]].to_numpy()
    t_ns = frame["t_ns"].to_numpy()
    ranges = {"u": table_range(u[:, 0])}
    f = DecoupledDynamics(M, ["u"], damping_tables({"u": result.estimator}, ranges))
    band = None
    if hasattr(result.estimator, "sample_functions"):
        band = DecoupledDynamics(M, ["u"], band_tables({"u": result.estimator}, ranges, members, seed=seed))
    error = [ForceError.from_dict(result.interval["force_error"])] if force_error else None
    return run_model(result.model, f, t_ns, u, tau, ["u"], band_f=band, band_members=members, force_error=error,
                     seed=seed)[0]


def coverage(runs) -> float:
    inside = np.concatenate([(r.measured >= r.band[0]) & (r.measured <= r.band[1]) for r in runs])
    return float(inside.mean())


def test_out_of_fold_residuals_give_the_disturbance_sd_and_time_constant(fitted) -> None:
    for model, r in fitted.items():
        e = r.interval["force_error"]
        assert e["sd"] == pytest.approx(FORCE_SD_N, rel=0.15), (model, e)
        assert e["time_constant_s"] == pytest.approx(FORCE_TC_S, rel=0.4), (model, e)
        assert e["step_s"] == pytest.approx(DT_S) and e["rows"] == 3200


def test_band_with_the_force_error_covers_fresh_trials_measured_velocity(fitted) -> None:
    runs = [free_runs(fitted["ls"], trial(seed)) for seed in (2, 3, 4)]
    assert 0.90 <= coverage(runs) <= 0.98, coverage(runs)
    for r in runs:  # the summary reports the same share per trial
        assert 0.85 <= r.summary()["band_coverage"]["u"] <= 0.99


def test_gp_band_adds_its_posterior_functions_to_the_force_error(fitted) -> None:
    """The GP's members carry both: wider than the force error alone (here its posterior, inflated for the
    targets' correlated errors, is wide: docs/models.md, "Free-run bands")."""
    fresh = [trial(seed) for seed in (2, 3)]
    both = coverage([free_runs(fitted["gp"], fr) for fr in fresh])
    assert 0.90 <= both and both >= coverage([free_runs(fitted["gp"], fr, force_error=False) for fr in fresh])


def test_without_the_force_error_or_its_correlation_the_band_misses(fitted) -> None:
    """No force error: LS has no band. A white force error of the same SD averages out over the vehicle's time
    constant: its band is far too narrow, so the AR(1)'s time constant matters."""
    fresh = [trial(seed) for seed in (2, 3, 4)]
    assert free_runs(fitted["ls"], fresh[0], force_error=False).band is None
    white = dict(fitted["ls"].interval["force_error"], time_constant_s=0.0)
    ls = fitted["ls"]
    runs = [free_runs(type(ls)(**{**vars(ls), "interval": {"force_error": white}}), fr) for fr in fresh]
    assert coverage(runs) < 0.6, coverage(runs)


def test_band_is_the_same_bytes_for_the_same_seed(fitted) -> None:
    frame = trial(5).iloc[:1200]
    one, two = (free_runs(fitted["gp"], frame, members=16) for _ in range(2))
    assert one.band[0].tobytes() == two.band[0].tobytes() and one.band[1].tobytes() == two.band[1].tobytes()
    other = free_runs(fitted["gp"], frame, members=16, seed=1)
    assert other.band[0].tobytes() != one.band[0].tobytes()


def test_ar1_draws_and_fit_recover_sd_and_correlation_across_gaps() -> None:
    """Draws at 0.05 s of an AR(1) with T = 2 s; two segments with a gap and a second trial's clock starting over:
    the fit uses only pairs one step apart."""
    truth = ForceError(sd=2.5, time_constant_s=2.0)
    draws = truth.sample(4, 20_000, 0.05, np.random.default_rng(0))
    assert np.std(draws) == pytest.approx(2.5, rel=0.05)
    t = np.arange(20_000, dtype=np.int64) * 50_000_000
    t_ns = np.concatenate([t[:10_000], t[10_000:] + 10**12, t])  # a gap, then another trial from 0
    fit = fit_ar1(draws[:3].ravel()[:40_000], t_ns)
    assert fit.step_s == pytest.approx(0.05) and fit.pairs == 40_000 - 3
    assert fit.lag1 == pytest.approx(np.exp(-0.05 / 2.0), abs=0.005)
    assert fit.time_constant_s == pytest.approx(2.0, rel=0.15) and fit.sd == pytest.approx(2.5, rel=0.05)
    assert fit_ar1(np.random.default_rng(1).standard_normal(500), t[:500]).time_constant_s < 0.05  # white
    with pytest.raises(ValueError, match="2 force errors for 1 input"):
        run_model("m", lambda x, u: u - x, t[:50], np.zeros((50, 1)), np.zeros((50, 1)), ["u"], band_members=4,
                  force_error=[truth, truth])
