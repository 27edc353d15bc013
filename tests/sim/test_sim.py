from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from pipeline import physics
from pipeline.config.vehicle import Vehicle
from pipeline.sim import (
    Controls,
    SensorOptions,
    SimTrial,
    SimTruth,
    generate_trial,
    load_example_vehicle,
    true_damping,
)
from pipeline.sim.sensors import dvl_rotation
from pipeline.sim.vehicle import Dynamics, scalar_rhs
from pipeline.vocabulary import force_columns
from tests.fixturepaths import T200_CSV, shared_fixture

QUIET = SensorOptions(noise=False, dropouts=False)


@pytest.fixture(scope="module")
def vehicle() -> Vehicle:
    return load_example_vehicle()


@pytest.fixture(scope="module")
def trial(vehicle: Vehicle) -> SimTrial:
    return generate_trial(vehicle, duration_s=20.0, seed=7, sensors=QUIET)


def nu_of(table: pd.DataFrame) -> np.ndarray:
    return table[["u_mps", "v_mps", "w_mps", "p_radps", "q_radps", "r_radps"]].to_numpy()


def test_truth_columns_follow_contracts(trial: SimTrial) -> None:
    t = trial.truth
    assert t["t_ns"].dtype == np.int64 and np.all(np.diff(t["t_ns"]) == 5_000_000)
    for col in ("udot_mps2", "rdot_radps2", "roll_rad", "yaw_rad", "x_m", "n1_rpm", "n5_rpm", "T_th3_N",
                "tau_u_N", "tau_r_Nm", "d_v_N", "d_r_Nm", "g_w_N", "Cnu_u_N", "Mnudot_r_Nm"):
        assert col in t.columns, col
    assert len(t) == 20 * 200 + 1


def test_damping_target_on_truth_is_true_damping(trial: SimTrial, vehicle: Vehicle) -> None:
    t = trial.truth
    M = physics.mass_matrix(vehicle)
    speeds = t[[thr.speed_signal for thr in vehicle.thrusters]].to_numpy()
    tau = physics.generalized_forces(vehicle, speeds)
    g = physics.restoring_force(vehicle, t["roll_rad"].to_numpy(), t["pitch_rad"].to_numpy())
    nudot = t[["udot_mps2", "vdot_mps2", "wdot_mps2", "pdot_radps2", "qdot_radps2", "rdot_radps2"]].to_numpy()
    d = physics.damping_target(M, tau, nudot, nu_of(t), g)
    np.testing.assert_allclose(d, true_damping(nu_of(t)), atol=1e-9)
    np.testing.assert_allclose(d, t[force_columns("d")].to_numpy(), atol=1e-9)
    assert np.abs(t["d_r_Nm"]).max() > 0.5  # the trial excites yaw


def test_accelerations_match_velocity_derivative(trial: SimTrial) -> None:
    t, dt = trial.truth, 0.005
    for vel, acc in (("u_mps", "udot_mps2"), ("v_mps", "vdot_mps2"), ("r_radps", "rdot_radps2")):
        x = t[vel].to_numpy()
        fd = (x[2:] - x[:-2]) / (2 * dt)
        np.testing.assert_allclose(fd, t[acc].to_numpy()[1:-1], atol=2e-4)


