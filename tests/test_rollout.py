"""The integrator's order, and batched rollouts (every model, segment and window of a trial stepped together)
against the per-segment reference they replace."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.simulate import rollout

A_SYS = np.array([[-0.5, 2.0], [-2.0, -0.5]])  # a damped rotation: x(t) = x_ss + exp(A t) (x0 - x_ss)
C_SYS = np.array([0.3, -0.2])  # a constant input (zero-order hold is exact for it)


def _linear(nu: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    return nu @ A_SYS.T + inputs


def _exact(x0: np.ndarray, t_s: float) -> np.ndarray:
    a, w = -A_SYS[0, 0], A_SYS[0, 1]
    rot = np.exp(-a * t_s) * np.array([[np.cos(w * t_s), np.sin(w * t_s)], [-np.sin(w * t_s), np.cos(w * t_s)]])
    x_ss = -np.linalg.solve(A_SYS, C_SYS)
    return x_ss + rot @ (x0 - x_ss)


def _final_error(dt_s: float, method: str = "rk4", t_end_s: float = 4.0) -> float:
    n = int(round(t_end_s / dt_s)) + 1
    x0 = np.array([1.0, -0.5])
    traj, div = rollout(_linear, x0[None], np.tile(C_SYS, (1, n, 1)), dt_s, method=method)
    assert div[0] == -1
    return float(np.abs(traj[0, -1] - _exact(x0, t_end_s)).max())


def test_rk4_converges_at_fourth_order_on_a_closed_form_system() -> None:
    errors = [_final_error(dt) for dt in (0.1, 0.05, 0.025)]
    ratios = [errors[0] / errors[1], errors[1] / errors[2]]
    assert all(12.0 < r < 20.0 for r in ratios), (errors, ratios)
    assert errors[-1] < 1e-6


def test_euler_converges_at_first_order() -> None:
    ratio = _final_error(0.01, "euler") / _final_error(0.005, "euler")
    assert 1.7 < ratio < 2.3, ratio


def test_coupled_svr_free_run_through_numpy_kernel_sums_equals_sklearn_predict() -> None:
    """The fast path of CoupledDynamics (no scikit-learn call per RK4 stage) gives the predict path's free run and
    horizon errors to float rounding, gaps and all."""
    from pipeline.models.svr import RBFSVR, WDSESVR, PerOutputRegressor
    from pipeline.simulate import (
        TAU_COLUMNS,
        VELOCITY_COLUMNS,
        CoupledDynamics,
        SyntheticPlant,
        free_run,
        horizon_errors,
        svr_kernel_predictor,
        synthetic_trial,
    )

    plant = SyntheticPlant()
    train = synthetic_trial(plant, duration_s=60.0, rate_hz=10.0, seed=1)
    test = synthetic_trial(plant, duration_s=40.0, rate_hz=10.0, seed=2, gap_s=(20.0, 22.0))
    vel = [VELOCITY_COLUMNS[d] for d in ("u", "v", "r")]
    rpm = ["n1_rpm", "n2_rpm", "n3_rpm"]
    acc = plant.dynamics(train[vel].to_numpy(), train[[TAU_COLUMNS[d] for d in ("u", "v", "r")]].to_numpy())
    X = np.hstack([train[vel].to_numpy(), train[rpm].to_numpy()])
    for est in (PerOutputRegressor([RBFSVR(gamma=0.2, epsilon=0.01 * a.std()) for a in acc.T]),
                PerOutputRegressor([WDSESVR(gammas=[0.3, 0.2, 0.3, 0.1, 0.0, 0.1], epsilon=0.01 * a.std())
                                    for a in acc.T])):
        est.fit(X, acc)
        fast = svr_kernel_predictor(est)
        assert fast is not None
        assert np.abs(fast(X[:50]) - est.predict(X[:50])).max() < 1e-12
        t_ns, seg, nu, n = (test["t_ns"].to_numpy(), test["segment"].to_numpy(), test[vel].to_numpy(),
                            test[rpm].to_numpy())
        runs = [free_run("m", CoupledDynamics(est, fast=f), t_ns, nu, n, ["u", "v", "r"], segment=seg)
                for f in (True, False)]
        assert np.isnan(runs[0].predicted).sum() == np.isnan(runs[1].predicted).sum() > 0  # the gap
        assert np.nanmax(np.abs(runs[0].predicted - runs[1].predicted)) < 1e-10
        h = [horizon_errors(CoupledDynamics(est, fast=f), t_ns, nu, n, ["u", "v", "r"], [1.0, 5.0], segment=seg)
             for f in (True, False)]
        assert h[0]["5"]["mae_end"] == pytest.approx(h[1]["5"]["mae_end"], rel=1e-9)
    assert svr_kernel_predictor(object()) is None
