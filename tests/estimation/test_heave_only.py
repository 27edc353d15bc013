"""A heave-only vehicle: a depth-hold trial (a depth sensor and the vertical thrust, no attitude) from text tables
through sync, differentiate, derive and features (issue 34, item 3).

The known answer: a vertical thruster's logged thrust drives the heave model
(m + Z_wdot) w' = T + W - B - Z_w w - Z_ww w|w| (NED: z and T down; the vehicle 3 N buoyant), integrated finely, up
and down; its depth, sampled at 10 Hz with 2 mm of noise, is the only motion sensor (``sensors.position`` with
``components: [z]``), and without ``sensors.attitude`` the vehicle is taken as level. Then w, w', tau_w, g_w and the
damping target d_w match the model, and a least-squares fit of tau_w - M w' on (1, w, w|w|) over the feature store
gives back B - W, Z_w and Z_ww.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline import store
from pipeline.config import Params, load_vehicle
from pipeline.errors import ConfigError
from stages import derive as derive_stage
from stages import differentiate as differentiate_stage
from stages import features as features_stage
from stages import ingest as ingest_stage
from stages import sync as sync_stage

EPOCH_S = 1_700_000_000.0
DURATION_S = 120.0
MASS, ADDED_W = 11.5, 14.57
M33 = MASS + ADDED_W
ZW, ZWW = 5.0, 20.0
G = 9.81
WEIGHT_N = MASS * G
BUOYANCY_N = WEIGHT_N + 3.0
DEPTH0_M, DEPTH_SD_M = 5.0, 0.002

VEHICLE = {
    "name": "heaver",
    "rigid_body": {"mass_kg": MASS, "inertia_kgm2": np.diag([0.16] * 3).tolist(), "cg_m": [0.0, 0.0, 0.0],
                   "cb_m": [0.0, 0.0, 0.0], "buoyancy_N": BUOYANCY_N},
    "added_mass": np.diag([5.5, 12.7, ADDED_W, 0.12, 0.12, 0.12]).tolist(),
    "thrusters": [{"name": "vert", "thrust_signal": "thrust_N", "position_m": [0.0, 0.0, 0.0],
                   "direction": [0.0, 0.0, 1.0]}],
    "sensors": {"position": {"signals": ["depth_m"], "components": ["z"]}, "depth": "depth_m"},
    "streams": {
        "depth": {"file": "depth.csv", "clock": "column", "signals": {"depth_m": {"field": "depth"}},
                  "csv": {"time_column": "t", "time_origin": "relative", "epoch_s": EPOCH_S}},
        "thrust": {"file": "thrust.csv", "clock": "column", "signals": {"thrust_N": {"field": "thrust"}},
                   "csv": {"time_column": "t", "time_origin": "relative", "epoch_s": EPOCH_S}},
    },
}


def thrust_N(t_s: np.ndarray) -> np.ndarray:
    """The vertical thrust (N, down): around the buoyancy's 3 N, so the vehicle goes both up and down."""
    return 3.0 + 15.0 * np.sin(2 * np.pi * t_s / 20.0) + 6.0 * np.sin(2 * np.pi * t_s / 7.3)


def heave(w: np.ndarray | float, thrust: np.ndarray | float) -> np.ndarray | float:
    return (thrust + WEIGHT_N - BUOYANCY_N - ZW * w - ZWW * w * np.abs(w)) / M33


