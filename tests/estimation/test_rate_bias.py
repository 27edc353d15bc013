"""Rate-sensor biases from the logged attitude (pipeline.estimation.rate_bias), on trials with known answers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline.estimation.rate_bias import (
    PLAUSIBLE_BIAS_RADPS,
    debias,
    estimate_rate_biases,
    euler_rate_matrix,
)
from pipeline.estimation.smoother import Measurements

GRID_HZ, RATE_HZ = 20.0, 100.0


def test_euler_rate_matrix_inverts_the_body_rate_map() -> None:
    """T(Theta) maps body rates to Euler-angle rates; its inverse is Fossen's (2011, eq. 2.29-2.30, p. 25)
    [[1, 0, -s(theta)], [0, c(phi), c(theta) s(phi)], [0, -s(phi), c(theta) c(phi)]]. Roll and pitch far from
    zero and unequal, so a swapped entry or sign shows."""
    roll = np.array([0.3, -0.7, 1.1])
    pitch = np.array([-0.4, 0.9, 0.2])
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    inverse = np.zeros((3, 3, 3))
    inverse[:, 0, 0], inverse[:, 0, 2] = 1.0, -sp
    inverse[:, 1, 1], inverse[:, 1, 2] = cr, cp * sr
    inverse[:, 2, 1], inverse[:, 2, 2] = -sr, cp * cr
    T = euler_rate_matrix(roll, pitch)
    assert T.shape == (3, 3, 3)
    np.testing.assert_allclose(T @ inverse, np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-12)


def _attitude(t_s: np.ndarray, roll0: float = 0.0, pitch0: float = 0.0) -> np.ndarray:
    """Roll, pitch, yaw (n, 3) of a vehicle that rolls and pitches a little about (roll0, pitch0) and turns."""
    return np.stack([roll0 + 0.05 * np.sin(2 * np.pi * t_s / 17.0),
                     pitch0 + 0.04 * np.sin(2 * np.pi * t_s / 23.0 + 1.0),
                     0.8 * np.sin(2 * np.pi * t_s / 60.0) + 0.01 * t_s], axis=1)


def _attitude_rate(t_s: np.ndarray, roll0: float = 0.0, pitch0: float = 0.0) -> np.ndarray:
    return np.stack([0.05 * 2 * np.pi / 17.0 * np.cos(2 * np.pi * t_s / 17.0),
                     0.04 * 2 * np.pi / 23.0 * np.cos(2 * np.pi * t_s / 23.0 + 1.0),
                     0.8 * 2 * np.pi / 60.0 * np.cos(2 * np.pi * t_s / 60.0) + 0.01], axis=1)


def _body_rates(att: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """omega = T^-1 Theta_dot, written out (Fossen 2011, eq. 2.29's inverse), independent of the code tested."""
    sr, cr, sp, cp = np.sin(att[:, 0]), np.cos(att[:, 0]), np.sin(att[:, 1]), np.cos(att[:, 1])
    return np.stack([rate[:, 0] - sp * rate[:, 2],
                     cr * rate[:, 1] + cp * sr * rate[:, 2],
                     -sr * rate[:, 1] + cp * cr * rate[:, 2]], axis=1)


def synthetic(duration_s: float, bias: tuple[float, float, float], *, seed: int = 0, angle_noise: float = 1.7e-3,
              rate_noise: tuple[float, float, float] = (2e-3, 2e-3, 2e-4), roll0: float = 0.0, pitch0: float = 0.0,
              angle_corr_s: float = 0.0):
    """A trial with known attitude and body rates (omega = T^-1 Theta_dot, exact): the attitude on a 20 Hz grid
    with white (or, with ``angle_corr_s``, first-order Markov) errors; rates at 100 Hz with noise and ``bias``."""
    rng = np.random.default_rng(seed)
    grid_ns = np.arange(int(duration_s * GRID_HZ) + 1, dtype=np.int64) * int(1e9 / GRID_HZ)
    t_s = grid_ns / 1e9
    err = rng.standard_normal((t_s.size, 3))
    if angle_corr_s > 0:  # AR(1) at the grid step, same stationary SD
        a = np.exp(-1.0 / (GRID_HZ * angle_corr_s))
        for k in range(1, t_s.size):
            err[k] = a * err[k - 1] + np.sqrt(1 - a * a) * err[k]
    angles = _attitude(t_s, roll0, pitch0) + angle_noise * err
    rate_ns = np.arange(int(duration_s * RATE_HZ) + 1, dtype=np.int64) * int(1e9 / RATE_HZ) + 3_000_000
    rate_ns = rate_ns[rate_ns <= grid_ns[-1]]
    tr = rate_ns / 1e9
    att = _attitude(tr, roll0, pitch0)
    omega = _body_rates(att, _attitude_rate(tr, roll0, pitch0))
    rates = {d: Measurements(rate_ns, omega[:, j] + bias[j] + rate_noise[j] * rng.standard_normal(tr.size),
                             rate_noise[j] ** 2) for j, d in enumerate("pqr")}
    return grid_ns, angles, rates


SIGNALS = {"p": "p_gyro", "q": "q_gyro", "r": "r_fog"}


def _estimate(grid_ns, angles, rates, used=(True, True, True), ok=None):
    ok = np.ones(grid_ns.size, dtype=bool) if ok is None else ok
    return estimate_rate_biases(grid_ns, angles, ok, used, rates, {d: SIGNALS[d] for d in rates})


def test_a_known_bias_is_found_within_20_percent_and_its_sd_covers_it() -> None:
    bias = (3e-4, -2e-4, 1.5e-4)
    est = _estimate(*synthetic(240.0, bias, seed=1))
    for j, dof in enumerate("pqr"):
        e = est[dof]
        assert e.identifiable and e.signal == SIGNALS[dof]
        assert e.bias_radps == pytest.approx(bias[j], rel=0.2), dof
        assert abs(e.bias_radps - bias[j]) <= 3 * e.sd_radps, dof
        assert e.sd_radps < 0.1 * abs(bias[j]), dof  # informative, not merely wide


def test_zero_bias_gives_zero_within_its_sd() -> None:
    est = _estimate(*synthetic(240.0, (0.0, 0.0, 0.0), seed=2))
    for dof in "pqr":
        assert est[dof].identifiable
        assert abs(est[dof].bias_radps) <= 3 * est[dof].sd_radps, dof
        assert est[dof].sd_radps < 3e-5, dof


def test_roll_and_pitch_couple_the_rates_through_the_euler_relation() -> None:
    """Banked 30 deg and pitched -15 deg (asymmetric): a bias on q moves yaw by q sin(phi) / cos(theta) and pitch
    by q cos(phi); one on r moves yaw by r cos(phi) / cos(theta) and pitch by -r sin(phi). Noise-free: exact."""
    bias = (0.0, 2.5e-4, -1.5e-4)
    grid_ns, angles, rates = synthetic(240.0, bias, seed=3, angle_noise=0.0, rate_noise=(1e-9, 1e-9, 1e-9),
                                       roll0=np.radians(30.0), pitch0=np.radians(-15.0))
    est = _estimate(grid_ns, angles, rates)
    for j, dof in enumerate("pqr"):
        assert est[dof].bias_radps == pytest.approx(bias[j], abs=2e-6), dof
    # with yaw alone logged, q and r are told apart only through the coupling: still found
    est = _estimate(grid_ns, angles, rates, used=(False, False, True))
    assert not est["p"].identifiable  # yaw does not move with p
    assert est["r"].bias_radps == pytest.approx(bias[2], rel=0.05)


def test_wrapped_yaw_and_attitude_outliers_do_not_move_the_bias() -> None:
    bias = (3e-4, -2e-4, 1.5e-4)
    grid_ns, angles, rates = synthetic(240.0, bias, seed=4)
    angles[:, 2] = np.angle(np.exp(1j * (angles[:, 2] + 3.0)))  # turns through +-pi, wrapped as an AHRS gives it
    rng = np.random.default_rng(5)
    spikes = rng.choice(np.arange(10, grid_ns.size - 10), size=20, replace=False)
    clean = _estimate(grid_ns, angles, rates)
    angles[spikes, rng.integers(0, 3, size=20)] += rng.choice([-0.3, 0.3], size=20)
    est = _estimate(grid_ns, angles, rates)
    for j, dof in enumerate("pqr"):
        assert est[dof].bias_radps == pytest.approx(bias[j], rel=0.2), dof
        assert abs(est[dof].bias_radps - bias[j]) <= 3 * est[dof].sd_radps, dof
        # the outliers cost little: the same estimate, an SD at most twice that without them
        assert abs(est[dof].bias_radps - clean[dof].bias_radps) <= 0.5 * clean[dof].sd_radps, dof
        assert est[dof].sd_radps <= 2 * clean[dof].sd_radps, dof


def test_the_sd_is_honest_with_autocorrelated_attitude_errors() -> None:
    """Attitude errors correlated over 5 s (an AHRS's filter): over 30 trials the 2-sigma interval covers the true
    bias of the FOG (r) at least 80 % of the time (an SD for white errors covers far less)."""
    hits = []
    for seed in range(30):
        est = _estimate(*synthetic(240.0, (3e-4, -2e-4, 1.5e-4), seed=100 + seed, angle_corr_s=5.0,
                                   angle_noise=3e-3))
        hits.append(abs(est["r"].bias_radps - 1.5e-4) <= 2 * est["r"].sd_radps)
    assert np.mean(hits) >= 0.8


def test_a_short_trial_or_an_unlogged_attitude_keeps_the_rates_as_measured() -> None:
    grid_ns, angles, rates = synthetic(240.0, (3e-4, -2e-4, 1.5e-4), seed=6)
    ok = np.zeros(grid_ns.size, dtype=bool)
    ok[:int(40 * GRID_HZ)] = True  # 40 s of valid attitude
    est = _estimate(grid_ns, angles, rates, ok=ok)
    assert not any(e.identifiable for e in est.values())
    assert "under the 60 s" in est["r"].reason
    kept = debias(rates, est)
    assert all(np.array_equal(kept[d].y, rates[d].y) for d in "pqr")
    record = json.loads(json.dumps(est["r"].as_dict(), allow_nan=False))  # strict JSON: no NaN for "not estimated"
    assert record["bias_radps"] is None and record["sd_radps"] is None and "under the 60 s" in record["reason"]
    # yaw alone, level: roll and pitch are not logged, so p and q move no logged angle
    est = _estimate(grid_ns, angles, rates, used=(False, False, True))
    assert not est["p"].identifiable and "no logged attitude angle" in est["p"].reason
    # a sensor so noisy that the SD passes a plausible bias: not subtracted
    grid_ns, angles, rates = synthetic(70.0, (0.0, 0.0, 1e-4), seed=7, rate_noise=(2e-3, 2e-3, 0.5),
                                       angle_noise=0.05)
    est = _estimate(grid_ns, angles, rates)
    assert est["r"].sd_radps > PLAUSIBLE_BIAS_RADPS and not est["r"].identifiable
    assert np.array_equal(debias(rates, est)["r"].y, rates["r"].y)


@pytest.fixture(scope="module")
def hard_trial():
    from pipeline.sim import generate_trial, load_example_vehicle

    vehicle = load_example_vehicle()
    return vehicle, generate_trial(vehicle, 240.0, seed=3200, warmup_s=20.0, preset="hard")


@pytest.mark.parametrize("setting", ["estimate", "none"])
def test_hard_preset_biases_and_the_yaw_rate_band(hard_trial, setting) -> None:
    from pipeline.config import Params
    from pipeline.estimation.differentiate import differentiate
    from pipeline.sync import synchronize
    from tests.store.test_stages_features import signal_tables

    vehicle, trial = hard_trial
    params = Params()
    assert params.differentiate.rate_bias == "estimate"  # the default
    tables = signal_tables(trial, vehicle)
    synced = synchronize(tables, vehicle, params.sync)
    diff = params.differentiate.model_copy(update={"rate_bias": setting})
    kin, report = differentiate(synced, vehicle, diff, tables)
    truth = trial.truth.set_index("t_ns").loc[kin["t_ns"].to_numpy()]
    cover = np.mean(np.abs(kin["r_radps"].to_numpy() - truth["r_radps"].to_numpy())
                    <= 2 * kin["r_smooth_std_radps"].to_numpy())
    if setting == "none":
        assert "rate_bias" not in report
        assert cover < 0.5  # the bias the band misses
        return
    expected = {"p": trial.truth["gyro_bias_p_radps"].mean(), "q": trial.truth["gyro_bias_q_radps"].mean(),
                "r": trial.truth["fog_bias_r_radps"].mean()}
    for dof, value in expected.items():
        got = report["rate_bias"][dof]
        assert got["identifiable"] and got["subtracted"]
        assert got["bias_radps"] == pytest.approx(value, rel=0.2), dof
    assert report["rate_bias"]["r"]["signal"] == "r_fog_radps"
    assert 0.90 <= cover <= 0.98