def test_scalar_and_vector_rhs_agree(vehicle: Vehicle) -> None:
    dyn = Dynamics(vehicle, generate_trial.__globals__["load_truth"]())
    rng = np.random.default_rng(0)
    y = np.concatenate([rng.normal(size=6) * 0.3, rng.normal(size=6) * 0.5, rng.normal(size=5) * 2000])
    cmd = rng.normal(size=5) * 2000
    fast = np.array(scalar_rhs(dyn)(y.tolist(), cmd.tolist()))
    np.testing.assert_allclose(fast[:6], dyn.eta_dot(y[None, :6], y[None, 6:12])[0], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(fast[6:12], dyn.nu_dot(y[None, :6], y[None, 6:12], y[None, 12:])[0], rtol=1e-12,
                               atol=1e-12)
    np.testing.assert_allclose(fast[12:], (cmd - y[12:]) / 0.1, rtol=1e-12)


def test_energy_conserved_without_forces(vehicle: Vehicle) -> None:
    rb = vehicle.rigid_body.model_copy(update={"cg_m": (0.0, 0.0, 0.0), "buoyancy_N": None})
    free = vehicle.model_copy(update={"rigid_body": rb})
    nu0 = np.array([0.5, -0.2, 0.1, 0.3, -0.2, 0.4])
    trial = generate_trial(free, duration_s=5.0, seed=0, truth=SimTruth(),
                           controls=Controls(commands="none", depth_control=False), nu0=nu0, sensors=QUIET)
    M = physics.mass_matrix(free)
    nu = nu_of(trial.truth)
    energy = 0.5 * np.einsum("ni,ij,nj->n", nu, M, nu)
    assert np.abs(energy - energy[0]).max() < 1e-8 * energy[0]
    assert np.abs(nu - nu0).max() > 0.01  # the motion is not trivial: Coriolis exchanges energy between DOFs


def test_coupled_and_cubic_damping_present() -> None:
    nu = np.zeros((2, 6))
    nu[0, [1, 5]] = 0.4, 0.3  # sway + yaw
    nu[1, 0] = 1.0
    d = true_damping(nu)
    truth = SimTruth.from_dict({"linear": [10.0, 25.0, 30.0, 6.0, 10.0, 10.0],
                                "quadratic": [30.0, 80.0, 90.0, 4.0, 12.0, 20.0],
                                "cubic": [8.0, 20.0, 0.0, 0.0, 0.0, 4.0]})
    assert d[1, 0] == pytest.approx(10 + 30 + 8)
    assert abs(d[0, 5] - truth.damping(nu)[0, 5]) > 0.3  # coupled |v| r, |r| v terms matter in yaw


def test_determinism_same_seed(vehicle: Vehicle) -> None:
    a = generate_trial(vehicle, duration_s=3.0, seed=3)
    b = generate_trial(vehicle, duration_s=3.0, seed=3)
    c = generate_trial(vehicle, duration_s=3.0, seed=4)
    pd.testing.assert_frame_equal(a.truth, b.truth)
    for name in a.streams:
        np.testing.assert_array_equal(a.streams[name].log_ns, b.streams[name].log_ns)
        for key in a.streams[name].fields:
            np.testing.assert_array_equal(a.streams[name].fields[key], b.streams[name].fields[key])
    assert not a.truth["u_mps"].equals(c.truth["u_mps"])


def test_stream_rates_and_stamps(trial: SimTrial) -> None:
    counts = {name: len(s) for name, s in trial.streams.items() if name != "dvl"}
    assert counts == {"ahrs": 20 * 120 + 1, "fog": 20 * 100 + 1, "depth": 20 * 10 + 1, "thrusters": 20 * 20 + 1}
    t_ns = trial.truth["t_ns"].to_numpy()
    dvl = trial.streams["dvl"]
    gaps = np.diff(t_ns[dvl.index]) / 1e9  # irregular pings, 0.25-0.31 s apart (snapped to the 5 ms truth grid)
    assert gaps.min() >= 0.25 - 0.005 and gaps.max() <= 0.31 + 0.005 and gaps.std() > 0.01
    np.testing.assert_array_equal(dvl.header_ns - t_ns[dvl.index], -50_000_000)
    np.testing.assert_array_equal(dvl.log_ns - t_ns[dvl.index], 20_000_000)


def test_dvl_lever_arm_measurement(trial: SimTrial, vehicle: Vehicle) -> None:
    dvl = trial.streams["dvl"]
    nu = nu_of(trial.truth)[dvl.index]
    r = np.array(vehicle.sensors.dvl.position_m)
    R = dvl_rotation(vehicle.sensors.dvl.rotation_rpy_deg)
    expected = np.array([R.T @ (n[:3] + np.cross(n[3:], r)) for n in nu])
    got = np.stack([dvl.fields[f"velocity.{a}"] for a in "xyz"], axis=1)
    np.testing.assert_allclose(got, expected, atol=1e-12)
    # and back: v_ref = R v_dvl - omega x r
    back = got @ R.T - np.cross(nu[:, 3:], r)
    np.testing.assert_allclose(back, nu[:, :3], atol=1e-12)


def test_dvl_dropout_bursts(vehicle: Vehicle) -> None:
    opts = SensorOptions(dropout_bursts_per_min=6.0, dropout_duration_s=(2.0, 3.0), dvl_lock_loss_fraction=0.0)
    trial = generate_trial(vehicle, duration_s=30.0, seed=11, sensors=opts)
    dvl = trial.streams["dvl"]
    lock = dvl.fields["bottom_lock"]
    assert 0 < lock.sum() < lock.size
    lost = ~lock
    for a in "xyz":
        assert np.all(dvl.fields[f"velocity.{a}"][lost] == 0.0)
        assert np.all(dvl.fields[f"velocity.{a}"][lock] != 0.0)
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0])))[::2]
    assert runs.min() >= 6  # bursts of >= 2 s at 3.2-4 Hz, not isolated samples


