"""The vehicle's model as the smoother's known input (pipeline.estimation.forced) and the smoother's joint
covariances, on signals whose right answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.estimation.forced import ForceModel, input_at, smooth_passes, smooth_with_input
from pipeline.estimation.smoother import Measurements, smooth, smoothed_variances, white_jerk
from pipeline.vocabulary import DOFS

H_NS = 50_000_000  # a 20 Hz grid, as the stages use
H_S = H_NS / 1e9


def _fast(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A velocity whose acceleration has content a 3.6 Hz sensor cannot resolve (periods 0.9-3 s), and an
    asymmetric slow part; returns (nu, nu_dot)."""
    nu = 0.3 * np.sin(0.4 * t + 0.2) + 0.02 * np.sin(7.0 * t) + 0.015 * np.cos(2.1 * t + 1.0) + 0.01 * t
    nudot = 0.12 * np.cos(0.4 * t + 0.2) + 0.14 * np.cos(7.0 * t) - 0.0315 * np.sin(2.1 * t + 1.0) + 0.01
    return nu, nudot


def _dvl_stamps(rng: np.random.Generator, duration_s: float) -> np.ndarray:
    """Pings 0.25-0.31 s apart, as the simulator's DVL (not on grid steps)."""
    return np.cumsum(rng.uniform(0.25, 0.31, int(duration_s / 0.25)))[:-5] + 0.013


