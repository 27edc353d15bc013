"""A velocity sensor's yaw misalignment from the model-aware smoother's profile likelihood, on a plant whose
answer is known."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.estimation.dvl_alignment import Misalignment, estimate_misalignment, turned, widen_for_misalignment
from pipeline.estimation.forced import ForceModel, smooth_passes
from pipeline.estimation.smoother import Measurements, Smoothed
from pipeline.vocabulary import DOFS

H_NS = 50_000_000


def _plant(seed: int, misalignment_deg: float, noise: float, duration_s: float = 240.0):
    """Surge and sway, each with linear + quadratic damping, driven by known thrusts with fast reversals at
    different periods; a DVL at 3.6 Hz whose mount is ``misalignment_deg`` off in yaw. Returns the grid, the
    measurements, the force model and the true (u, v)."""
    rng = np.random.default_rng(seed)
    fine = 1e-3
    tt = np.arange(0, duration_s + fine / 2, fine)
    m = np.array([90.0, 135.0])
    d1, d2 = np.array([20.0, 30.0]), np.array([40.0, 80.0])
    tau = np.stack([60 * np.tanh(4 * np.sin(2 * np.pi * tt / 9.0)) + 10 * np.sin(0.7 * tt),
                    70 * np.tanh(4 * np.sin(2 * np.pi * tt / 5.5 + 1.0)) + 12 * np.sin(1.1 * tt)], axis=1)
    nu = np.zeros((tt.size, 2))
    for i in range(1, tt.size):
        nu[i] = nu[i - 1] + fine * (tau[i - 1] - d1 * nu[i - 1] - d2 * nu[i - 1] * np.abs(nu[i - 1])) / m
    step = int(round(H_NS / 1e9 / fine))
    grid = (tt[::step] * 1e9).round().astype(np.int64)
    ts = np.cumsum(rng.uniform(0.25, 0.31, int(duration_s / 0.25)))
    ts = ts[ts < duration_s - 1.0]
    true = np.stack([np.interp(ts, tt, nu[:, 0]), np.interp(ts, tt, nu[:, 1])], axis=1)
    psi = np.radians(misalignment_deg)   # measured = R_z(-psi) true
    um = np.cos(psi) * true[:, 0] + np.sin(psi) * true[:, 1] + noise * rng.standard_normal(ts.size)
    vm = -np.sin(psi) * true[:, 0] + np.cos(psi) * true[:, 1] + noise * rng.standard_normal(ts.size)
    stamps = (ts * 1e9).astype(np.int64)
    meas = {"u": Measurements(stamps, um, noise**2), "v": Measurements(stamps, vm, noise**2)}
    n = grid.size
    M = np.diag([m[0], m[1], 100.0, 10.0, 10.0, 10.0])
    tau6 = np.zeros((n, 6))
    tau6[:, :2] = tau[::step]
    model = ForceModel(M=M, M_inv=np.linalg.inv(M), tau=tau6, g=np.zeros((n, 6)))
    return grid, meas, model


@pytest.mark.parametrize("truth_deg", [1.5, -2.0])
def test_a_misalignment_the_model_pins_down_is_found_within_0_2_deg(truth_deg: float) -> None:
    grid, meas, model = _plant(5, truth_deg, noise=0.005, duration_s=480.0)
    best, inputs, _ = smooth_passes(grid, meas, model, passes=3, process_noise={}, gate=5.0, dofs=DOFS)
    assert inputs["u"] is not None and inputs["v"] is not None
    found = estimate_misalignment(grid, meas["u"], meas["v"], best["u"], best["v"], inputs["u"], inputs["v"])
    assert found.identifiable, found
    assert found.estimate_deg == pytest.approx(truth_deg, abs=0.2)
    assert found.sd_deg <= 0.1
    # turning the measurements back by the estimate gives the true velocities' relation back
    u, v = turned(meas["u"], meas["v"], np.radians(found.estimate_deg))
    back_u, back_v = turned(u, v, -np.radians(found.estimate_deg))
    np.testing.assert_allclose(back_u.y, meas["u"].y, atol=1e-12)
    np.testing.assert_allclose(back_v.y, meas["v"].y, atol=1e-12)


def test_without_the_model_or_with_a_noisy_sensor_it_is_not_claimed() -> None:
    grid, meas, model = _plant(6, 1.0, noise=0.005)
    plain, inputs, _ = smooth_passes(grid, meas, model, passes=0, process_noise={}, gate=5.0, dofs=DOFS)
    found = estimate_misalignment(grid, meas["u"], meas["v"], plain["u"], plain["v"], inputs["u"], inputs["v"])
    assert not found.identifiable and "model was not taken" in found.reason
    grid, meas, model = _plant(6, 1.0, noise=0.08, duration_s=60.0)   # a poor DVL on a short trial
    best, inputs, _ = smooth_passes(grid, meas, model, passes=3, process_noise={}, gate=5.0, dofs=DOFS)
    found = estimate_misalignment(grid, meas["u"], meas["v"], best["u"], best["v"], inputs["u"], inputs["v"])
    assert not found.identifiable and found.reason


def test_the_prior_on_the_mount_is_combined_by_precisions_and_undone_only_beyond_its_sd() -> None:
    trial = Misalignment(estimate_deg=3.0, sd_deg=1.5, identifiable=False, reason="wide")
    post = trial.with_prior(2.0)                       # weight 4 / (4 + 2.25) = 0.64
    assert post.posterior_deg == pytest.approx(1.92) and post.posterior_sd_deg == pytest.approx(1.2)
    assert post.applied                                # 1.92 > 1.2
    weak = Misalignment(estimate_deg=0.5, sd_deg=1.0, identifiable=False).with_prior(2.0)
    assert weak.posterior_deg == pytest.approx(0.4) and not weak.applied   # 0.4 < sqrt(0.8)
    assert Misalignment(None, None, False, "no model").with_prior(2.0).posterior_sd_deg == 2.0
    exact = trial.with_prior(0.0)
    assert exact.posterior_deg == 0.0 and exact.posterior_sd_deg == 0.0 and not exact.applied


def test_the_mount_error_left_widens_u_and_v_by_the_other_velocity() -> None:
    n = 5

    def result(x: float, xdot: float) -> Smoothed:
        return Smoothed(x=np.full(n, x), xdot=np.full(n, xdot), q=1.0, loglik=0.0, used=n, gated=0,
                        x_sd=np.full(n, 0.01), xdot_sd=np.full(n, 0.002))

    u, v = result(1.2, 0.05), result(-0.3, 0.02)
    kept = Misalignment(0.5, 1.0, False).with_prior(2.0)          # not undone: RMS of the posterior is left
    widen_for_misalignment(u, v, kept)
    rms = np.radians(np.hypot(kept.posterior_deg, kept.posterior_sd_deg))
    np.testing.assert_allclose(u.x_sd, np.hypot(0.01, rms * 0.3))
    np.testing.assert_allclose(v.x_sd, np.hypot(0.01, rms * 1.2))
    np.testing.assert_allclose(u.xdot_sd, np.hypot(0.002, rms * 0.02))
    np.testing.assert_allclose(v.xdot_sd, np.hypot(0.002, rms * 0.05))
    u2, v2 = result(1.2, 0.05), result(-0.3, 0.02)
    widen_for_misalignment(u2, v2, Misalignment(None, None, False, "no model").with_prior(2.0))
    assert (u2.x_sd == 0.01).all() and (v2.xdot_sd == 0.002).all()   # no likelihood: nothing claimed