def test_dvl_lock_loss_chain_has_the_configured_fraction_and_burst_length() -> None:
    from pipeline.sim.sensors import lock_chain

    lock = lock_chain(200_000, 0.2, 6.0, np.random.default_rng(3))
    lost = ~lock
    runs = np.diff(np.flatnonzero(np.diff(np.r_[0, lost.astype(int), 0])))[::2]
    assert lost.mean() == pytest.approx(0.2, abs=0.01)
    assert runs.mean() == pytest.approx(6.0, rel=0.05)


def test_default_dvl_is_realistic(vehicle: Vehicle) -> None:
    """The default DVL: 0.02 m/s white noise, 0.5 % outliers, 0.3 % scale, 1 deg yaw misalignment, ~20 % lost."""
    opts = SensorOptions(dvl_averaging_s=0.0)
    trial = generate_trial(vehicle, duration_s=600.0, seed=5, sensors=opts)
    dvl = trial.streams["dvl"]
    lock = dvl.fields["bottom_lock"]
    assert 0.15 < 1 - lock.mean() < 0.25
    nu = nu_of(trial.truth)[dvl.index]
    r = np.array(vehicle.sensors.dvl.position_m)
    R_true = dvl_rotation(vehicle.sensors.dvl.rotation_rpy_deg) @ dvl_rotation((0.0, 0.0, 1.0))
    ideal = (nu[:, :3] + np.cross(nu[:, 3:], r)) @ R_true * 1.003
    got = np.stack([dvl.fields[f"velocity.{a}"] for a in "xyz"], axis=1)
    err = (got - ideal)[lock]
    mad_sd = 1.4826 * np.median(np.abs(err), axis=0)
    np.testing.assert_allclose(mad_sd, 0.02, rtol=0.1)
    big = np.any(np.abs(err) > 0.1, axis=1)  # 5 sigma: outliers only
    assert 0.001 < big.mean() < 0.01
    # the configured mount (without the misalignment) leaves a velocity-proportional error across track
    R_cfg = dvl_rotation(vehicle.sensors.dvl.rotation_rpy_deg)
    naive = (nu[:, :3] + np.cross(nu[:, 3:], r)) @ R_cfg
    assert np.median(np.abs(got - naive)[lock]) > np.median(np.abs(err))


def test_ahrs_quaternion_conventions(trial: SimTrial, vehicle: Vehicle) -> None:
    from scipy.spatial.transform import Rotation

    ahrs = trial.streams["ahrs"]
    q = np.stack([ahrs.fields[f"orientation.{a}"] for a in "xyzw"], axis=1)
    ypr = Rotation.from_quat(q).as_euler("ZYX")
    t = trial.truth.iloc[ahrs.index]
    np.testing.assert_allclose(ypr[:, 2], t["roll_rad"], atol=1e-12)
    np.testing.assert_allclose(ypr[:, 1], t["pitch_rad"], atol=1e-12)
    np.testing.assert_allclose(np.unwrap(ypr[:, 0]) - t["yaw_rad"].to_numpy(),
                               np.round((np.unwrap(ypr[:, 0]) - t["yaw_rad"].to_numpy()) / (2 * np.pi)) * 2 * np.pi,
                               atol=1e-9)
    ros = generate_trial(vehicle, duration_s=2.0, seed=7, sensors=SensorOptions(noise=False,
                                                                               ahrs_convention="flu_enu"))
    qe = np.stack([ros.streams["ahrs"].fields[f"orientation.{a}"] for a in "xyzw"], axis=1)
    t = ros.truth.iloc[ros.streams["ahrs"].index]
    # ENU yaw = pi/2 - NED yaw; FLU roll = FRD roll, FLU pitch = -FRD pitch
    ypr = Rotation.from_quat(qe).as_euler("ZYX")
    np.testing.assert_allclose(np.angle(np.exp(1j * (ypr[:, 0] - (np.pi / 2 - t["yaw_rad"].to_numpy())))), 0.0,
                               atol=1e-9)
    np.testing.assert_allclose(ypr[:, 1], -t["pitch_rad"], atol=1e-9)
    np.testing.assert_allclose(ypr[:, 2], t["roll_rad"], atol=1e-9)


