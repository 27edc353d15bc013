"""A BlueROV2-like ROV from a raw ROS 2 sqlite3 bag to the feature store (issue 14, done-when 2 and 5).

The bag is written with rosbags' own writer and carries no message definitions (its `message_definitions` table is
dropped, as in bags before Iron): `mavros_msgs/msg/RCOut` (the six motors' PWM, decoded with a `.msg`
file in a ROS package tree), the header-less `std_msgs/msg/Float64` depth, a `sensor_msgs/msg/Imu` in ROS axes
(FLU body, ENU earth) and a DVL's `geometry_msgs/msg/TwistWithCovarianceStamped` in its FLU axes.

The known answer: constant PWMs per 8-s block drive a pure surge manoeuvre (t1 = t2, t3 = t4; the vertical pair
holds the vehicle's extra buoyancy) through a surge model with known mass and damping, integrated finely. The
thrusts are the T200 sheet's rows at 16 V, read here with the csv module; tau is B T with B written out here from
the geometry; so T and tau are exact. Velocity, acceleration and the damping target match the surge model's truth
within the DVL noise away from the thrust steps.

The vehicle YAML is the block of the BlueROV2 walkthrough in docs/user-guide.md, read from the guide: the guide
and the test cannot drift apart.
"""

from __future__ import annotations

import csv
import re
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline import store
from pipeline.config import Params, load_vehicle
from stages import derive as derive_stage
from stages import differentiate as differentiate_stage
from stages import features as features_stage
from stages import ingest as ingest_stage
from stages import sync as sync_stage
from tests.fixturepaths import SHARED, T200_CSV, shared_fixture

GUIDE = Path(__file__).resolve().parents[2] / "docs" / "user-guide.md"
T200 = SHARED / "csv" / "bluerobotics_t200_performance_10-20V.csv"
KGF_N = 9.80665

RC = "mavros_msgs/msg/RCOut"
#: mavros's servo outputs: the PWM the autopilot sends each motor (not the pilot's RC override inputs)
RC_OUT = "std_msgs/Header header\nuint16[] channels\n"
TWIST = "geometry_msgs/msg/TwistWithCovarianceStamped"

T0_NS = 1_700_000_000_000_000_000   # a multiple of the 50-ms grid period
BLOCK_S = 8.0
# PWM (us) of t1..t6 per block: rest, strong surge, weak surge, reverse; the vertical pair at 1540 throughout
PWM_US = np.array([[1500, 1500, 1500, 1500, 1540, 1540],
                   [1700, 1700, 1300, 1300, 1540, 1540],
                   [1600, 1600, 1400, 1400, 1540, 1540],
                   [1400, 1400, 1600, 1600, 1540, 1540]])
DURATION_S = BLOCK_S * len(PWM_US)
RC_PHASE_S = 0.025
# BlueROV2-like geometry (body FRD), written out independently of the YAML
POSITIONS = np.array([[0.156, 0.111, 0.085], [0.156, -0.111, 0.085], [-0.156, 0.111, 0.085],
                      [-0.156, -0.111, 0.085], [0.0, 0.218, 0.0], [0.0, -0.218, 0.0]])
DIRECTIONS = np.array([[0.7071, -0.7071, 0], [0.7071, 0.7071, 0], [-0.7071, -0.7071, 0], [-0.7071, 0.7071, 0],
                       [0, 0, 1.0], [0, 0, 1.0]])
# the surge model of the truth: M11 = mass + added mass; linear and quadratic damping
M11, XU, XUU = 11.5 + 5.5, 4.03, 18.18
WEIGHT_N, BUOYANCY_N = 11.5 * 9.81, 114.384064
HEADING_RAD = np.deg2rad(30.0)        # NED heading; ENU yaw 60 deg
DEPTH_M = 3.0


def guide_block(heading: str, lang: str) -> str:
    """The first ```lang block after the heading holding ``heading`` in the user guide."""
    text = GUIDE.read_text(encoding="utf-8")
    start = text.index(heading)
    match = re.compile(rf"^```{lang}\n(.*?)^```", re.M | re.S).search(text, start)
    assert match is not None, (heading, lang)
    return match.group(1)


