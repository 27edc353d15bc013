"""A ship-like trial from its raw files to trained coupled models, with no preprocessing by the user (issue 14).

One propeller (speed logged in rev/s), one rudder (deg), no lateral thruster; earth-frame x/y rates, heading (deg) and
yaw rate (deg/s) at 20 Hz in a whitespace table with a cp1252 preamble, no header and time rounded to 3 significant
digits. A hand-built 3-DOF model with known mass, damping, propeller thrust and rudder force makes the truth. All
the user writes is the vehicle YAML and the params: the blocks of the ship walkthrough in docs/user-guide.md, read
from the guide, so that the guide and the test cannot drift apart. The models trained on one zig-zag are scored
against the simulator's true accelerations on another (seed: the propeller's period and phase), which stays within
the first's envelope.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline import layout, physics, store
from pipeline.config import load_params, load_vehicle
from pipeline.layout import MODELS
from pipeline.models.card import load_model
from pipeline.studies.coupled import model_inputs
from pipeline.tableio import read_parquet
from stages import derive as derive_stage
from stages import differentiate as differentiate_stage
from stages import features as features_stage
from stages import ingest as ingest_stage
from stages import sync as sync_stage
from stages import train as train_stage
from stages import tune as tune_stage
from tests.cli.guide_helpers import guide_block

GUIDE_SECTION = "Walkthrough: a ship model in a towing tank"
VEHICLE_YAML = guide_block(GUIDE_SECTION, "yaml", "# ship.yaml")
PARAMS_YAML = guide_block(GUIDE_SECTION, "yaml", "# params.yaml")

M = np.diag([110.0, 180.0, 180.0, 11.0, 45.0, 60.0])


def _nudot(nu: np.ndarray, n_rpm: float, delta: float) -> np.ndarray:
    """M^-1 (tau - C(nu) nu - D(nu) nu) of the 3-DOF ship, written out for the diagonal M (30x faster than the
    general form; the zig-zag test checks that both agree)."""
    u, v, r = nu[0], nu[1], nu[5]
    m11, m22, m66 = M[0, 0], M[1, 1], M[5, 5]
    # rudder lift and the skeg's lift against the drift, both at the stern (1 m aft): without the skeg the hull's
    # Munk moment makes the ship course-unstable (eigenvalue +0.39/s at 0.8 m/s) and no 20 deg rudder checks a turn
    stern_Y = 40.0 * delta * u * abs(u) - 80.0 * u * v
    surge = 1e-4 * n_rpm * abs(n_rpm) + m22 * v * r - (20 * u + 30 * u * abs(u))
    sway = stern_Y - m11 * u * r - (60 * v + 80 * v * abs(v))
    yaw = -1.0 * stern_Y - (m22 - m11) * u * v - (15 * r + 20 * r * abs(r))
    return np.array([surge / m11, sway / m22, 0, 0, 0, yaw / m66])


def _steady_u(n_rpm: float) -> float:
    """Surge speed where the propeller's thrust meets the surge damping, straight ahead."""
    return float(np.roots([30.0, 20.0, -1e-4 * n_rpm**2]).max())


