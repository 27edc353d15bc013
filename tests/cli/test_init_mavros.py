"""`auvid init` on an ArduSub (mavros) ROS 2 bag without message definitions (issue 34, item 3).

The bag, written with rosbags' own writer, holds what mavros records on a BlueROV2: the servo outputs
(``/mavros/rc/out``, RCOut), the pilot's RC inputs (``/mavros/rc/override``, OverrideRCIn: no header; and
``/mavros/rc/in``, RCIn), ``/mavros/global_position/rel_alt`` (Float64, metres up), ``/mavros/vfr_hud``, the IMU in
ROS axes and ``/mavros/local_position/velocity_body`` (TwistStamped, FLU). The known answers: the motors' PWM in
the servo outputs, the pilot's inputs that ArduSub's vectored frame mixes into those same PWMs, and a depth that
is minus rel_alt. The starter config, TODOs filled with the BlueROV2 walkthrough's constants, validates, and
ingest gives those answers: with servo outputs logged the thrusters take them; without, the pilot's inputs mixed.
"""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from pipeline.cli.init import starter_config
from pipeline.config import Params, load_vehicle, todo_markers
from pipeline.config.mixing import PRESETS
from pipeline.io.msgdefs import load_user_types
from pipeline.layout import stream_path
from pipeline.sim.ardusub_vectored import DIRECTIONS
from pipeline.tableio import read_parquet
from stages import ingest as ingest_stage
from tests.cli.test_rov_e2e import POSITIONS, T200
from tests.fixturepaths import T200_CSV, shared_fixture

T0_NS = 1_700_000_000_000_000_000
DEFS = {
    "mavros_msgs/msg/RCOut": "std_msgs/Header header\nuint16[] channels\n",
    "mavros_msgs/msg/RCIn": "std_msgs/Header header\nuint8 rssi\nuint16[] channels\n",
    "mavros_msgs/msg/OverrideRCIn": "uint16 CHAN_RELEASE=0\nuint16 CHAN_NOCHANGE=65535\nuint16[18] channels\n",
    "mavros_msgs/msg/VfrHud": ("std_msgs/Header header\nfloat32 airspeed\nfloat32 groundspeed\nint16 heading\n"
                               "float32 throttle\nfloat32 altitude\nfloat32 climb\n"),
}
# pilot inputs per 2-s block, ArduSub's channel order: pitch, roll, throttle, yaw, forward, lateral
PILOT_US = np.array([[1500, 1500, 1500, 1500, 1500, 1500], [1500, 1500, 1500, 1500, 1700, 1500],
                     [1500, 1500, 1400, 1500, 1500, 1500], [1500, 1500, 1500, 1600, 1500, 1550]])
BLOCK_S, N = 2.0, 80  # 10 Hz for 8 s


def motors_us(pilot: np.ndarray) -> np.ndarray:
    """The vectored frame's motor PWMs, worked by the formula of docs/user-guide.md 8.1 (no clipping reached)."""
    order = [1, 0, 3, 2, 4, 5]  # channel order -> ArduSub's factor order (roll, pitch, yaw, throttle, fwd, lat)
    x = (pilot[:, order] - 1500.0) / 400.0
    return 1500.0 + 400.0 * np.clip(x @ np.asarray(PRESETS["ardusub_vectored"]).T, -1, 1)


def rel_alt_m(t_s: np.ndarray) -> np.ndarray:
    return -2.0 - 0.1 * t_s  # diving: 2 m deep and going down


def write_msgs(root: Path) -> Path:
    for msgtype, text in DEFS.items():
        pkg, _, name = msgtype.split("/")
        (root / pkg / "msg").mkdir(parents=True, exist_ok=True)
        (root / pkg / "msg" / f"{name}.msg").write_text(text)
    (root / "mavros_msgs" / "package.xml").write_text("<package><name>mavros_msgs</name></package>\n")
    return root