VEHICLE_YAML = guide_block("Walkthrough: a BlueROV2-like ROV", "yaml")


def t200_kgf_at_16V() -> dict[int, float]:
    """PWM (us) -> force (kgf) of the sheet's 16 V rows."""
    with shared_fixture(T200_CSV).open(encoding="utf-8") as f:
        rows = [{k.strip(): v.strip() for k, v in row.items()} for row in csv.DictReader(f)]
    return {int(r["PWM (µs)"]): float(r["Force (Kg f)"]) for r in rows if float(r["Voltage (V)"]) == 16.0}


def allocation() -> np.ndarray:
    d = DIRECTIONS / np.linalg.norm(DIRECTIONS, axis=1, keepdims=True)
    return np.vstack([d.T, np.cross(POSITIONS, d).T])  # (6, 6): column i = [d_i; r_i x d_i]


def block_of(t_s: np.ndarray) -> np.ndarray:
    return np.minimum((np.asarray(t_s) / BLOCK_S + 1e-9).astype(int), len(PWM_US) - 1)


def rc_stamps_s() -> np.ndarray:
    """The servo outputs' log times: 10 Hz, 25 ms off the 20 Hz grid (mavros sends on its own clock)."""
    return RC_PHASE_S + np.arange(int(DURATION_S * 10)) * 0.1


def commanded_block(t_s: np.ndarray) -> np.ndarray:
    """The block of the last RC message at or before ``t_s``: the ESCs hold a PWM until the next message."""
    rc = rc_stamps_s()
    return block_of(rc[np.clip(np.searchsorted(rc, np.asarray(t_s) + 1e-9, side="right") - 1, 0, None)])


def surge_truth(h_s: float = 1e-3) -> tuple[np.ndarray, np.ndarray]:
    """(t, u) of the surge model driven by the blocks' tau_u, RK4 at ``h_s``, from rest."""
    table = t200_kgf_at_16V()
    tau_u = [float(allocation()[0] @ (np.array([table[p] for p in pwm]) * KGF_N)) for pwm in PWM_US]
    t = np.arange(int(round(DURATION_S / h_s)) + 1) * h_s
    blocks = commanded_block(t)
    u = np.zeros_like(t)
    f = lambda x, tau: (tau - XU * x - XUU * x * abs(x)) / M11  # noqa: E731
    for k in range(t.size - 1):
        tau = tau_u[blocks[k]]
        x = u[k]
        k1 = f(x, tau)
        k2 = f(x + h_s / 2 * k1, tau)
        k3 = f(x + h_s / 2 * k2, tau)
        k4 = f(x + h_s * k3, tau)
        u[k + 1] = x + h_s / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return t, u


def write_msg_tree(root: Path) -> None:
    """A ROS package tree: <root>/mavros_msgs/msg/RCOut.msg, with the package.xml of a checkout."""
    (root / "mavros_msgs" / "msg").mkdir(parents=True)
    (root / "mavros_msgs" / "msg" / "RCOut.msg").write_text(RC_OUT)
    (root / "mavros_msgs" / "package.xml").write_text("<package><name>mavros_msgs</name></package>\n")


