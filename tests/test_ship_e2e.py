"""A ship-like trial from its raw files to trained coupled models, with no preprocessing by the user (issue 14).

One propeller (speed logged in rev/s), one rudder (deg), no lateral thruster; earth-frame x/y rates, heading (deg) and
yaw rate (deg/s) at 20 Hz in a whitespace table with a cp1252 preamble, no header and time rounded to 3 significant
digits. A hand-built 3-DOF model with known mass, damping, propeller thrust and rudder force makes the truth; the
vehicle YAML below is all the user writes.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from pipeline import physics, store
from pipeline.config import Params, load_vehicle
from stages import derive as derive_stage
from stages import differentiate as differentiate_stage
from stages import features as features_stage
from stages import ingest as ingest_stage
from stages import sync as sync_stage
from stages import train as train_stage
from stages import tune as tune_stage

VEHICLE_YAML = """\
name: ship
rigid_body: {mass_kg: 100.0, inertia_kgm2: [[10, 0, 0], [0, 40, 0], [0, 0, 40]]}
added_mass: [[10, 0, 0, 0, 0, 0], [0, 80, 0, 0, 0, 0], [0, 0, 80, 0, 0, 0],
             [0, 0, 0, 1, 0, 0], [0, 0, 0, 0, 5, 0], [0, 0, 0, 0, 0, 20]]
thrusters:
  - {name: prop, speed_signal: n_prop_rpm, position_m: [-1.0, 0, 0], direction: [1, 0, 0],
     thrust: {k_fwd_N_per_rpm2: 1.0e-4}}
control_surfaces:
  - {name: rudder, angle_signal: rudder_rad}
sensors:
  velocity: {frame: earth, signals: [xdot_mps, ydot_mps]}
  attitude: {yaw: yaw_rad}
  rates: {r: r_radps}
streams:
  tank:
    file: run*.dat
    clock: column
    time: {rate_hz: 20}
    csv: {time_column: t, header: false, skip_rows: 4, encoding: cp1252,
          columns: [t, x, y, xdot, ydot, psi, r, delta, n]}
    signals:
      xdot_mps: {field: xdot}
      ydot_mps: {field: ydot}
      yaw_rad: {field: psi, unit: deg}
      r_radps: {field: r, unit: deg/s}
      rudder_rad: {field: delta, unit: deg}
      n_prop_rpm: {field: n, unit: rps}
"""

M = np.diag([110.0, 180.0, 180.0, 11.0, 45.0, 60.0])


def _nudot(nu: np.ndarray, n_rpm: float, delta: float) -> np.ndarray:
    u, v, r = nu[0], nu[1], nu[5]
    rudder_Y = 40.0 * delta * u * abs(u)  # rudder lift at the stern
    tau = np.array([1e-4 * n_rpm * abs(n_rpm), rudder_Y, 0, 0, 0, -1.0 * rudder_Y])
    damping = np.array([20 * u + 30 * u * abs(u), 60 * v + 80 * v * abs(v), 0, 0, 0, 15 * r + 20 * r * abs(r)])
    return np.linalg.solve(M, tau - physics.coriolis_force(M, nu[None])[0] - damping)


def simulate_zigzag(seed: int, duration_s: float = 150.0) -> tuple[str, np.ndarray]:
    """(the table's text, true [udot vdot rdot] at each 20 Hz row); a 20/20 zig-zag with a varying propeller."""
    rng = np.random.default_rng(seed)
    h, sub = 0.01, 5
    nu, psi, pos, delta = np.array([0.5, 0, 0, 0, 0, 0.0]), 0.0, np.zeros(2), np.deg2rad(20.0)
    rows, truth = [], []
    for k in range(int(duration_s / h)):
        t = k * h
        n_rpm = 600 + 200 * np.sin(2 * np.pi * t / (47 + 5 * seed))
        if psi > np.deg2rad(20):
            delta = -np.deg2rad(20.0)
        elif psi < -np.deg2rad(20):
            delta = np.deg2rad(20.0)
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


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_ship_zigzag_runs_from_raw_tables_to_coupled_models_with_rudder_and_propeller(tmp_path: Path) -> None:
    (tmp_path / "ship.yaml").write_text(VEHICLE_YAML)
    vehicle = load_vehicle(tmp_path / "ship.yaml")
    truths = {}
    for trial, seed in (("z1", 1), ("z2", 2)):
        text, truths[trial] = simulate_zigzag(seed)
        (tmp_path / "data" / "raw" / trial).mkdir(parents=True)
        (tmp_path / "data" / "raw" / trial / "run01.dat").write_bytes(text.encode("cp1252"))
    inputs = ["u_mps", "v_mps", "r_radps", "rudder_rad", "n_prop_rpm"]
    params = Params(features={"test_trials": ["z2"], "tuning_fraction": 0.25},
                    coupled={"inputs": inputs, "models": ["rbf_svr", "two_weights_svr", "wdse_svr"], "folds": 3,
                             "max_evals": 4, "max_samples": 300})
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
        k = np.round((part["t_ns"].to_numpy() - part["t_ns"].to_numpy().min()) / 5e7).astype(int)
        k += int(round((part["t_ns"].min() - _first_stamp(tmp_path, trial)) / 5e7))
        truth = truths[trial][k]
        for j, col in enumerate(("udot_mps2", "vdot_mps2", "rdot_radps2")):
            err = part[col].to_numpy() - truth[:, j]
            r2 = 1 - np.mean(err**2) / np.var(truth[:, j])
            assert r2 > 0.9, (trial, col, r2)

    if not os.environ.get("AUVID_SHIP_TRAIN"):
        pytest.skip("tune + train of the ship took 20 s to 4 min here (the search's GP seeding); AUVID_SHIP_TRAIN=1")
    tune_stage.run(tmp_path, vehicle, params)
    metrics = train_stage.run(tmp_path, vehicle, params).summary["metrics"]
    for model in ("two_weights_svr", "wdse_svr"):  # blocked CV on the train trial (z2's final R2 is low: open)
        for out in ("udot_mps2", "vdot_mps2", "rdot_radps2"):
            assert metrics[model][out]["cv_test_r2"] > 0.9, (model, out, metrics[model])


def _first_stamp(root: Path, trial: str) -> int:
    from pipeline import layout
    from pipeline.tableio import read_parquet

    return int(read_parquet(layout.stream_path(root, trial, "tank"))[0].column("t_ns")[0].as_py())
