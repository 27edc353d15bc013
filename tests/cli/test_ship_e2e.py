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

import json
import re
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pipeline import layout, physics, store
from pipeline.config import load_params, load_vehicle
from pipeline.layout import MODELS
from pipeline.models.card import load_model
from pipeline.sim.tank import M, nudot, simulate_zigzag
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
        np.testing.assert_allclose(nudot(nu, n_rpm, delta), general, atol=1e-12)
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
    for trial in ("z1", "z2"):  # a clean zig-zag: nothing taken for a disturbance and removed
        assert json.loads(layout.estimation_report_path(tmp_path, trial).read_text())["disturbances"] == []

    rows = store.load(tmp_path)
    assert {"rudder_rad", "n_prop_rpm"} <= set(rows.columns)
    assert rows["rudder_rad"].abs().max() == pytest.approx(np.deg2rad(20.0), rel=1e-6)
    assert rows["n_prop_rpm"].max() > 700  # rev/s converted at ingest
    # the guide's rudder lift model reaches tau: 1/2 rho A C_La = 40 N/rad/(m/s)^2 at 1 m aft, the angle of attack
    # the rudder angle less the cross-flow's v - r over u (the propeller pushes along x: no sway force, no moment)
    u, v, r, delta = (rows[c].to_numpy() for c in ("u_mps", "v_mps", "r_radps", "rudder_rad"))
    lift = 40.0 * (delta - np.arctan2(v - r, np.abs(u))) * u * u
    assert np.std(lift) > 1.0  # the zig-zags' rudder force, not a constant
    np.testing.assert_allclose(rows["tau_v_N"], lift, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(rows["tau_r_Nm"], -lift, rtol=1e-9, atol=1e-9)
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


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_vibration_on_the_measured_surge_is_named_and_removed_with_the_defaults(tmp_path: Path) -> None:
    """A 2-Hz narrow-band disturbance (0.02 m/s) on the measured surge of both zig-zags, the guide's ship.yaml and
    params.yaml as they are: `auvid run` removes it (differentiate.disturbances: remove, the default), the report
    names it (frequency and output), and every SVR predicts the unseen zig-zag's true accelerations within 0.03 of
    the ceiling (the true model at the same estimated inputs). Left in, u̇'s SVRs score below 0
    (bench/ship_ringing.py, docs/benchmarks.md)."""
    from pipeline.cli import main as auvid

    (tmp_path / "ship.yaml").write_text(VEHICLE_YAML)
    (tmp_path / "params.yaml").write_text(PARAMS_YAML)
    truths = {}
    for trial, seed in (("z1", 1), ("z2", 2)):
        text, truths[trial] = simulate_zigzag(seed, ring_mps=0.02, ring_hz=2.0)
        (tmp_path / "tank" / trial).mkdir(parents=True)
        (tmp_path / "tank" / trial / "run01.dat").write_bytes(text.encode("cp1252"))
    root = tmp_path / "runs"
    config = ["--root", str(root), "--vehicle", str(tmp_path / "ship.yaml"), "--params", str(tmp_path / "params.yaml")]
    assert auvid(["run", *config, "--to", "train", str(tmp_path / "tank/z1"), str(tmp_path / "tank/z2")]) == 0
    assert auvid(["report", *config]) == 0
    html = (root / "reports" / "report.html").read_text(encoding="utf-8")
    for trial in ("z1", "z2"):
        assert re.search(rf"{trial}: u̇ carried a narrow-band disturbance at 2\.0\d Hz \(\d+ % of its variance\)", html)
    assert "v̇ carried" not in html and "ṙ carried" not in html

    params = load_params(tmp_path / "params.yaml")
    test = store.load(root, split="test")
    truth = _truth_at(root, test, truths["z2"])
    nu = np.zeros((len(test), 6))
    nu[:, 0], nu[:, 1], nu[:, 5] = test["u_mps"], test["v_mps"], test["r_radps"]
    ceiling = nudot(nu, test["n_prop_rpm"].to_numpy(), test["rudder_rad"].to_numpy())[:, [0, 1, 5]]
    for model in params.coupled.models:
        estimator, _ = load_model(root / MODELS / "coupled" / f"{model}.joblib")
        predicted = estimator.predict(test[model_inputs(model, params.coupled)].to_numpy(float))
        for j, out in enumerate(OUTPUTS):
            gap = _r2(truth[:, j], ceiling[:, j]) - _r2(truth[:, j], predicted[:, j])
            assert gap < 0.03, (model, out, gap)