def write_bag(path: Path, seed: int = 0) -> Path:
    """The dive: servo outputs at 10 Hz (log time, off the grid), IMU at 50 Hz and DVL at 10 Hz (header stamps, logged
    20 ms later), depth at 10 Hz; no message definitions in the bag."""
    from rosbags.rosbag2 import Writer

    rng = np.random.default_rng(seed)
    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg(RC_OUT, RC))
    T = ts.types
    t_truth, u_truth = surge_truth()
    no_hash = "RIHS01_" + "0" * 64

    def stamp(t_s: float) -> object:
        ns = T0_NS + round(t_s * 1e9)
        return T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)

    def header(t_s: float) -> object:
        return T["std_msgs/msg/Header"](stamp=stamp(t_s), frame_id="base_link")

    def vec3(x: float, y: float, z: float) -> object:
        return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)

    half = (np.pi / 2 - HEADING_RAD) / 2  # ENU yaw = 90 deg - NED heading; q = (cos, 0, 0, sin) of half of it
    orientation = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(half)), w=float(np.cos(half)))
    cov9, cov36 = np.zeros(9), np.zeros(36)
    log_ns = lambda t_s: T0_NS + round(t_s * 1e9)  # noqa: E731
    with Writer(path, version=9) as w:
        def conn(topic: str, msgtype: str) -> object:
            return w.add_connection(topic, msgtype, msgdef="", rihs01=no_hash)

        rc, imu, dvl, depth = (conn("/mavros/rc/out", RC), conn("/mavros/imu/data", "sensor_msgs/msg/Imu"),
                               conn("/dvl/twist", TWIST),
                               conn("/bluerov/depth", "std_msgs/msg/Float64"))
        messages: list[tuple[int, object, bytes]] = []
        for t in rc_stamps_s():
            channels = np.full(16, 0, dtype=np.uint16)  # the unused outputs: 0
            channels[:6] = PWM_US[block_of(t)]
            out = T[RC](header=header(t - 0.001), channels=channels)
            messages.append((log_ns(t), rc, ts.serialize_cdr(out, RC)))
        for k in range(int(DURATION_S * 50) + 1):
            t = k * 0.02 + 0.005
            gyro = rng.normal(0.0, 2e-4, 3)
            msg = T["sensor_msgs/msg/Imu"](
                header=header(t), orientation=orientation, orientation_covariance=cov9,
                angular_velocity=vec3(*gyro), angular_velocity_covariance=cov9,
                linear_acceleration=vec3(0.0, 0.0, 9.81), linear_acceleration_covariance=cov9)
            messages.append((log_ns(t + 0.02), imu, ts.serialize_cdr(msg, "sensor_msgs/msg/Imu")))
        for k in range(int(DURATION_S * 10) + 1):
            t = k * 0.1 + 0.013
            u = float(np.interp(t, t_truth, u_truth))
            noise = rng.normal(0.0, 0.003, 3)
            twist = T["geometry_msgs/msg/Twist"](linear=vec3(u + noise[0], noise[1], noise[2]),
                                                 angular=vec3(0.0, 0.0, 0.0))
            msg = T[TWIST](
                header=header(t), twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov36))
            messages.append((log_ns(t + 0.02), dvl, ts.serialize_cdr(msg, TWIST)))
            d = T["std_msgs/msg/Float64"](data=DEPTH_M)
            messages.append((log_ns(k * 0.1 + 0.003), depth, ts.serialize_cdr(d, "std_msgs/msg/Float64")))
        for t_ns, connection, data in sorted(messages, key=lambda m: m[0]):
            w.write(connection, t_ns, bytes(data))
    con = sqlite3.connect(next(path.glob("*.db3")))
    try:  # a bag before Iron: no definitions at all
        con.execute("DROP TABLE message_definitions")
        con.commit()
    finally:
        con.close()
    return path