def test_input_at_integrates_a_piecewise_linear_input_exactly_between_grid_steps() -> None:
    grid = np.arange(40, dtype=np.int64) * H_NS + 7
    a = np.cumsum(np.arange(40) % 7 - 2.5) * 0.1          # asymmetric, with kinks
    t = np.array([7, 7 + H_NS // 3, 7 + 5 * H_NS + 12_345_678, 7 + 38 * H_NS + H_NS // 2], dtype=np.int64)
    value, U = input_at(grid, a, t, 0)
    rate, _ = input_at(grid, a, t, 1)

    def exact(ts: float) -> float:  # the integral of the linear interpolation, by fine quadrature
        fine = np.linspace(grid[0] / 1e9, ts, 200_001)
        f = np.interp(fine, grid / 1e9, a)
        return float(np.sum((f[1:] + f[:-1]) / 2 * np.diff(fine)))

    np.testing.assert_allclose(value, [exact(x / 1e9) for x in t], atol=1e-9)
    np.testing.assert_allclose(rate, np.interp(t / 1e9, grid / 1e9, a), atol=1e-12)
    assert U[0] == 0.0 and U[-1] == pytest.approx(exact(grid[-1] / 1e9), abs=1e-9)


def test_with_the_true_model_and_noise_free_sensors_the_smoother_returns_the_true_acceleration() -> None:
    rng = np.random.default_rng(32)
    grid = np.arange(0, int(60 / H_S) + 1, dtype=np.int64) * H_NS
    t = grid / 1e9
    nu, nudot = _fast(t)
    ts = _dvl_stamps(rng, 59.0)
    y, _ = _fast(ts)
    meas = Measurements((ts * 1e9).astype(np.int64), y, 1e-8)   # noise-free, a floor for the variance
    forced = smooth_with_input(grid, meas, nudot, gate=0, input_error=True)
    kinematic = smooth(grid, meas, gate=0)
    inner = slice(100, -100)
    np.testing.assert_allclose(forced.xdot[inner], nudot[inner], atol=1e-4)
    # the velocity within the trapezoid rule's error on the input sampled at 20 Hz
    np.testing.assert_allclose(forced.x[inner], nu[inner], atol=1e-3)
    # the white-jerk smoother alone cannot follow the 7 rad/s content between pings as closely
    assert np.abs(kinematic.xdot[inner] - nudot[inner]).max() > 1e-3


def test_the_input_shifts_the_estimate_not_the_covariance() -> None:
    rng = np.random.default_rng(5)
    grid = np.arange(0, 1201, dtype=np.int64) * H_NS
    ts = _dvl_stamps(rng, 59.0)
    y = _fast(ts)[0] + 0.02 * rng.standard_normal(ts.size)
    meas = Measurements((ts * 1e9).astype(np.int64), y, 0.02**2)
    a = 0.1 * np.sin(grid / 1e9 * 3.0)
    plain, shifted = smooth(grid, meas, q=0.5, gate=0), smooth_with_input(grid, meas, a, q=0.5, gate=0)
    smoothed_variances([plain, shifted])
    np.testing.assert_allclose(shifted.x_sd, plain.x_sd, rtol=1e-9)
    np.testing.assert_allclose(shifted.xdot_sd, plain.xdot_sd, rtol=1e-9)
    # the same measurements less the input's integral, smoothed, plus the input: the likelihood is the same model
    # of the same data (unit Jacobian)
    U = input_at(grid, a, meas.t_ns)[0]
    direct = smooth(grid, Measurements(meas.t_ns, meas.y - U, meas.var), q=0.5, gate=0)
    assert shifted.loglik == pytest.approx(direct.loglik, rel=1e-12)


def test_joint_and_lag_two_covariances_are_the_textbook_rts() -> None:
    """cov(x, x') and cov(x_k, x_{k+2}) from the banded recursion against a Kalman filter + RTS smoother written
    step by step (Särkkä 2013, Th. 8.2 and the smoothed cross-covariance P_{k,k+1} = G_k P_{k+1})."""
    rng = np.random.default_rng(11)
    n, h = 400, 0.1
    grid = np.arange(n, dtype=np.int64) * 100_000_000
    keep = np.ones(n, dtype=bool)
    keep[::3] = False
    keep[200:230] = False
    k = np.flatnonzero(keep)
    r, q = 0.02**2, 0.05
    y = np.sin(0.5 * k * h) + 0.02 * rng.standard_normal(k.size)
    got = smooth(grid, Measurements(grid[k], y, r), q=q, gate=0)
    smoothed_variances([got], burn_s=1e9)
    phi, Q = white_jerk(h, q)
    S_inv = np.diag([1.0, 1.0 / h, 1.0 / h**2])
    P = S_inv @ (1e10 * np.eye(3)) @ S_inv
    x = np.zeros(3)
    Hm = np.array([1.0, 0.0, 0.0])
    obs = dict(zip(k.tolist(), y.tolist(), strict=True))
    xf, Pf, Pp = np.zeros((n, 3)), np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
    for i in range(n):
        if i:
            x, P = phi @ x, phi @ P @ phi.T + Q
        Pp[i] = P
        if i in obs:
            gain = P @ Hm / (Hm @ P @ Hm + r)
            x, P = x + gain * (obs[i] - x[0]), P - np.outer(gain, Hm @ P)
        xf[i], Pf[i] = x, P
    Ps, G = Pf.copy(), np.zeros((n, 3, 3))
    for i in range(n - 2, -1, -1):
        G[i] = Pf[i] @ phi.T @ np.linalg.inv(Pp[i + 1])
        Ps[i] = Pf[i] + G[i] @ (Ps[i + 1] - Pp[i + 1]) @ G[i].T
    lag2 = np.array([(G[i] @ G[i + 1] @ Ps[i + 2])[0, 0] for i in range(n - 2)])
    ok = slice(60, n - 2)
    np.testing.assert_allclose(got.x_xdot_cov[ok], Ps[ok, 0, 1], rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(got.x_lag2_cov[: n - 2][ok], lag2[ok], rtol=1e-5, atol=1e-12)


def _plant(seed: int, duration_s: float = 120.0, model_error: float = 0.0):
    """Surge of a vehicle with linear + quadratic damping driven by a known thrust with fast reversals, logged with
    white noise as a speed sensor gives it; a DVL-like
    sensor. Returns (grid, measurements, ForceModel, true nu_dot)."""
    rng = np.random.default_rng(seed)
    m, d1, d2 = 90.0, 20.0, 40.0
    fine = 1e-3
    tt = np.arange(0, duration_s + fine / 2, fine)
    tau = 60 * np.tanh(4 * np.sin(2 * np.pi * tt / 7.0)) + 15 * np.sin(0.9 * tt)   # reversals within ~0.3 s
    u = np.zeros(tt.size)
    for i in range(1, tt.size):  # semi-implicit Euler at 1 kHz: the truth
        acc = (tau[i - 1] - d1 * u[i - 1] - d2 * u[i - 1] * abs(u[i - 1])) / m
        u[i] = u[i - 1] + fine * acc
    udot = (tau - d1 * u - d2 * u * np.abs(u)) / m
    step = int(round(H_S / fine))
    grid = (tt[::step] * 1e9).round().astype(np.int64)
    ts = _dvl_stamps(rng, duration_s - 1.0)
    y = np.interp(ts, tt, u) + 0.02 * rng.standard_normal(ts.size)
    meas = {"u": Measurements((ts * 1e9).astype(np.int64), y, 0.02**2)}
    n = grid.size
    M = np.diag([m, 100.0, 100.0, 10.0, 10.0, 10.0])
    tau6 = np.zeros((n, 6))
    tau6[:, 0] = tau[::step] * (1 + model_error) + 1.5 * rng.standard_normal(n)
    noise_var = np.zeros((n, 6))
    noise_var[:, 0] = (1.5 / m) ** 2  # the logged thrust's noise, as force_model estimates it from the signal
    model = ForceModel(M=M, M_inv=np.linalg.inv(M), tau=tau6, g=np.zeros((n, 6)), noise_var=noise_var)
    return grid, meas, model, udot[::step]


def test_passes_never_lower_the_likelihood_and_lift_the_targets() -> None:
    grid, meas, model, truth = _plant(1)
    best, inputs, report = smooth_passes(grid, meas, model, passes=3, process_noise={}, gate=5.0, dofs=DOFS)
    history = report["passes"]
    kinematic = history[0]["loglik"]["u"]
    assert best["u"].loglik >= kinematic
    chosen = report["chosen"]["u"]
    assert chosen >= 1 and inputs["u"] is not None
    assert best["u"].loglik == max(h["loglik"]["u"] for h in history[: chosen + 1])

    def rmse(x: np.ndarray) -> float:
        inner = slice(100, -100)
        return float(np.sqrt(np.mean((x[inner] - truth[inner]) ** 2)))

    plain = smooth_passes(grid, meas, model, passes=0, process_noise={}, gate=5.0, dofs=DOFS)[0]
    assert rmse(best["u"].xdot) <= 0.6 * rmse(plain["u"].xdot)
    # an honest band: 2-sigma covers the true acceleration 90-99 % of the time
    inner = slice(100, -100)
    cover = np.mean(np.abs(best["u"].xdot - truth)[inner] <= 2 * best["u"].xdot_sd[inner])
    assert 0.9 <= cover <= 0.99


def test_a_wrong_model_is_not_taken() -> None:
    """Thrust logged 3 times too large: the model explains the data worse than the kinematic smoother, and the DOF
    keeps the kinematic result."""
    grid, meas, model, _ = _plant(2, model_error=2.0)
    best, inputs, report = smooth_passes(grid, meas, model, passes=3, process_noise={}, gate=5.0, dofs=DOFS)
    assert len(report["passes"]) == 3  # passes 1 and 2 tried, then stopped
    for h in report["passes"][1:]:
        assert h["loglik"]["u"] < report["passes"][0]["loglik"]["u"]
    assert report["chosen"]["u"] == 0 and inputs["u"] is None


def test_an_input_noisier_than_what_it_explains_is_not_taken() -> None:
    """Roll under a restoring moment computed from a noisy attitude, say: here the logged thrust carries white noise
    of 60 N the model does not know of. The input-error term absorbs it (the likelihood may rise) but the
    derivative would be worse than the kinematic smoother's: the DOF keeps the kinematic result."""
    grid, meas, model, truth = _plant(3)
    rng = np.random.default_rng(33)
    noisy = model.tau.copy()
    noisy[:, 0] += 20.0 * rng.standard_normal(noisy.shape[0])
    model = ForceModel(M=model.M, M_inv=model.M_inv, tau=noisy, g=model.g, noise_var=None)
    best, inputs, report = smooth_passes(grid, meas, model, passes=3, process_noise={}, gate=5.0, dofs=DOFS)
    assert max(h["loglik"]["u"] for h in report["passes"][1:]) > report["passes"][0]["loglik"]["u"]
    assert report["chosen"]["u"] == 0 and inputs["u"] is None


def test_excitation_report_gives_the_resolved_band_and_the_power_above_it() -> None:
    """Thrust-driven acceleration: a 0.05 Hz sine and a 1 Hz sine of half its amplitude (a fifth of the power
    above any band between them); the band from the kinematic smoother's q, the sensor's noise and interval."""
    from pipeline.estimation.forced import excitation_report

    grid = np.arange(0, 200 * 20, dtype=np.int64) * H_NS              # 200 s, whole periods of both sines
    t = grid / 1e9
    n = grid.size
    tau = np.zeros((n, 6))
    tau[:, 1] = 100.0 * (np.sin(2 * np.pi * 0.05 * t) + 0.5 * np.sin(2 * np.pi * 1.0 * t))
    M = np.diag([90.0, 100.0, 100.0, 10.0, 10.0, 10.0])
    model = ForceModel(M=M, M_inv=np.linalg.inv(M), tau=tau, g=np.zeros((n, 6)))
    r, interval, f_c = 0.02**2, 0.25, 0.3
    q = (2 * np.pi * f_c) ** 6 * r * interval
    stamps = np.arange(0, 199, interval)
    meas = {"v": Measurements((stamps * 1e9).astype(np.int64), np.zeros(stamps.size), r)}
    out = excitation_report(grid, model, meas, [{"process_noise": {"v": q}}])
    assert set(out) == {"v"}
    assert out["v"]["resolved_band_hz"] == pytest.approx(f_c, rel=1e-9)
    assert out["v"]["power_above_band"] == pytest.approx(0.2, abs=1e-6)
    assert excitation_report(grid, None, meas, [{"process_noise": {"v": q}}]) == {}
