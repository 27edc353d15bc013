"""IMU accelerometers in the kalman method, with known answers: the specific force of an analytic, turning, tilted
trajectory gives back the reference point's body acceleration exactly; on a simulated trial they sharpen the
acceleration targets and their bias is found."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from pipeline.estimation.accelerometer import reference_acceleration
from pipeline.sim.vehicle import euler_rotation

G = 9.81
R_IMU = np.array([0.4, -0.15, 0.2])


def _motion(t: np.ndarray):
    """An asymmetric analytic motion: nu_lin (u != v, w), attitude (roll, pitch, yaw) and their derivatives."""
    nu = np.stack([0.6 + 0.2 * np.sin(0.7 * t), -0.25 + 0.1 * np.cos(1.1 * t), 0.05 * np.sin(0.5 * t)], axis=1)
    nu_dot = np.stack([0.14 * np.cos(0.7 * t), -0.11 * np.sin(1.1 * t), 0.025 * np.cos(0.5 * t)], axis=1)
    eta = np.stack([0.1 * np.sin(0.9 * t), -0.08 + 0.05 * np.cos(0.6 * t), 0.3 * t + 0.2 * np.sin(0.4 * t)], axis=1)
    return nu, nu_dot, eta


def _omega(t: np.ndarray) -> np.ndarray:
    """Body rates from the Euler angles' rates (ZYX): omega = T(eta)^-1 eta_dot, the rates by central difference."""
    dt = 1e-6
    _, _, eta = _motion(t)
    eta_dot = (_motion(t + dt)[2] - _motion(t - dt)[2]) / (2 * dt)
    phi, theta = eta[:, 0], eta[:, 1]
    return np.stack([eta_dot[:, 0] - eta_dot[:, 2] * np.sin(theta),
                     eta_dot[:, 1] * np.cos(phi) + eta_dot[:, 2] * np.cos(theta) * np.sin(phi),
                     -eta_dot[:, 1] * np.sin(phi) + eta_dot[:, 2] * np.cos(theta) * np.cos(phi)], axis=1)


def _specific_force(t: np.ndarray) -> np.ndarray:
    """What an accelerometer at R_IMU reads, independently of the formula under test: the earth-frame velocity of
    its point, R (nu + omega x r), differentiated numerically, less gravity, rotated into body axes."""
    dt = 1e-4

    def v_earth(tt: np.ndarray) -> np.ndarray:
        nu, _, eta = _motion(tt)
        v = nu + np.cross(_omega(tt), R_IMU)
        return np.einsum("nij,nj->ni", euler_rotation(eta[:, 0], eta[:, 1], eta[:, 2]), v)

    a_earth = (v_earth(t + dt) - v_earth(t - dt)) / (2 * dt)
    _, _, eta = _motion(t)
    R = euler_rotation(eta[:, 0], eta[:, 1], eta[:, 2])
    return np.einsum("nji,nj->ni", R, a_earth - np.array([0.0, 0.0, G]))


def test_noise_free_turning_tilted_vehicle_gives_the_true_acceleration() -> None:
    t = np.linspace(0.0, 20.0, 401)
    nu, nu_dot, eta = _motion(t)
    omega = _omega(t)
    omega_dot = (_omega(t + 1e-4) - _omega(t - 1e-4)) / 2e-4
    f = _specific_force(t)
    assert np.ptp(omega[:, 2]) > 0.1 and np.abs(eta[:, :2]).max() > 0.05  # turning and tilted

    def derived(r: np.ndarray = R_IMU, g: float = G) -> np.ndarray:
        return reference_acceleration(f, r, eta[:, 0], eta[:, 1], omega, omega_dot, nu, g)

    np.testing.assert_allclose(derived(), nu_dot, atol=2e-6)
    assert np.abs(derived(r=np.zeros(3)) - nu_dot).max() > 1e-2     # the lever arm matters
    assert np.abs(derived(g=0.0) - nu_dot).max() > 0.5               # and gravity
    assert np.abs(derived(r=R_IMU * [1, -1, 1]) - nu_dot).max() > 1e-3  # on the right side


@pytest.fixture(scope="module")
def imu_trial():
    """A 150-s DAGON trial with realistic sensors; the vehicle config with the AHRS's accelerometers configured."""
    from pipeline.config.vehicle import Vehicle
    from pipeline.sim import example_vehicle_path, generate_trial, load_example_vehicle

    raw = yaml.safe_load(example_vehicle_path().read_text())
    raw["streams"]["ahrs"]["signals"].update(
        {f"a{a}_imu_mps2": {"field": f"linear_acceleration.{a}", "unit": "m/s^2"} for a in "xyz"})
    raw["sensors"]["accelerometer"] = {"signals": [f"a{a}_imu_mps2" for a in "xyz"], "position_m": [0.2, 0.1, -0.1]}
    with_imu = Vehicle.model_validate(raw)
    return load_example_vehicle(), with_imu, generate_trial(with_imu, 150.0, seed=5, warmup_s=20.0)


def test_accelerometers_sharpen_the_targets_and_their_bias_is_found(imu_trial) -> None:
    from pipeline.config import Params
    from pipeline.estimation.differentiate import differentiate
    from pipeline.sim import SensorOptions
    from pipeline.sync import synchronize
    from tests.store.test_stages_features import signal_tables

    plain, with_imu, trial = imu_trial
    params = Params()
    tables = signal_tables(trial, with_imu)
    synced = synchronize(tables, with_imu, params.sync)
    r2 = {}
    kinematic = params.differentiate.model_copy(update={"model_passes": 0})
    for name, vehicle, how in (("kinematic", plain, kinematic), ("dvl", plain, params.differentiate),
                               ("imu", with_imu, params.differentiate)):
        kin, report = differentiate(synced, vehicle, how, tables)
        truth = trial.truth.set_index("t_ns").loc[kin["t_ns"].to_numpy()]
        for acc in ("udot_mps2", "vdot_mps2"):
            a = truth[acc].to_numpy()
            r2[name, acc] = 1 - np.mean((kin[acc].to_numpy() - a) ** 2) / np.var(a)
    # the DVL alone with the white-jerk smoother: u_dot 0.953, v_dot 0.954; with accelerometers 0.998, 0.987
    assert r2["kinematic", "udot_mps2"] < 0.97 and r2["kinematic", "vdot_mps2"] < 0.97
    assert r2["imu", "udot_mps2"] >= 0.99 and r2["imu", "udot_mps2"] >= r2["kinematic", "udot_mps2"] + 0.03
    assert r2["imu", "vdot_mps2"] >= 0.975 and r2["imu", "vdot_mps2"] >= r2["kinematic", "vdot_mps2"] + 0.02
    # the vehicle's model in the smoother (the default) takes the DVL alone part of the way
    assert r2["dvl", "udot_mps2"] >= r2["kinematic", "udot_mps2"] + 0.02
    assert r2["dvl", "vdot_mps2"] >= r2["kinematic", "vdot_mps2"] + 0.02
    bias = report["accelerometer"]["bias_mps2"]
    for dof, true in zip("uvw", SensorOptions().accel_bias_mps2, strict=True):  # FRD IMU: its axes are the body's
        assert bias[dof] == pytest.approx(true, abs=0.003), dof
    assert report["noise"]["ax_imu_mps2"]["sd"] == pytest.approx(0.02, rel=0.15)


def test_the_example_vehicle_has_no_accelerometer() -> None:
    from pipeline.sim import load_example_vehicle

    assert load_example_vehicle().sensors.accelerometer is None
