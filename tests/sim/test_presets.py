"""The simulator's presets (issue 32 item 4): the gentle default unchanged, the hard one as stated."""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Sequence

import numpy as np
import pytest

from pipeline import physics
from pipeline.config.vehicle import Vehicle
from pipeline.sim import (
    PRESET_SEED_OFFSET,
    Controls,
    Disturbance,
    SensorOptions,
    SimTrial,
    StreamSpec,
    generate_trial,
    load_example_vehicle,
    load_truth,
)
from pipeline.sim.sensors import EARTH_RATE_RADPS
from pipeline.sim.vehicle import Commander, Dynamics, scalar_rhs
from pipeline.vocabulary import ACCELERATION, VELOCITY, force_columns

HARD_SEED = PRESET_SEED_OFFSET["hard"]

#: The truth columns every trial had before the presets, and the sha256 of those columns and of every stream of
#: ``generate_trial(load_example_vehicle(), 10.0, seed=3, warmup_s=2.0)``, taken before the presets were added.
ORIGINAL_COLUMNS = [
    "t_ns", "u_mps", "v_mps", "w_mps", "p_radps", "q_radps", "r_radps", "udot_mps2", "vdot_mps2", "wdot_mps2",
    "pdot_radps2", "qdot_radps2", "rdot_radps2", "x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad", "depth_m",
    "n1_rpm", "n2_rpm", "n3_rpm", "n4_rpm", "n5_rpm", "n1_cmd_rpm", "n2_cmd_rpm", "n3_cmd_rpm", "n4_cmd_rpm",
    "n5_cmd_rpm", "T_th1_N", "T_th2_N", "T_th3_N", "T_th4_N", "T_th5_N", *force_columns("tau"),
    *force_columns("Mnudot"), *force_columns("Cnu"), *force_columns("g"), *force_columns("d"),
]
GENTLE_SHA256 = "fea719fb29928003482bd7443e9483eed5f67e3ac88d0e874e3d8af8d2916cc8"


def trial_digest(trial: SimTrial, columns: Sequence[str] = ORIGINAL_COLUMNS) -> str:
    """sha256 of ``columns`` of the truth table and of every stream's stamps and fields."""
    h = hashlib.sha256()
    for col in columns:
        h.update(col.encode())
        h.update(np.ascontiguousarray(trial.truth[col].to_numpy()).tobytes())
    for name in sorted(trial.streams):
        s = trial.streams[name]
        h.update(name.encode())
        h.update(s.log_ns.tobytes())
        h.update(s.header_ns.tobytes())
        for key in sorted(s.fields):
            h.update(key.encode())
            h.update(np.ascontiguousarray(s.fields[key]).tobytes())
    return h.hexdigest()


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return load_example_vehicle()


@pytest.fixture(scope="module")
def hard(vehicle: Vehicle) -> SimTrial:
    return generate_trial(vehicle, duration_s=60.0, seed=HARD_SEED, preset="hard")


def horizontal(vehicle: Vehicle) -> np.ndarray:
    return np.abs(physics.allocation_matrix(vehicle)[2]) < 0.9


def test_gentle_default_is_byte_identical_to_before_the_presets(vehicle: Vehicle) -> None:
    trial = generate_trial(vehicle, 10.0, seed=3, warmup_s=2.0)
    assert trial_digest(trial) == GENTLE_SHA256
    assert trial.truth["u_mps"].iloc[1000] == -0.011949400842337277
    assert trial.streams["fog"].fields["vector.z"][123] == -0.05375154637492906
    explicit = generate_trial(vehicle, 10.0, seed=3, warmup_s=2.0, preset="gentle")
    assert trial_digest(explicit) == GENTLE_SHA256
    zero = [*force_columns("dist"), "gyro_bias_p_radps", "gyro_bias_q_radps", "gyro_bias_r_radps",
            "fog_bias_r_radps"]
    assert (trial.truth[zero].to_numpy() == 0.0).all()
    np.testing.assert_array_equal(trial.truth[force_columns("d_true")].to_numpy(),
                                  trial.truth[force_columns("d")].to_numpy())


def test_unknown_preset_is_refused(vehicle: Vehicle) -> None:
    with pytest.raises(ValueError, match="preset must be one of"):
        generate_trial(vehicle, 1.0, preset="brutal")