# ---------------------------------------------------------------- writers

FORMAT_PATHS = {"mcap": "t.mcap", "ros1": "t.bag", "ros2-sqlite3": "t_db3", "ros2-mcap": "t_mcap", "csv": "t_csv"}


@pytest.fixture(scope="module")
def short_trial(vehicle: Vehicle) -> SimTrial:
    return generate_trial(vehicle, duration_s=4.0, seed=5)


def expected_counts(duration_s: float, dvl_pings: int) -> dict[str, int]:
    rates = {"/ahrs/imu": 120, "/fog/rate": 100, "/pressure/depth": 10, "/thrusters/joint_states": 20}
    return {"/dvl/data": dvl_pings, **{topic: int(duration_s * rate) + 1 for topic, rate in rates.items()}}


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "ros2-sqlite3", "ros2-mcap"])
def test_written_logs_open_with_anyreader(fmt: str, short_trial: SimTrial, tmp_path) -> None:
    from rosbags.highlevel import AnyReader

    from pipeline.sim import write_trial

    path = write_trial(short_trial, fmt, tmp_path / FORMAT_PATHS[fmt])
    with AnyReader([path]) as reader:
        counts: dict[str, int] = {}
        for conn, _, _ in reader.messages():
            counts[conn.topic] = counts.get(conn.topic, 0) + 1
        assert counts == expected_counts(4.0, len(short_trial.streams["dvl"]))
        dvl_conn = [c for c in reader.connections if c.topic == "/dvl/data"]
        assert dvl_conn[0].msgtype == "auv_msgs/msg/DVL"
        stream = short_trial.streams["dvl"]
        for i, (conn, t_ns, raw) in enumerate(reader.messages(connections=dvl_conn)):
            msg = reader.deserialize(raw, conn.msgtype)
            assert t_ns == stream.log_ns[i]
            assert msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec == stream.header_ns[i]
            assert msg.velocity.x == stream.fields["velocity.x"][i]
            assert msg.bottom_lock == stream.fields["bottom_lock"][i]
        js = [c for c in reader.connections if c.topic == "/thrusters/joint_states"]
        conn, _, raw = next(iter(reader.messages(connections=js)))
        msg = reader.deserialize(raw, conn.msgtype)
        assert list(msg.name) == ["th1", "th2", "th3", "th4", "th5"]
        np.testing.assert_array_equal(msg.velocity, short_trial.streams["thrusters"].fields["velocity"][0])


def test_mcap_readable_by_mcap_ros2_decoder(short_trial: SimTrial, tmp_path) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from pipeline.sim import write_trial

    path = write_trial(short_trial, "mcap", tmp_path / "t.mcap")
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == sum(expected_counts(4.0, len(short_trial.streams["dvl"])).values())
        schemas = {s.name: s.data.decode() for s in summary.schemas.values()}
        assert "bool bottom_lock" in schemas["auv_msgs/msg/DVL"]
        decoded = [m for _, _, _, m in reader.iter_decoded_messages(topics=["/dvl/data"])]
    assert len(decoded) == len(short_trial.streams["dvl"])
    assert decoded[3].velocity.y == short_trial.streams["dvl"].fields["velocity.y"][3]