@pytest.fixture(scope="module")
def dive(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The user's directory: bluerov2.yaml (the guide's block), msgs/, the T200 sheet, dives/dive01."""
    home = tmp_path_factory.mktemp("bluerov")
    (home / "bluerov2.yaml").write_text(VEHICLE_YAML, encoding="utf-8")
    write_msg_tree(home / "msgs")
    shutil.copy(shared_fixture(T200_CSV), home / T200.name)
    (home / "dives").mkdir()
    write_bag(home / "dives" / "dive01")
    return home


def test_the_guides_bluerov2_runs_from_a_bag_without_definitions_to_features_with_t200_thrust(dive: Path) -> None:
    vehicle = load_vehicle(dive / "bluerov2.yaml")
    root, params = dive / "runs" / "bluerov", Params()
    for stage, extra in ((ingest_stage, {"logs": [dive / "dives" / "dive01"]}), (sync_stage, {}),
                         (differentiate_stage, {}), (derive_stage, {}), (features_stage, {})):
        result = stage.run(root, vehicle, params, **extra)
        assert not result.quarantined, (stage.NAME, result.quarantined)

    rows = store.load(root)
    assert set(rows["trial"]) == {"dive01"}
    t_s = (rows["t_ns"].to_numpy() - T0_NS) / 1e9
    assert t_s.min() < 2.0 and t_s.max() > DURATION_S - 2.0, (t_s.min(), t_s.max())

    # PWM: us in the bag, s in the store; thrust: the sheet's 16 V rows; tau = B T
    pwm_s = rows[[f"pwm{i}_s" for i in range(1, 7)]].to_numpy()
    expected_pwm = PWM_US[commanded_block(t_s)]  # held, not interpolated across a step
    np.testing.assert_allclose(pwm_s, expected_pwm * 1e-6, rtol=1e-12)
    table = t200_kgf_at_16V()
    thrust = rows[[f"T_t{i}_N" for i in range(1, 7)]].to_numpy()
    expected_T = np.vectorize(table.__getitem__)(expected_pwm) * KGF_N
    np.testing.assert_allclose(thrust, expected_T, rtol=1e-12, atol=1e-12)
    tau = rows[[f"tau_{d}_{u}" for d, u in zip("uvwpqr", ["N"] * 3 + ["Nm"] * 3, strict=True)]].to_numpy()
    np.testing.assert_allclose(tau, expected_T @ allocation().T, rtol=1e-9, atol=1e-9)
    strong = commanded_block(t_s) == 1  # by hand: 2 x 0.7071/|d| x (1.82 + 1.44) kgf of surge, nothing of sway or yaw
    assert tau[strong, 0] == pytest.approx(2 * np.sqrt(0.5) * (1.82 + 1.44) * KGF_N, rel=1e-12)
    np.testing.assert_allclose(tau[strong][:, [1, 5]], 0.0, atol=1e-12)
    assert tau[:, 2] == pytest.approx(2 * 0.08 * KGF_N, rel=1e-12)  # the vertical pair, 1540 us
    # the extra buoyancy: g_w = B - W, held by the vertical pair, so the heave damping target is ~0
    assert rows["g_w_N"].to_numpy() == pytest.approx(BUOYANCY_N - WEIGHT_N, rel=1e-9)
    assert np.abs(rows["d_w_N"]).max() < 0.5

    # ROS axes converted: heading 30 deg NED from the ENU quaternion; depth from the header-less Float64
    np.testing.assert_allclose(rows["yaw_rad"], HEADING_RAD, atol=1e-9)
    np.testing.assert_allclose(rows[["roll_rad", "pitch_rad"]], 0.0, atol=1e-9)
    np.testing.assert_allclose(rows["depth_m"], DEPTH_M, rtol=1e-12)

    # the surge model's truth, away from the thrust steps (the smoother rounds off a step over ~1 s)
    t_truth, u_truth = surge_truth()
    u = np.interp(t_s, t_truth, u_truth)
    udot = (tau[:, 0] - XU * u - XUU * u * np.abs(u)) / M11
    steady = np.abs(t_s - BLOCK_S * np.round(t_s / BLOCK_S)) > 1.5
    assert steady.sum() > 300
    err = lambda col, truth: float(np.sqrt(np.mean((rows[col].to_numpy()[steady] - truth[steady]) ** 2)))  # noqa: E731
    assert err("u_smooth_mps", u) < 0.005          # 0.002 here (DVL noise 0.003 m/s at 10 Hz)
    assert err("udot_mps2", udot) < 0.03            # 0.015-0.017 over seeds 0-3
    assert err("d_u_N", XU * u + XUU * u * np.abs(u)) < 0.03 * M11
    np.testing.assert_allclose(rows[["v_smooth_mps", "w_smooth_mps"]], 0.0, atol=0.005)  # FLU -> FRD: no sway
    assert u.max() > 1.0 and u.min() < -0.3  # a real manoeuvre, both ways


def test_the_guides_inspect_commands_decode_the_servo_outputs_with_the_msg_tree(
        dive: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from pipeline.cli import main

    bag, msgs = str(dive / "dives" / "dive01"), str(dive / "msgs")
    assert main(["inspect", bag, "--msgs", msgs]) == 0
    listing = capsys.readouterr().out
    assert "mavros_msgs/msg/RCOut" in listing and "cannot decode" not in listing
    assert main(["inspect", bag, "--msgs", msgs, "--fields", "/mavros/rc/out"]) == 0
    assert "channels[i]" in capsys.readouterr().out
    assert main(["inspect", bag]) == 0  # without the definitions: listed, with what to do
    assert "`message_definitions`" in capsys.readouterr().out