def truth(h_s: float = 1e-3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(t, depth, w) of the heave model, RK4 at ``h_s`` from rest at DEPTH0_M."""
    t = np.arange(int(round(DURATION_S / h_s)) + 1) * h_s
    z, w = np.empty_like(t), np.empty_like(t)
    z[0], w[0] = DEPTH0_M, 0.0
    for k in range(t.size - 1):
        tk, x = t[k], w[k]
        k1 = heave(x, thrust_N(tk))
        k2 = heave(x + h_s / 2 * k1, thrust_N(tk + h_s / 2))
        k3 = heave(x + h_s / 2 * k2, thrust_N(tk + h_s / 2))
        k4 = heave(x + h_s * k3, thrust_N(tk + h_s))
        w[k + 1] = x + h_s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        z[k + 1] = z[k] + h_s / 6 * (x + 2 * (x + h_s / 2 * k1) + 2 * (x + h_s / 2 * k2) + (x + h_s * k3))
    return t, z, w


def write_trial(trial: Path, seed: int = 0) -> None:
    rng = np.random.default_rng(seed)
    t, z, _ = truth()
    trial.mkdir(parents=True)
    t_depth = np.arange(0.0, DURATION_S, 0.1) + 0.013
    depth = np.interp(t_depth, t, z) + rng.normal(0.0, DEPTH_SD_M, t_depth.size)
    (trial / "depth.csv").write_text("t,depth\n" + "".join(f"{a:.4f},{b:.5f}\n" for a, b in zip(t_depth, depth,
                                                                                                    strict=True)))
    t_thrust = np.arange(0.0, DURATION_S, 0.05)
    (trial / "thrust.csv").write_text("t,thrust\n" + "".join(f"{a:.4f},{b:.6f}\n" for a, b in zip(
        t_thrust, thrust_N(t_thrust), strict=True)))


@pytest.fixture(scope="module")
def features(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object]:
    home = tmp_path_factory.mktemp("heave")
    (home / "heaver.yaml").write_text(yaml.safe_dump(VEHICLE, sort_keys=False))
    write_trial(home / "dives" / "hold01")
    vehicle = load_vehicle(home / "heaver.yaml")
    root, params = home / "runs", Params()
    for stage, extra in ((ingest_stage, {"logs": [home / "dives" / "hold01"]}), (sync_stage, {}),
                         (differentiate_stage, {}), (derive_stage, {}), (features_stage, {})):
        result = stage.run(root, vehicle, params, **extra)
        assert not result.quarantined, (stage.NAME, result.quarantined)
    return root, store.load(root)


def test_a_depth_hold_trial_without_attitude_gives_heave_and_its_forces(features, caplog) -> None:
    _, rows = features
    t_s = (rows["t_ns"].to_numpy() - int(EPOCH_S * 1e9)) / 1e9
    assert t_s.min() < 3.0 and t_s.max() > DURATION_S - 3.0
    t, _, w_true = truth()
    w = np.interp(t_s, t, w_true)
    thrust = thrust_N(t_s)
    assert w.min() < -0.3 and w.max() > 0.5  # up and down

    np.testing.assert_allclose(rows["tau_w_N"], thrust, atol=1e-3)  # thrust down = +w
    np.testing.assert_allclose(rows[["tau_u_N", "tau_v_N"]], 0.0, atol=1e-12)
    np.testing.assert_allclose(rows["g_w_N"], BUOYANCY_N - WEIGHT_N, rtol=1e-9)  # level: roll = pitch = 0
    np.testing.assert_allclose(rows[["roll_rad", "pitch_rad", "yaw_rad"]], 0.0, atol=0.0)
    np.testing.assert_allclose(rows[["u_smooth_mps", "v_smooth_mps", "udot_mps2", "vdot_mps2"]], 0.0, atol=0.0)

    rms = lambda a, b: float(np.sqrt(np.mean((np.asarray(a) - b) ** 2)))  # noqa: E731
    assert rms(rows["w_smooth_mps"], w) < 0.005          # 0.0024-0.0026 over seeds 0-2
    assert rms(rows["wdot_mps2"], heave(w, thrust)) < 0.02  # 0.011-0.012
    assert rms(rows["d_w_N"], ZW * w + ZWW * w * np.abs(w)) < 0.5  # N; 0.28-0.32
    assert rows["w_smooth_std_mps"].median() > 0  # the smoother's SDs, from the positions


def test_heave_damping_and_buoyancy_come_back_from_the_feature_store(features) -> None:
    """tau_w - M w' = (B - W) + Z_w w + Z_ww w|w|: by least squares, without the configured buoyancy."""
    _, rows = features
    w = rows["w_smooth_mps"].to_numpy()
    y = rows["tau_w_N"].to_numpy() - rows["Mnudot_w_N"].to_numpy()
    coef, *_ = np.linalg.lstsq(np.column_stack([np.ones_like(w), w, w * np.abs(w)]), y, rcond=None)
    net, zw, zww = coef
    assert net == pytest.approx(BUOYANCY_N - WEIGHT_N, abs=0.05)  # 2.991-2.995 N over seeds 0-2
    assert zw == pytest.approx(ZW, rel=0.05)  # 4.98-5.10
    assert zww == pytest.approx(ZWW, rel=0.03)  # 19.84-20.03


def test_the_level_vehicle_is_said_and_earth_horizontal_sources_still_need_attitude(tmp_path: Path,
                                                                                   caplog) -> None:
    import pandas as pd

    from pipeline.kinematics import body_kinematics

    vehicle = load_vehicle_from(tmp_path, VEHICLE)
    synced = pd.DataFrame({"t_ns": np.arange(3, dtype=np.int64), "segment": np.zeros(3, dtype=np.int32),
                           "depth_m": [1.0, 1.1, 1.2], "depth_m_rate_mps": [1.0, 1.0, 1.0],
                           "thrust_N": [0.0, 0.0, 0.0]})
    with caplog.at_level(logging.WARNING, logger="pipeline.kinematics"):
        body = body_kinematics(synced, vehicle)
    assert "taken as level" in caplog.text
    np.testing.assert_allclose(body[["u_mps", "v_mps", "w_mps"]].to_numpy()[0], [0.0, 0.0, 1.0])

    planar = {**VEHICLE, "sensors": {"position": {"signals": ["depth_m", "depth_m"]}}}
    with pytest.raises(ConfigError, match=r"sensors.position.*give sensors.attitude"):
        load_vehicle_from(tmp_path, planar)
    with pytest.raises(ConfigError, match=r"components.*\[z\]"):  # one signal: which axis, said
        load_vehicle_from(tmp_path, {**VEHICLE, "sensors": {"position": {"signals": ["depth_m"]}}})


def load_vehicle_from(tmp_path: Path, doc: dict) -> object:
    path = tmp_path / "v.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_vehicle(path)


def test_a_depth_with_attitude_gives_w_alone_whatever_the_roll_pitch_and_lever_arm() -> None:
    """A depth measures no u, v: they stay 0 (not the lever-arm term, not a share of z by pitch); w is z's rate
    turned by the heading alone (as a planar source's x, y are), whatever roll and pitch."""
    from pipeline.config.vehicle import LinearVelocity
    from pipeline.kinematics import velocity_to_body

    depth = LinearVelocity("sensors.position", "earth", ("depth_m",), None, False, (0.3, 0.0, 0.1),
                           (0.0, 0.0, 0.0), "ned", differentiated=True, components=("z",))
    assert depth.dofs == ("w",)
    n = 4
    rates = np.tile([0.1, 0.2, 0.3], (n, 1))
    roll, pitch, yaw = np.full(n, 0.2), np.full(n, -0.3), np.linspace(0.0, 3.0, n)
    v = velocity_to_body(np.full((n, 1), 0.5), depth, roll, pitch, yaw, rates)
    lever_w = np.cross(rates[0], [0.3, 0.0, 0.1])[2]
    np.testing.assert_allclose(v, np.column_stack([np.zeros(n), np.zeros(n), np.full(n, 0.5 - lever_w)]),
                               atol=1e-15)