@pytest.mark.parametrize("fmt", ["mcap", "ros1", "ros2-sqlite3", "ros2-mcap"])
def test_written_bytes_deterministic(fmt: str, vehicle: Vehicle, tmp_path) -> None:
    from pipeline.sim import write_trial

    a = write_trial(generate_trial(vehicle, duration_s=1.0, seed=2), fmt, tmp_path / "a" / FORMAT_PATHS[fmt])
    b = write_trial(generate_trial(vehicle, duration_s=1.0, seed=2), fmt, tmp_path / "b" / FORMAT_PATHS[fmt])
    files_a = sorted(p.relative_to(a) for p in a.rglob("*")) if a.is_dir() else [None]
    files_b = sorted(p.relative_to(b) for p in b.rglob("*")) if b.is_dir() else [None]
    assert files_a == files_b
    if a.is_file():
        assert a.read_bytes() == b.read_bytes()
    else:
        for pa_, pb_ in zip(sorted(a.rglob("*")), sorted(b.rglob("*")), strict=True):
            if pa_.suffix in (".mcap", ".db3"):
                assert pa_.read_bytes() == pb_.read_bytes(), pa_.name


def test_csv_layout_matches_csv_vehicle(short_trial: SimTrial, tmp_path) -> None:
    from pipeline.sim import write_trial

    path = write_trial(short_trial, "csv", tmp_path / "t_csv")
    csv_vehicle = load_example_vehicle("csv")
    assert csv_vehicle.sensors.attitude.yaw == "yaw_rad"
    for name, source in csv_vehicle.streams.items():
        frame = pd.read_csv(path / source.file)
        assert source.csv is not None and source.csv.time_column in frame.columns
        for signal in source.signals.values():
            assert signal.field in frame.columns, (name, signal.field)
        assert len(frame) == len(short_trial.streams[name])
    ahrs = pd.read_csv(path / "ahrs.csv")
    t = short_trial.truth.iloc[short_trial.streams["ahrs"].index]
    assert np.abs(np.radians(ahrs["pitch"].to_numpy()) - t["pitch_rad"].to_numpy()).max() < 0.01
    dvl = pd.read_csv(path / "dvl.csv")
    np.testing.assert_array_equal(dvl["stamp_ns"].to_numpy(), short_trial.streams["dvl"].header_ns)
    np.testing.assert_array_equal(dvl["velocity.x"].to_numpy(), short_trial.streams["dvl"].fields["velocity.x"])


def test_example_writes_trials_and_vehicle(tmp_path) -> None:
    from pipeline.config import load_vehicle
    from pipeline.sim import example

    paths = example(tmp_path, fmt="mcap", duration_s=2.0, n_trials=2)
    assert [p.name for p in paths.trials] == ["trial01.mcap", "trial02.mcap"]
    vehicle = load_vehicle(paths.vehicle)
    assert vehicle.model_dump() == load_example_vehicle().model_dump()
    assert all(p.exists() for p in paths.truth)
    csv_paths = example(tmp_path / "csv", fmt="csv", duration_s=2.0, n_trials=1)
    assert load_vehicle(csv_paths.vehicle).streams["dvl"].file == "dvl.csv"
    assert (csv_paths.trials[0] / "dvl.csv").exists()


def test_simulate_with_thrust_table(vehicle: Vehicle, tmp_path) -> None:
    import shutil

    import yaml

    from pipeline.config import load_vehicle
    from pipeline.sim import example_vehicle_path

    shutil.copy(shared_fixture(T200_CSV), tmp_path / "t200.csv")
    data = yaml.safe_load(example_vehicle_path().read_text())
    for thr in data["thrusters"]:
        thr["thrust"] = {"table": "t200.csv", "table_speed_column": "RPM", "table_thrust_column": "Force (Kg f)",
                         "table_thrust_unit": "kgf"}
    (tmp_path / "v.yaml").write_text(yaml.safe_dump(data))
    tabled = load_vehicle(tmp_path / "v.yaml")
    trial = generate_trial(tabled, duration_s=3.0, seed=1, sensors=QUIET)
    t = trial.truth
    speeds = t[[thr.speed_signal for thr in tabled.thrusters]].to_numpy()
    np.testing.assert_allclose(t[[f"T_{thr.name}_N" for thr in tabled.thrusters]].to_numpy(),
                               physics.thrusts(tabled, speeds), atol=1e-12)
    assert np.abs(t["T_th1_N"]).max() > 0.1