def write_bag(path: Path, servo_outputs: bool = True, only: tuple[str, ...] | None = None) -> Path:
    """The dive; ``only``: just these topics."""
    from rosbags.rosbag2 import Writer

    ts = get_typestore(Stores.ROS2_HUMBLE)
    for msgtype, text in DEFS.items():
        ts.register(get_types_from_msg(text, msgtype))
    T = ts.types

    def header(t_s: float) -> object:
        ns = T0_NS + round(t_s * 1e9)
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
                                        frame_id="base_link")

    def vec3(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> object:
        return T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z)

    cov9, no_hash = np.zeros(9), "RIHS01_" + "0" * 64
    level = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0)
    messages: list[tuple[int, Any, bytes]] = []
    with Writer(path, version=9) as w:
        topics = {"/mavros/rc/override": "mavros_msgs/msg/OverrideRCIn", "/mavros/rc/in": "mavros_msgs/msg/RCIn",
                  "/mavros/global_position/rel_alt": "std_msgs/msg/Float64",
                  "/mavros/vfr_hud": "mavros_msgs/msg/VfrHud", "/mavros/imu/data": "sensor_msgs/msg/Imu",
                  "/mavros/local_position/velocity_body": "geometry_msgs/msg/TwistStamped"}
        if servo_outputs:
            topics["/mavros/rc/out"] = "mavros_msgs/msg/RCOut"
        if only is not None:
            topics = {k: v for k, v in topics.items() if k in only}
        conn = {topic: w.add_connection(topic, msgtype, msgdef="", rihs01=no_hash) for topic, msgtype in topics.items()}

        def put(t_s: float, topic: str, msg: object) -> None:
            if topic in conn:
                messages.append((T0_NS + round(t_s * 1e9), conn[topic], bytes(ts.serialize_cdr(msg, topics[topic]))))

        for k in range(N):
            t = 0.1 * k
            pilot = PILOT_US[min(int(t / BLOCK_S + 1e-9), len(PILOT_US) - 1)]
            channels = np.full(18, 65535, dtype=np.uint16)  # CHAN_NOCHANGE beyond the six axes
            channels[:6] = pilot
            put(t, "/mavros/rc/override", T["mavros_msgs/msg/OverrideRCIn"](channels=channels))
            put(t + 0.01, "/mavros/rc/in", T["mavros_msgs/msg/RCIn"](header=header(t), rssi=0,
                                                                      channels=channels[:16].copy()))
            if servo_outputs:
                out = np.zeros(16, dtype=np.uint16)
                out[:6] = np.round(motors_us(pilot[None])[0])
                put(t + 0.02, "/mavros/rc/out", T["mavros_msgs/msg/RCOut"](header=header(t + 0.02), channels=out))
            put(t + 0.03, "/mavros/global_position/rel_alt", T["std_msgs/msg/Float64"](data=float(rel_alt_m(t))))
            put(t + 0.04, "/mavros/vfr_hud", T["mavros_msgs/msg/VfrHud"](
                header=header(t + 0.04), airspeed=0.0, groundspeed=0.0, heading=0, throttle=0.0,
                altitude=float(rel_alt_m(t + 0.04)), climb=-0.1))
            put(t + 0.05, "/mavros/imu/data", T["sensor_msgs/msg/Imu"](
                header=header(t + 0.05), orientation=level, orientation_covariance=cov9, angular_velocity=vec3(),
                angular_velocity_covariance=cov9, linear_acceleration=vec3(z=9.81),
                linear_acceleration_covariance=cov9))
            put(t + 0.06, "/mavros/local_position/velocity_body", T["geometry_msgs/msg/TwistStamped"](
                header=header(t + 0.06), twist=T["geometry_msgs/msg/Twist"](linear=vec3(z=-0.1), angular=vec3())))
        for t_ns, connection, data in sorted(messages, key=lambda m: m[0]):
            w.write(connection, t_ns, data)
    con = sqlite3.connect(next(path.glob("*.db3")))
    try:  # a bag before Iron: no definitions
        con.execute("DROP TABLE message_definitions")
        con.commit()
    finally:
        con.close()
    return path