def simulate_zigzag(seed: int, duration_s: float = 150.0, rudder_rate_degps: float = 15.0
                    ) -> tuple[str, np.ndarray]:
    """(the table's text, true [udot vdot rdot] at each 20 Hz row): a 20/20 zig-zag, started straight at the
    propeller's steady speed, the rudder moved at ``rudder_rate_degps``; the propeller speed varies as a sine of a
    period and phase drawn from ``seed``, so every seed covers the same envelope (about 16 rudder switches)."""
    rng = np.random.default_rng(seed)
    h, sub = 0.01, 5
    period_s, phase = rng.uniform(40.0, 60.0), rng.uniform(0.0, 2 * np.pi)
    n0 = 600 + 200 * np.sin(phase)
    nu, psi, pos = np.array([_steady_u(n0), 0, 0, 0, 0, 0.0]), 0.0, np.zeros(2)
    delta, command, step = 0.0, np.deg2rad(20.0), np.deg2rad(rudder_rate_degps) * h
    rows, truth = [], []
    for k in range(int(duration_s / h)):
        t = k * h
        n_rpm = 600 + 200 * np.sin(2 * np.pi * t / period_s + phase)
        if psi < -np.deg2rad(20):  # a positive rudder turns the bow to port (psi falls): counter-rudder
            command = -np.deg2rad(20.0)
        elif psi > np.deg2rad(20):
            command = np.deg2rad(20.0)
        delta += np.clip(command - delta, -step, step)
        if k % sub == 0:
            u, v, r = nu[0], nu[1], nu[5]
            xdot, ydot = u * np.cos(psi) - v * np.sin(psi), u * np.sin(psi) + v * np.cos(psi)
            noise = rng.normal(0, [0.005, 0.005, 0.02, 0.05])
            rows.append([t, pos[0], pos[1], xdot + noise[0], ydot + noise[1], np.rad2deg(psi) + noise[2],
                         np.rad2deg(r) + noise[3], np.rad2deg(delta), n_rpm / 60])
            acc = _nudot(nu, n_rpm, delta)
            truth.append([acc[0], acc[1], acc[5]])
        k1 = _nudot(nu, n_rpm, delta)  # RK4 in nu, heading and position by the same steps
        k2 = _nudot(nu + h / 2 * k1, n_rpm, delta)
        k3 = _nudot(nu + h / 2 * k2, n_rpm, delta)
        k4 = _nudot(nu + h * k3, n_rpm, delta)
        psi += h * nu[5]
        pos += h * np.array([nu[0] * np.cos(psi) - nu[1] * np.sin(psi), nu[0] * np.sin(psi) + nu[1] * np.cos(psi)])
        nu = nu + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    preamble = "Towing tank run, zig-zag 20°/20°\nship model 1:25\nrudder in °, heading in °\nunits: s m m/s °\n"
    body = "\n".join("  ".join([f"{row[0]:.3g}"] + [f"{x:.6f}" for x in row[1:]]) for row in rows)
    return preamble + body + "\n", np.array(truth)