INFLOW = SimTruth.from_dict({**{k: list(v) for k, v in (("linear", (10.0, 25.0, 30.0, 6.0, 10.0, 10.0)),
                                                       ("quadratic", (30.0, 80.0, 90.0, 4.0, 12.0, 20.0)))},
                             "inflow_loss": 0.3, "inflow_ref_rpm": 2500.0})


def test_inflow_loss_scalar_and_vector_rhs_agree(vehicle: Vehicle) -> None:
    dyn = Dynamics(vehicle, INFLOW)
    rng = np.random.default_rng(1)
    for _ in range(5):
        y = np.concatenate([rng.normal(size=6) * 0.3, rng.normal(size=6) * 0.5, rng.normal(size=5) * 2000])
        fast = np.array(scalar_rhs(dyn)(y.tolist(), [0.0] * 5))
        np.testing.assert_allclose(fast[6:12], dyn.nu_dot(y[None, :6], y[None, 6:12], y[None, 12:])[0],
                                   rtol=1e-12, atol=1e-12)


def test_inflow_loss_is_the_advance_ratio_law(vehicle: Vehicle) -> None:
    """T = T0(n) (1 - c u_a / n): 15 % of static thrust lost at 0.5 m/s axial inflow and 2500 rpm; more when the
    vehicle moves the way the thruster pushes, less (a gain) against it; no loss at rest; T(0) = 0."""
    dyn = Dynamics(vehicle, INFLOW)
    n = np.array([[2500.0, 2500.0, -2500.0, 0.0, 1250.0]])
    surge = np.array([[0.5, 0, 0, 0, 0, 0]])
    static, applied = dyn.thrust(n), dyn.thrust(n, surge)
    np.testing.assert_allclose(applied[0, :2] / static[0, :2], 0.85)  # th1/th2 push +x, inflow +0.5 m/s
    np.testing.assert_allclose(applied[0, 2], static[0, 2])  # th3 is lateral: no axial inflow in pure surge
    assert applied[0, 3] == 0.0
    np.testing.assert_allclose(dyn.thrust(n, -surge)[0, :2] / static[0, :2], 1.15)
    np.testing.assert_allclose(dyn.thrust(n, np.zeros((1, 6))), static)
    sway = np.array([[0, 0.5, 0, 0, 0, 0]])  # th3 reversed (pushes -y) while the vehicle moves +y: thrust grows
    assert abs(dyn.thrust(n, sway)[0, 2]) > abs(static[0, 2])
    assert SimTruth().applied_thrust(static, n, np.ones_like(n)) is static  # off by default


def test_truth_table_keeps_applied_forces_and_true_damping_with_inflow_loss(vehicle: Vehicle) -> None:
    """With the loss on, T_*/tau_* are the forces applied and d_* the true damping; the static-curve damping
    target (what derive computes) differs from d by exactly the unmodelled thrust loss B (T0 - T)."""
    t = generate_trial(vehicle, duration_s=10.0, seed=3, truth=INFLOW, sensors=QUIET, warmup_s=5.0).truth
    nu = nu_of(t)
    assert abs(t["u_mps"].iloc[0]) > 0.01  # warm-up: the trial starts in motion
    np.testing.assert_allclose(t[force_columns("d")].to_numpy(), INFLOW.damping(nu), atol=1e-9)
    speeds = t[[thr.speed_signal for thr in vehicle.thrusters]].to_numpy()
    tau_static = physics.generalized_forces(vehicle, speeds)
    tau = t[force_columns("tau")].to_numpy()
    M = physics.mass_matrix(vehicle)
    g = physics.restoring_force(vehicle, t["roll_rad"].to_numpy(), t["pitch_rad"].to_numpy())
    nudot = t[["udot_mps2", "vdot_mps2", "wdot_mps2", "pdot_radps2", "qdot_radps2", "rdot_radps2"]].to_numpy()
    np.testing.assert_allclose(physics.damping_target(M, tau, nudot, nu, g), INFLOW.damping(nu), atol=1e-9)
    loss = tau_static - tau
    assert np.abs(loss[:, 0]).max() > 0.05 * np.abs(tau_static[:, 0]).max()
    np.testing.assert_allclose(physics.damping_target(M, tau_static, nudot, nu, g), INFLOW.damping(nu) + loss,
                               atol=1e-9)
