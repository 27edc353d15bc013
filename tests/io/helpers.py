"""Small logs with a known answer, written by the libraries' own writers (rosbags, mcap) into a temp dir.

One synthetic trial (:func:`trial`) holds a custom DVL type, an Imu and a JointState with names th1..th3; every
writer below writes the same trial, so that every format must give the same values and stamps.
Reusable by other tests: ``trial``, ``expected``, ``write_mcap``, ``write_rosbag2``, ``write_rosbag1``,
``write_rosbag1_unindexed``, ``ros2_store``, ``ros1_store``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from rosbags.typesys import Stores, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

DVL_MSG_ROS2 = """std_msgs/Header header
geometry_msgs/Vector3 velocity
bool bottom_lock
float32 altitude
"""
DVL_MSG_ROS1 = """Header header
geometry_msgs/Vector3 velocity
bool bottom_lock
float32 altitude
"""
DVL = "auv_msgs/msg/DVL"
IMU = "sensor_msgs/msg/Imu"
JOINTS = "sensor_msgs/msg/JointState"
TOPICS = {"/dvl/data": DVL, "/ahrs/imu": IMU, "/thrusters/joint_states": JOINTS}
REQUESTS = {
    "/dvl/data": ["velocity.x", "velocity.y", "velocity.z", "bottom_lock", "altitude"],
    "/ahrs/imu": ["orientation.w", "orientation.z", "angular_velocity.z", "linear_acceleration.x",
                  "orientation_covariance[4]"],
    "/thrusters/joint_states": ["velocity[name=th1]", "velocity[name=th3]", "velocity[1]", "position[0]"],
}


@dataclass
class Msg:
    topic: str
    msgtype: str
    log_ns: int
    stamp_ns: int
    values: dict[str, float]


def ros2_store() -> Typestore:
    store = get_typestore(Stores.LATEST)
    store.register(get_types_from_msg(DVL_MSG_ROS2, DVL))
    return store


def ros1_store() -> Typestore:
    store = get_typestore(Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(DVL_MSG_ROS1, DVL))
    return store


def trial(n: int = 12, seed: int = 0) -> list[Msg]:
    """Messages of the three topics, interleaved in log-time order; header stamps lag the log time."""
    rng = np.random.default_rng(seed)
    t0 = 1_700_000_000_000_000_000
    out: list[Msg] = []
    for i in range(n):
        for k, (topic, msgtype) in enumerate(TOPICS.items()):
            log_ns = t0 + i * 100_000_000 + k * 1_000_000 + int(rng.integers(0, 1000))
            stamp = log_ns - 2_000_000 - int(rng.integers(0, 1000))
            if msgtype == DVL:
                vals = {"velocity.x": rng.normal(), "velocity.y": rng.normal(), "velocity.z": rng.normal(),
                        "bottom_lock": float(i % 3 != 0),
                        "altitude": float(np.float32(rng.uniform(1, 30)))}
            elif msgtype == IMU:
                vals = {"orientation.w": rng.normal(), "orientation.z": rng.normal(),
                        "angular_velocity.z": rng.normal(), "linear_acceleration.x": rng.normal(),
                        "orientation_covariance[4]": rng.normal()}
            else:
                vel = rng.normal(size=3) * 100
                vals = {"velocity[name=th1]": vel[0], "velocity[name=th3]": vel[2], "velocity[1]": vel[1],
                        "position[0]": rng.normal()}
            out.append(Msg(topic, msgtype, log_ns, stamp, {k2: float(v) for k2, v in vals.items()}))
    return out


def expected(msgs: list[Msg]) -> dict[str, dict[str, np.ndarray]]:
    """topic -> {"log_ns", "header_ns", field paths...} as the readers must return them."""
    out: dict[str, dict[str, list[Any]]] = {}
    for m in msgs:
        cols = out.setdefault(m.topic, {"log_ns": [], "header_ns": []})
        cols["log_ns"].append(m.log_ns)
        cols["header_ns"].append(m.stamp_ns)
        for k, v in m.values.items():
            cols.setdefault(k, []).append(v)
    return {t: {k: np.asarray(v, dtype=np.int64 if k.endswith("_ns") else np.float64) for k, v in c.items()}
            for t, c in out.items()}


def build(store: Typestore, m: Msg, *, ros1: bool) -> object:
    T = store.types  # noqa: N806
    sec, nsec = divmod(m.stamp_ns, 1_000_000_000)
    stamp = T["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
    hkw = {"seq": 0} if ros1 else {}
    header = T["std_msgs/msg/Header"](**hkw, stamp=stamp, frame_id="base_link")
    v3 = T["geometry_msgs/msg/Vector3"]
    q = T["geometry_msgs/msg/Quaternion"]
    vals = m.values
    if m.msgtype == DVL:
        return T[DVL](header=header, velocity=v3(x=vals["velocity.x"], y=vals["velocity.y"], z=vals["velocity.z"]),
                      bottom_lock=bool(vals["bottom_lock"]), altitude=vals["altitude"])
    if m.msgtype == IMU:
        cov = np.zeros(9)
        cov[4] = vals["orientation_covariance[4]"]
        return T[IMU](header=header, orientation=q(x=0.0, y=0.0, z=vals["orientation.z"], w=vals["orientation.w"]),
                      orientation_covariance=cov, angular_velocity=v3(x=0.0, y=0.0, z=vals["angular_velocity.z"]),
                      angular_velocity_covariance=np.zeros(9),
                      linear_acceleration=v3(x=vals["linear_acceleration.x"], y=0.0, z=0.0),
                      linear_acceleration_covariance=np.zeros(9))
    vel = np.array([vals["velocity[name=th1]"], vals["velocity[1]"], vals["velocity[name=th3]"]])
    return T[JOINTS](header=header, name=["th1", "th2", "th3"], position=np.array([vals["position[0]"], 0.0, 0.0]),
                     velocity=vel, effort=np.zeros(3))


def write_mcap(path: Path, msgs: list[Msg], *, compression: str = "zstd", chunked: bool = True,
               summary: bool = True, indexes: bool = True) -> Path:
    """A plain MCAP file (ROS 2 CDR, ros2msg schemas) written by the mcap library."""
    from mcap.writer import CompressionType, IndexType, Writer

    store = ros2_store()
    comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4, "none": CompressionType.NONE}[compression]
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=2048, compression=comp, use_chunking=chunked,
                   index_types=IndexType.ALL if indexes else IndexType.NONE, use_statistics=summary,
                   use_summary_offsets=summary, repeat_channels=summary, repeat_schemas=summary)
        w.start(profile="ros2", library="auvid-tests")
        channels: dict[str, int] = {}
        for topic, msgtype in TOPICS.items():
            text, _ = store.generate_msgdef(msgtype, ros_version=2)
            sid = w.register_schema(name=msgtype, encoding="ros2msg", data=text.encode())
            channels[topic] = w.register_channel(topic=topic, message_encoding="cdr", schema_id=sid)
        for i, m in enumerate(msgs):
            data = bytes(store.serialize_cdr(build(store, m, ros1=False), m.msgtype))
            w.add_message(channels[m.topic], log_time=m.log_ns, data=data, publish_time=m.log_ns, sequence=i)
        w.finish()
    return path


def write_rosbag2(path: Path, msgs: list[Msg], *, storage: str = "sqlite3", compression: str | None = None,
                  version: int = 9) -> Path:
    """A ROS 2 bag directory written by rosbags (compression: None, "file" or "message", zstd)."""
    from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

    store = ros2_store()
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    w = Writer(path, version=version, storage_plugin=plugin)  # type: ignore[arg-type]
    if compression:
        mode = CompressionMode.FILE if compression == "file" else CompressionMode.MESSAGE
        w.set_compression(mode, CompressionFormat.ZSTD)
    with w:
        conns = {t: w.add_connection(t, mt, typestore=store) for t, mt in TOPICS.items()}
        for m in msgs:
            w.write(conns[m.topic], m.log_ns, bytes(store.serialize_cdr(build(store, m, ros1=False), m.msgtype)))
    return path


def write_rosbag1(path: Path, msgs: list[Msg], *, compression: str | None = None,
                  chunk_threshold: int | None = 2048) -> Path:
    """A ROS 1 bag written by rosbags (compression None, "bz2" or "lz4")."""
    from rosbags.rosbag1 import Writer

    store = ros1_store()
    w = Writer(path)
    if compression:
        w.set_compression(Writer.CompressionFormat[compression.upper()])
    if chunk_threshold:
        w.chunk_threshold = chunk_threshold
    with w:
        conns = {t: w.add_connection(t, mt, typestore=store) for t, mt in TOPICS.items()}
        for m in msgs:
            w.write(conns[m.topic], m.log_ns, bytes(store.serialize_ros1(build(store, m, ros1=True), m.msgtype)))
    return path


def write_rosbag1_unindexed(path: Path, msgs: list[Msg], **kw: Any) -> Path:
    """A ROS 1 bag whose index was never written (recorder killed): index_pos 0, no index section."""
    write_rosbag1(path, msgs, **kw)
    data = bytearray(path.read_bytes())
    at = data.index(b"index_pos=") + len(b"index_pos=")
    index_pos = int.from_bytes(data[at:at + 8], "little")
    data[at:at + 8] = bytes(8)
    path.write_bytes(bytes(data[:index_pos]))
    return path


# mavros_msgs/msg/OverrideRCIn.msg as mavros 2.x ships it
OVERRIDE_RC_IN = """# Override RC Input
# Currently MAVLink defines override for 18 channel

uint16 CHAN_RELEASE=0
uint16 CHAN_NOCHANGE=65535

uint16[18] channels
"""