def test_the_simulated_trial_is_a_zigzag() -> None:
    """The rudder switches sides and checks each swing: a constant rudder (a ship circling) teaches nothing."""
    rng = np.random.default_rng(0)
    for _ in range(20):  # the written-out dynamics are M^-1 (tau - C(nu) nu - D(nu) nu)
        nu = np.zeros(6)
        nu[[0, 1, 5]] = rng.normal(0.0, 0.5, 3)
        n_rpm, delta = rng.uniform(400.0, 800.0), rng.uniform(-0.35, 0.35)
        u, v, r = nu[0], nu[1], nu[5]
        stern_Y = 40.0 * delta * u * abs(u) - 80.0 * u * v
        tau = np.array([1e-4 * n_rpm * abs(n_rpm), stern_Y, 0, 0, 0, -stern_Y])
        damping = np.array([20 * u + 30 * u * abs(u), 60 * v + 80 * v * abs(v), 0, 0, 0, 15 * r + 20 * r * abs(r)])
        general = np.linalg.solve(M, tau - physics.coriolis_force(M, nu[None])[0] - damping)
        np.testing.assert_allclose(_nudot(nu, n_rpm, delta), general, atol=1e-12)
    table = np.loadtxt(simulate_zigzag(1)[0].splitlines()[4:])
    rudder, heading = table[:, 7], table[:, 5]
    assert np.count_nonzero(np.diff(np.sign(rudder[np.abs(rudder) > 19.9]))) >= 10
    assert np.abs(heading).max() < 90.0


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_ship_zigzag_runs_from_raw_tables_to_coupled_models_with_rudder_and_propeller(
        tmp_path: Path, record_property: pytest.RecordProperty) -> None:
    (tmp_path / "ship.yaml").write_text(VEHICLE_YAML)
    vehicle = load_vehicle(tmp_path / "ship.yaml")
    truths = {}
    for trial, seed in (("z1", 1), ("z2", 2)):
        text, truths[trial] = simulate_zigzag(seed)
        (tmp_path / "data" / "raw" / trial).mkdir(parents=True)
        (tmp_path / "data" / "raw" / trial / "run01.dat").write_bytes(text.encode("cp1252"))
    (tmp_path / "params.yaml").write_text(PARAMS_YAML)
    params = load_params(tmp_path / "params.yaml")
    inputs, models = params.coupled.inputs, params.coupled.models
    assert inputs == ["u_mps", "v_mps", "r_radps", "rudder_rad", "n_prop_rpm"]
    assert params.coupled.actuators() == ["rudder_rad", "n_prop_rpm"] and params.features.test_trials == ["z2"]
    logs = [tmp_path / "data" / "raw" / t for t in ("z1", "z2")]
    for stage, extra in ((ingest_stage, {"logs": logs}), (sync_stage, {}), (differentiate_stage, {}),
                         (derive_stage, {}), (features_stage, {})):
        result = stage.run(tmp_path, vehicle, params, **extra)
        assert not result.quarantined, (stage.NAME, result.quarantined)

    rows = store.load(tmp_path)
    assert {"rudder_rad", "n_prop_rpm"} <= set(rows.columns)
    assert rows["rudder_rad"].abs().max() == pytest.approx(np.deg2rad(20.0), rel=1e-6)
    assert rows["n_prop_rpm"].max() > 700  # rev/s converted at ingest
    # the earth-frame rates were rotated into u, v: the accelerations match the simulator's truth
    for trial in ("z1", "z2"):
        part = rows[rows["trial"] == trial]
        truth = _truth_at(tmp_path, part, truths[trial])
        for j, col in enumerate(OUTPUTS):
            assert _r2(truth[:, j], part[col].to_numpy()) > 0.99, (trial, col)

    # the test trial stays within the training trial's envelope (measured: u 2.8 %, v and r 0.8 % of its rows
    # beyond the train_test block's range; a ship circling at constant rudder gave 5.3 %, 5.4 %, 2.4 %)
    train_test, test = rows[rows["split"] == "train_test"], rows[rows["split"] == "test"]
    for col in inputs:
        outside = np.mean((test[col] < train_test[col].min()) | (test[col] > train_test[col].max()))
        assert outside < 0.04 and train_test[col].std() > 0, (col, outside)

    tune_stage.run(tmp_path, vehicle, params)
    metrics = train_stage.run(tmp_path, vehicle, params).summary["metrics"]
    test = store.load(tmp_path, split="test")
    truth = _truth_at(tmp_path, test, truths["z2"])
    for model in models:
        estimator, _ = load_model(tmp_path / MODELS / "coupled" / f"{model}.joblib")
        predicted = estimator.predict(test[model_inputs(model, params.coupled)].to_numpy(float))
        for j, out in enumerate(OUTPUTS):
            m = metrics[model][out]
            m["final_r2_vs_truth"] = _r2(truth[:, j], predicted[:, j])
            record_property(f"{model}/{out}", {k: round(v, 4) for k, v in m.items()})
            print(f"{model:16s} {out:12s} CV {m['cv_test_r2']:.3f}  final {m['final_r2']:.3f}  "
                  f"final vs truth {m['final_r2_vs_truth']:.3f}")
            # measured: CV 0.94-0.999, final vs the targets 0.992-0.999 and vs the truth 0.994-0.999 (with
            # max_evals 4 one CV fold of the RBF's udot chose a kernel that scored 0.007 there: CV mean 0.66)
            assert m["final_r2_vs_truth"] > 0.95, (model, out, m)
            assert m["final_r2"] > 0.95, (model, out, m)
            assert m["cv_test_r2"] > 0.85, (model, out, m)


OUTPUTS = ("udot_mps2", "vdot_mps2", "rdot_radps2")


def _r2(truth: np.ndarray, estimate: np.ndarray) -> float:
    return float(1 - np.mean((estimate - truth) ** 2) / np.var(truth))


def _truth_at(root: Path, part: pd.DataFrame, truth: np.ndarray) -> np.ndarray:
    """The simulator's [udot vdot rdot] at the feature rows of one trial (its table's rows are 50 ms apart)."""
    trial = part["trial"].iloc[0]
    first = int(read_parquet(layout.stream_path(root, trial, "tank"))[0].column("t_ns")[0].as_py())
    k = np.round((part["t_ns"].to_numpy() - first) / 5e7).astype(int)
    return truth[k]