def test_hard_excitation_is_one_sine_per_thruster_within_the_stated_bounds(vehicle: Vehicle) -> None:
    controls = Controls.hard()
    assert (controls.n_sines, controls.amplitude_rpm, controls.max_rpm) == (1, 1800.0, 3500.0)
    dyn = Dynamics(vehicle, load_truth())
    periods = np.concatenate([Commander(dyn, controls, np.random.default_rng(s)).periods for s in range(50)])
    assert periods.shape[1] == 1 and 5.0 <= periods.min() < 5.5 and 17.5 < periods.max() <= 18.0
    # the trial's commands are exactly 1800 sin(2 pi t / P + phase), P from the command stream of the seed
    trial = generate_trial(vehicle, 60.0, seed=HARD_SEED, preset="hard")
    rng_cmd = np.random.default_rng(np.random.SeedSequence(HARD_SEED).spawn(2)[0])
    commander = Commander(dyn, controls, rng_cmd)
    t_s = (trial.truth["t_ns"].to_numpy() - trial.truth["t_ns"].iloc[0]) / 1e9
    cmd = trial.truth[[f"n{k + 1}_cmd_rpm" for k in range(len(vehicle.thrusters))]].to_numpy()
    for k in np.flatnonzero(horizontal(vehicle)):
        expected = 1800.0 * np.sin(2 * np.pi * t_s / commander.periods[k, 0] + commander.phases[k, 0])
        np.testing.assert_allclose(cmd[:, k], expected, atol=1e-9)
        assert 1750.0 < np.abs(cmd[:, k]).max() <= 1800.0


def test_hall_counter_speeds_are_quantized_and_half_a_window_late(hard: SimTrial, vehicle: Vehicle) -> None:
    thr = hard.streams["thrusters"]
    t_ns = hard.truth["t_ns"].to_numpy()
    quantum_rpm = 60.0 / (7 * 0.1)  # 7 pulses per revolution counted over 0.1 s
    rpm = thr.fields["velocity"] * 60.0 / (2 * np.pi)
    counts = rpm / quantum_rpm
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    # one message per 0.1-s window, stamped at its end (the first window ends 0.1 s in), 1 ms to the log
    np.testing.assert_array_equal(thr.index, np.arange(1, thr.index.size + 1) * 20)
    np.testing.assert_array_equal(thr.log_ns - t_ns[thr.index], 1_000_000)
    n_true = hard.truth[[t.speed_signal for t in vehicle.thrusters]].to_numpy()
    # within one count of the window's mean speed ...
    window_mean = np.stack([n_true[i - 20:i + 1].mean(axis=0) for i in thr.index])
    assert np.abs(rpm - window_mean).max() < quantum_rpm + 2.0
    # ... which lags the truth by half the window: the best-fitting shift is 10 truth rows (50 ms)
    horiz = horizontal(vehicle)
    errors = [np.mean((rpm[:, horiz] - n_true[thr.index - shift][:, horiz]) ** 2) for shift in range(0, 21)]
    assert int(np.argmin(errors)) == 10
    assert errors[0] > 2 * errors[10]


def test_disturbance_enters_the_dynamics(hard: SimTrial, vehicle: Vehicle) -> None:
    t = hard.truth
    M = physics.mass_matrix(vehicle)
    dist = t[force_columns("dist")].to_numpy()
    assert dist[:, [0, 1]].std(axis=0).min() > 1.0 and dist[:, 5].std() > 0.2
    assert np.abs(dist[:, 2:5]).max() == 0.0
    rhs = (t[force_columns("tau")].to_numpy() - t[force_columns("Cnu")].to_numpy() - t[force_columns("d")].to_numpy()
           - t[force_columns("g")].to_numpy() + dist)
    np.testing.assert_allclose(t[ACCELERATION].to_numpy(), rhs @ np.linalg.inv(M).T, atol=1e-9)
    # the damping target from exact nu, nu_dot and applied tau is the true damping less the disturbance
    nu = t[VELOCITY].to_numpy()
    g = physics.restoring_force(vehicle, t["roll_rad"].to_numpy(), t["pitch_rad"].to_numpy())
    target = physics.damping_target(M, t[force_columns("tau")].to_numpy(), t[ACCELERATION].to_numpy(), nu, g)
    np.testing.assert_allclose(target, t[force_columns("d_true")].to_numpy(), atol=1e-8)
    np.testing.assert_allclose(target[:, 1], (t["d_v_N"] - t["dist_v_N"]).to_numpy(), atol=1e-8)
    # and the vehicle moves differently without it (same seed, same commands)
    calm = generate_trial(vehicle, 60.0, seed=HARD_SEED, preset="hard", disturbance=Disturbance())
    assert np.abs(calm.truth["v_mps"].to_numpy() - t["v_mps"].to_numpy()).max() > 0.02
    np.testing.assert_array_equal(calm.truth["n1_cmd_rpm"].to_numpy(), t["n1_cmd_rpm"].to_numpy())


