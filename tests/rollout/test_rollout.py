"""The integrator's order, and batched rollouts (every model, segment and window of a trial stepped together)
against the per-segment reference they replace."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.rollout import rollout

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
    from pipeline.rollout import CoupledDynamics, fast_predictor, free_run, horizon_errors
    from pipeline.sim.synthetic import SyntheticPlant, synthetic_trial
    from pipeline.vocabulary import TAU_COLUMNS, VELOCITY_COLUMNS

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
        fast = fast_predictor(est)
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
    assert fast_predictor(object()) is None


def test_graybox_free_run_through_its_fast_predictor_equals_sklearn_predict() -> None:
    """The gray box (McFarland-Whitcomb base + WDSE residual, the study's columns) rolls out through its parts'
    fast predictors (no scikit-learn call per RK4 stage) to the predict path's free run within float rounding;
    an unfitted gray box, or one whose residual offers no fast predictor, falls back to ``predict``."""
    from sklearn.linear_model import Ridge

    from pipeline.config.params import CoupledParams
    from pipeline.models.graybox import GrayBox
    from pipeline.rollout import CoupledDynamics, fast_predictor, free_run
    from pipeline.sim.synthetic import synthetic_frame
    from pipeline.studies.coupled import build_model, model_inputs

    params = CoupledParams()
    cols = model_inputs("graybox", params)
    train = synthetic_frame(600, rate_hz=4.0, seed=3, noise=0.02)
    test = synthetic_frame(240, rate_hz=4.0, seed=4, noise=0.02, split="test", trial="syn02")
    hyper = {o: {"gammas": [0.3, 0.2, 0.3, 0.1, 0.1, 0.1], "C": 1.0, "epsilon": 0.01} for o in params.outputs}
    est = build_model("graybox", hyper, params, train=train)
    assert fast_predictor(est) is None  # not fitted yet
    est.fit(train[cols].to_numpy(float), train[params.outputs].to_numpy(float))
    fast = fast_predictor(est)
    assert fast is not None
    X = test[cols].to_numpy(float)
    slow = est.predict(X)
    assert np.abs(fast(X) - slow).max() <= 1e-12 * max(1.0, np.abs(slow).max())
    nu, inputs = X[:, :3], X[:, 3:]
    t_ns = test["t_ns"].to_numpy()
    runs = [free_run("graybox", CoupledDynamics(est, fast=f), t_ns, nu, inputs, ["u", "v", "r"]) for f in (True, False)]
    assert np.isfinite(runs[1].predicted).all()
    assert np.abs(runs[0].predicted - runs[1].predicted).max() < 1e-10
    other = GrayBox(residual=Ridge()).fit(X, test[params.outputs].to_numpy(float))
    assert fast_predictor(other) is None


def _one_at_a_time(f, nu0, inputs, starts, lengths, dt_s, **kw):
    """The reference the batch replaces: each member rolled out alone with its own dynamics (take(f, [b]))."""
    from pipeline.rollout import rollout, take

    out, div = [], []
    clamp = kw.pop("clamp", None)
    for b, (a, n) in enumerate(zip(starts, lengths, strict=True)):
        extra = {} if clamp is None else {"clamp": clamp[None, a:a + n]}
        traj, d = rollout(take(f, np.array([b])), nu0[b][None], inputs[None, a:a + n], dt_s, **kw, **extra)
        out.append(traj[0])
        div.append(d[0])
    return np.concatenate(out), np.array(div)


def _band_like(n_members: int, scale: float = 1.0):
    """Decoupled dynamics with one damping table per batch member (as the GP's posterior functions)."""
    from pipeline.physics import coriolis_force
    from pipeline.rollout import DecoupledDynamics, Table1D
    from pipeline.sim.synthetic import SyntheticPlant

    plant = SyntheticPlant()
    grid = np.linspace(-3.0, 3.0, 301)
    factors = scale * np.linspace(0.6, 1.4, n_members)
    tables = {d: Table1D(-3.0, 3.0, factors[:, None] * plant.damping(d, grid)[None]) for d in ("u", "v", "r")}
    return DecoupledDynamics(plant.mass_matrix(), ["u", "v", "r"], tables, coriolis_force)


def test_ragged_batch_equals_one_member_at_a_time() -> None:
    """Members of different lengths (ending at different steps), two dynamics in one stack, per-member tables,
    a clamped DOF and a diverging member: the batch gives each member's lone rollout to float rounding."""
    from pipeline.rollout import DecoupledDynamics, MemberStack, rollout_ragged, stack

    rng = np.random.default_rng(3)
    n_rows, dt_s = 120, 0.05
    inputs = rng.normal(0.0, 20.0, (n_rows, 3))
    clamp = rng.normal(0.0, 0.2, (n_rows, 3))
    starts = np.array([0, 7, 30, 3, 50, 60, 11])
    lengths = np.array([37, 5, 1, 23, 60, 2, 90])
    group = np.array([0, 1, 1, 0, 1, 0, 1])
    unstable = _band_like(int((group == 1).sum()), scale=-3.0)  # negative damping: some members diverge
    shared = _band_like(1, scale=0.8)
    shared.damping = {d: type(t)(t.lo, t.hi, t.values[0, ::2]) for d, t in shared.damping.items()}  # other grid
    merged = stack([shared, unstable], group)  # one decoupled dynamics over a TableStack
    assert isinstance(merged, DecoupledDynamics)
    nu0 = rng.normal(0.0, 0.5, (starts.size, 3))
    bound = np.array([2.0, 2.0, 2.0])
    cases = [(MemberStack([lambda nu, u: -0.8 * nu * np.abs(nu) + 0.05 * u, unstable], group), {}),
             (MemberStack([shared, unstable], group), {"clamp_mask": np.array([False, False, True])}),
             (merged, {}), (merged, {"clamp_mask": np.array([False, False, True])})]
    results = []
    for f, kw in cases:
        c = {"clamp": clamp} if kw else {}
        flat, div = rollout_ragged(f, nu0, inputs, starts, lengths, dt_s, bound=bound, **kw, **c)
        results.append(flat)
        ref, ref_div = _one_at_a_time(f, nu0, inputs, starts, lengths, dt_s, bound=bound, **kw, **c)
        np.testing.assert_array_equal(div, ref_div)
        assert (div >= 0).any() and (div < 0).any()
        np.testing.assert_array_equal(np.isnan(flat), np.isnan(ref))
        np.testing.assert_allclose(flat, ref, rtol=1e-10, atol=1e-14)
    np.testing.assert_array_equal(results[3], results[1])  # the TableStack is Table1D's arithmetic


def test_free_run_band_and_horizons_batched_equal_per_segment_reference() -> None:
    """run_model (all runs, band members and horizon windows in one batch) against rolling each run, each
    band member and each horizon's windows separately, on a trial with three runs of different lengths."""
    from pipeline.rollout import divergence_bound, grid_step_s, rollout, run_model, run_models, segment_runs, windows
    from pipeline.sim.synthetic import SyntheticPlant, synthetic_trial
    from pipeline.vocabulary import TAU_COLUMNS, VELOCITY_COLUMNS

    plant = SyntheticPlant()
    trial = synthetic_trial(plant, duration_s=40.0, rate_hz=10.0, seed=4, gap_s=(9.0, 10.0))
    seg = trial["segment"].to_numpy().copy()
    seg[230:] = np.where(seg[230:] >= 0, seg[230:] + 5, seg[230:])  # a third run
    t_ns, nu = trial["t_ns"].to_numpy(), trial[[VELOCITY_COLUMNS[d] for d in ("u", "v", "r")]].to_numpy()
    tau = trial[[TAU_COLUMNS[d] for d in ("u", "v", "r")]].to_numpy()
    f, band = _band_like(1, scale=0.7).take(np.array([0])), _band_like(4)
    f.damping = {d: type(t)(t.lo, t.hi, t.values[0]) for d, t in f.damping.items()}  # one shared table
    run, hz = run_model("m", f, t_ns, nu, tau, ["u", "v", "r"], [1.0, 3.0], segment=seg, band_f=band,
                             band_members=4)
    dt_s, bound = grid_step_s(t_ns), divergence_bound(nu, 10.0)
    runs = segment_runs(t_ns, seg, dt_s)
    assert len({b - a for a, b in runs}) == 3
    for a, b in runs:
        traj, _ = rollout(f, nu[a][None], tau[None, a:b], dt_s, bound=bound)
        np.testing.assert_allclose(run.predicted[a:b], traj[0], rtol=1e-10, atol=1e-14)
        members, _ = rollout(band, np.repeat(nu[a][None], 4, 0), np.repeat(tau[None, a:b], 4, 0), dt_s, bound=bound)
        np.testing.assert_allclose(run.band[0][a:b], members.mean(0) - 2 * members.std(0), rtol=1e-10, atol=1e-14)
    for h in (1.0, 3.0):
        st = windows(t_ns, seg, dt_s, h)
        n = int(round(h / dt_s)) + 1
        idx = st[:, None] + np.arange(n)
        traj, _ = rollout(f, nu[st], tau[idx], dt_s, bound=bound)
        err = np.abs(traj - nu[idx])
        assert hz[f"{h:g}"]["n_windows"] == st.size
        assert hz[f"{h:g}"]["mae_end"]["u"] == pytest.approx(float(err[:, -1, 0].mean()), rel=1e-10)
        assert hz[f"{h:g}"]["mae_window"]["r"] == pytest.approx(float(err[:, :, 2].mean()), rel=1e-10)
    other = _band_like(3, scale=1.2).take(np.array([2, 2]))  # per-member tables for the two runs' members
    other.damping = {d: type(t)(t.lo, t.hi, t.values[0]) for d, t in other.damping.items()}
    both = run_models({"m": (f, band), "other": (other, None)}, t_ns, nu, tau, ["u", "v", "r"], [1.0, 3.0],
                           segment=seg, band_members=4)
    alone = run_model("other", other, t_ns, nu, tau, ["u", "v", "r"], [1.0, 3.0], segment=seg)
    for got, want in ((both["m"], (run, hz)), (both["other"], alone)):
        np.testing.assert_allclose(got[0].predicted, want[0].predicted, rtol=1e-10, atol=1e-14)
        assert got[1]["3"]["mae_end"]["v"] == pytest.approx(want[1]["3"]["mae_end"]["v"], rel=1e-10)
    np.testing.assert_allclose(both["m"][0].band[1], run.band[1], rtol=1e-10, atol=1e-14)


def test_bridging_of_all_models_and_outage_lengths_in_one_batch_equals_separate_calls() -> None:
    from pipeline.physics import coriolis_force
    from pipeline.rollout import DecoupledDynamics, bridge_outages
    from pipeline.sim.synthetic import SyntheticPlant, synthetic_trial
    from pipeline.vocabulary import TAU_COLUMNS, VELOCITY_COLUMNS

    plant = SyntheticPlant()
    trial = synthetic_trial(plant, duration_s=60.0, rate_hz=10.0, seed=5, gap_s=(20.0, 23.0))
    dofs = ["u", "v", "r"]
    t_ns, seg, yaw = trial["t_ns"].to_numpy(), trial["segment"].to_numpy(), trial["yaw_rad"].to_numpy()
    nu, tau = (trial[[c[d] for d in dofs]].to_numpy() for c in (VELOCITY_COLUMNS, TAU_COLUMNS))
    weak = DecoupledDynamics(plant.mass_matrix(), dofs, {d: (lambda x, d=d: 0.6 * plant.damping(d, x)) for d in dofs},
                             coriolis_force)
    models = {"truth": plant.as_dynamics(), "weak": weak}
    rows = bridge_outages(models, t_ns, nu, tau, yaw, dofs, [5.0, 12.0, 50.0], segment=seg)
    assert [r["window_s"] for r in rows] == [5.0] * 3 + [12.0] * 3  # 50 s fits in no run
    for r in rows:
        if r["model"] == "hold_last":
            continue
        alone = bridge_outages({r["model"]: models[r["model"]]}, t_ns, nu, tau, yaw, dofs, [r["window_s"]],
                               segment=seg)[1]
        assert alone["n_windows"] == r["n_windows"] and alone["n_diverged"] == r["n_diverged"]
        for k in ("mean_error_m", "median_error_m", "max_error_m"):
            assert r[k] == pytest.approx(alone[k], rel=1e-10)