def fill(doc: dict[str, Any]) -> dict[str, Any]:
    """Every TODO of the starter filled with the BlueROV2 walkthrough's constants; the thrusters' directions those of
    the vectored frame (each pilot axis pushes its own axis: the config check of a mixing frame)."""
    table = {"table": T200.name, "table_pwm_column": "PWM (µs)", "table_thrust_column": "Force (Kg f)",
             "table_thrust_unit": "kgf", "table_voltage_column": "Voltage (V)", "voltage_V": 16.0}
    values = {"rigid_body.mass_kg": 11.5, "rigid_body.inertia_kgm2": np.diag([0.16] * 3).tolist(),
              "rigid_body.cg_m": [0.0, 0.0, 0.0], "rigid_body.cb_m": [0.0, 0.0, -0.02],
              "rigid_body.buoyancy_N": 114.384064, "added_mass": np.diag([5.5, 12.7, 14.57, 0.12, 0.12, 0.12]).tolist()}
    for key, what in todo_markers(doc):
        *head, last = key.split(".")
        node: Any = doc
        for part in head:
            node = node[int(part)] if isinstance(node, list) else node[part]
        if key in values:
            value: Any = values[key]
        elif key.startswith("thrusters."):
            i = int(head[1])
            value = {"position_m": POSITIONS[i].tolist(), "direction": DIRECTIONS[i].tolist(), "thrust": table}[last]
        elif key.endswith("mixing.frame"):
            value = "ardusub_vectored"
        else:
            raise AssertionError(f"unexpected TODO {key}: {what}")
        node[int(last) if isinstance(node, list) else last] = value
    return doc


@pytest.fixture(scope="module")
def home(tmp_path_factory: pytest.TempPathFactory) -> Path:
    home = tmp_path_factory.mktemp("ardusub")
    write_msgs(home / "msgs")
    shutil.copy(shared_fixture(T200_CSV), home / T200.name)
    write_bag(home / "dive01", servo_outputs=True)
    write_bag(home / "manual01", servo_outputs=False)
    write_bag(home / "hold01", only=("/mavros/rc/out", "/mavros/global_position/rel_alt"))
    return home


def starter(home: Path, bag: str) -> tuple[dict[str, Any], str]:
    text = starter_config([home / bag], definitions=load_user_types([home / "msgs"]),
                          definition_dirs=[home / "msgs"], base_dir=home).text
    return yaml.safe_load(text), text


def by_topic(doc: dict[str, Any]) -> dict[str, Any]:
    return {s["topic"]: s for s in doc["streams"].values()}


def ingest(home: Path, doc: dict[str, Any], bag: str) -> dict[str, np.ndarray]:
    """The filled config validated, then ingest's tables of the bag: signal -> values (all streams)."""
    path = home / f"{bag}.yaml"
    path.write_text(yaml.safe_dump(fill(doc), sort_keys=False, allow_unicode=True), encoding="utf-8")
    vehicle = load_vehicle(path)
    root = home / "runs" / bag
    result = ingest_stage.run(root, vehicle, Params(), logs=[home / bag])
    assert not result.quarantined, result.quarantined
    out: dict[str, np.ndarray] = {}
    for name in vehicle.streams:
        out.update({k: np.asarray(v) for k, v in read_parquet(stream_path(root, bag, name))[0].to_pydict().items()
                    if k != "t_ns"})
    return out