def test_scalar_rhs_with_external_force_matches_the_vector_one(vehicle: Vehicle) -> None:
    dyn = Dynamics(vehicle, load_truth())
    rng = np.random.default_rng(1)
    y = np.concatenate([rng.normal(size=6) * 0.3, rng.normal(size=6) * 0.5, rng.normal(size=5) * 2000])
    cmd, force = rng.normal(size=5) * 2000, rng.normal(size=6) * 5
    fast = np.array(scalar_rhs(dyn, external=True)(y.tolist(), [*cmd.tolist(), *force.tolist()]))
    np.testing.assert_allclose(fast[6:12], dyn.nu_dot(y[None, :6], y[None, 6:12], y[None, 12:], force[None])[0],
                               rtol=1e-12, atol=1e-12)


def test_disturbance_is_an_ou_process_with_the_stated_sd_and_time_constant() -> None:
    dist = Disturbance.hard()
    assert dist.sd == (3.0, 3.0, 0.0, 0.0, 0.0, 1.0) and dist.time_constant_s == 30.0
    f = dist.sample(400_000, 0.1, np.random.default_rng(0))  # 40,000 s: 1300 time constants
    np.testing.assert_allclose(f.std(axis=0)[[0, 1, 5]], [3.0, 3.0, 1.0], rtol=0.1)
    lag = 300  # one time constant
    rho = np.mean(f[:-lag, 0] * f[lag:, 0]) / f[:, 0].var()
    assert rho == pytest.approx(math.exp(-1.0), abs=0.08)
    with pytest.raises(Exception, match="time_constant_s"):
        Disturbance(time_constant_s=0.0)


def test_gyro_and_fog_bias_appear_in_the_logged_rates(vehicle: Vehicle) -> None:
    quiet_rates = dataclasses.replace(SensorOptions.hard(), ahrs_rate_noise_radps=0.0,
                                      fog=StreamSpec(100.0, 0.002, 0.0, 0.0))
    trial = generate_trial(vehicle, 20.0, seed=HARD_SEED, preset="hard", sensors=quiet_rates)
    t = trial.truth
    fog, ahrs = trial.streams["fog"], trial.streams["ahrs"]
    np.testing.assert_allclose(fog.fields["vector.z"] - t["r_radps"].to_numpy()[fog.index],
                               t["fog_bias_r_radps"].to_numpy()[fog.index], atol=1e-15)
    for axis, dof in zip("xyz", "pqr", strict=True):
        np.testing.assert_allclose(ahrs.fields[f"angular_velocity.{axis}"] - t[f"{dof}_radps"].to_numpy()[ahrs.index],
                                   t[f"gyro_bias_{dof}_radps"].to_numpy()[ahrs.index], atol=1e-15)
    # the stated value: the constant bias plus the Earth's rate at 45 deg N, -Omega sin(45 deg) on r when level
    earth_r = -EARTH_RATE_RADPS * math.sin(math.radians(45.0))
    np.testing.assert_allclose(t["fog_bias_r_radps"], 2e-4 + earth_r, atol=2e-6)
    np.testing.assert_allclose(t["gyro_bias_r_radps"], 3e-4 + earth_r, atol=2e-6)
    for col in ("fog_bias_r_radps", "gyro_bias_r_radps"):
        assert 1e-4 <= t[col].abs().min() and t[col].abs().max() <= 5e-4