def test_servo_outputs_become_the_thrusters_pwm_and_rel_alt_a_flipped_depth(home: Path) -> None:
    doc, text = starter(home, "dive01")
    streams = by_topic(doc)
    assert "/mavros/rc/override" not in streams and "/mavros/rc/in" not in streams  # pilot inputs: commented out
    assert "#   topic: \"/mavros/rc/override\"" in text and "#   topic: \"/mavros/vfr_hud\"" in text
    rc = streams["/mavros/rc/out"]
    assert rc["signals"]["pwm3_s"] == {"field": "channels[2]", "unit": "us"} and "mixing" not in rc
    assert [t["pwm_signal"] for t in doc["thrusters"]] == [f"pwm{k}_s" for k in range(1, 7)]
    assert streams["/mavros/global_position/rel_alt"]["signals"]["depth_m"] == {"field": "data", "unit": "m",
                                                                                 "sign": -1}
    sensors = doc["sensors"]
    assert sensors["depth"] == "depth_m"
    assert sensors["attitude"]["convention"] == "flu_enu" and sensors["rates"]["signs"] == [1.0, -1.0, -1.0]
    assert sensors["velocity"] == {"frame": "body", "axes": "flu",
                                   "signals": ["u_velocity_body_mps", "v_velocity_body_mps", "w_velocity_body_mps"]}
    assert not [k for k, _ in todo_markers(doc) if not k.startswith(("rigid_body", "added_mass", "thrusters."))]

    signals = ingest(home, doc, "dive01")
    t_s = 0.1 * np.arange(N)
    np.testing.assert_allclose(signals["depth_m"], -rel_alt_m(t_s), rtol=1e-12)  # rel_alt -2 m: 2 m deep
    pilot = PILOT_US[np.minimum((t_s / BLOCK_S + 1e-9).astype(int), len(PILOT_US) - 1)]
    pwm = np.stack([signals[f"pwm{k}_s"] for k in range(1, 7)], axis=1)
    np.testing.assert_allclose(pwm, np.round(motors_us(pilot)) * 1e-6, rtol=1e-12)


def test_pilot_inputs_alone_are_mixed_by_the_frame_the_user_names(home: Path) -> None:
    doc, text = starter(home, "manual01")
    streams = by_topic(doc)
    rc = streams["/mavros/rc/override"]  # override before RC in; RC in commented out
    assert "/mavros/rc/in" not in streams
    assert rc["signals"]["throttle_s"] == {"field": "channels[2]", "unit": "us"}
    assert rc["mixing"]["inputs"] == {a: f"{a}_s" for a in ("pitch", "roll", "throttle", "yaw", "forward",
                                                             "lateral")}
    assert rc["mixing"]["outputs"] == [t["pwm_signal"] for t in doc["thrusters"]]
    assert "streams.rc_override.mixing.frame" in [k for k, _ in todo_markers(doc)]

    signals = ingest(home, doc, "manual01")
    t_s = 0.1 * np.arange(N)
    pilot = PILOT_US[np.minimum((t_s / BLOCK_S + 1e-9).astype(int), len(PILOT_US) - 1)]
    pwm = np.stack([signals[f"pwm{k}_s"] for k in range(1, 7)], axis=1)
    np.testing.assert_allclose(pwm, motors_us(pilot) * 1e-6, rtol=1e-12)
    assert np.ptp(pwm[:, 4]) > 0 and np.ptp(pwm[:, 0]) > 0  # the vertical and a horizontal motor both driven


def test_without_definitions_the_mavros_topics_are_mapped_with_a_todo_for_them(home: Path) -> None:
    text = starter_config([home / "dive01"]).text
    doc = yaml.safe_load(text)
    assert "/mavros/rc/out" in by_topic(doc)
    assert "message_definitions" in [k.split(".")[0] for k, _ in todo_markers(doc)]


def test_servo_outputs_and_rel_alt_alone_make_a_heave_only_starter(home: Path) -> None:
    """No IMU, no velocity: the depth differentiated is the motion sensor (w only) and the vehicle is level."""
    doc, text = starter(home, "hold01")
    assert doc["sensors"]["position"] == {"signals": ["depth_m"], "components": ["z"]}
    assert "attitude" not in doc["sensors"] and "taken as level" in text
    signals = ingest(home, doc, "hold01")
    np.testing.assert_allclose(signals["depth_m"], -rel_alt_m(0.1 * np.arange(N)), rtol=1e-12)
