"""Write a simulated trial as a real log, with the libraries' own writers, custom DVL type included.

Formats (:data:`FORMATS`): ``mcap`` (ROS 2 CDR in MCAP via the ``mcap`` writer, ``ros2msg`` schemas),
``ros1`` (``rosbags.rosbag1.Writer``), ``ros2-sqlite3`` and ``ros2-mcap`` (``rosbags.rosbag2.Writer``, a bag
directory), ``csv`` (a directory with one ``<stream>.csv`` per stream, time columns ``stamp_ns`` (header) and
``log_ns``). The DVL message ``auv_msgs/msg/DVL`` and mavros's ``mavros_msgs/msg/RCOut`` (servo outputs) and
``OverrideRCIn`` (the pilot's RC override) are registered from ``msgs/``, so each log embeds their definitions;
``definitions=False`` writes a ROS 2 bag without any, as bags before Iron are. A trial is anything with
``streams`` (a :class:`pipeline.sim.SimTrial`, :class:`pipeline.sim.ardusub.HeaveTrial`: servo outputs and
``rel_alt``, no attitude; :class:`pipeline.sim.ardusub_vectored.VectoredTrial`). Messages are written in log-time
order (ties: stream order), so the same trial gives the same bytes.
"""

from __future__ import annotations

import logging
import shutil
from functools import cache
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from pipeline.config import parse
from pipeline.config.vehicle import Vehicle
from pipeline.sim.sensors import _FRD_FLU, _NED_ENU, Stream

log = logging.getLogger(__name__)

FORMATS = ("mcap", "ros1", "ros2-sqlite3", "ros2-mcap", "csv")
EXTENSIONS = {"mcap": ".mcap", "ros1": ".bag", "ros2-sqlite3": "", "ros2-mcap": "", "csv": ""}
DVL_TYPE = "auv_msgs/msg/DVL"
RC_OUT_TYPE = "mavros_msgs/msg/RCOut"
OVERRIDE_TYPE = "mavros_msgs/msg/OverrideRCIn"
#: the mavros types registered from ``msgs/`` (file name: the type's name)
MAVROS_TYPES = (RC_OUT_TYPE, OVERRIDE_TYPE)
_LIBRARY = "auvid-sim"


def dvl_msgdef() -> str:
    """The custom DVL message definition (``pipeline/sim/msgs/DVL.msg``)."""
    return resources.files("pipeline.sim").joinpath("msgs/DVL.msg").read_text(encoding="utf-8")


def rc_out_msgdef() -> str:
    """mavros's servo outputs (``pipeline/sim/msgs/RCOut.msg``; the same text in ROS 1 and ROS 2)."""
    return mavros_msgdef(RC_OUT_TYPE)


def mavros_msgdef(msgtype: str) -> str:
    """A mavros message's definition from ``pipeline/sim/msgs/`` (RCOut, OverrideRCIn)."""
    return resources.files("pipeline.sim").joinpath(f"msgs/{msgtype.rsplit('/', 1)[1]}.msg").read_text(encoding="utf-8")


@cache
def typestore(ros_version: int) -> Any:
    """A rosbags typestore (ROS 1 Noetic or ROS 2 Humble) with the DVL and RCOut types registered."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros_version == 1 else Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(dvl_msgdef(), DVL_TYPE))
    for msgtype in MAVROS_TYPES:
        store.register(get_types_from_msg(mavros_msgdef(msgtype), msgtype))
    return store


def _messages(stream: Stream, store: Any, ros_version: int) -> list[Any]:
    """Message objects of one stream, in order."""
    T = store.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    Vector3, Quaternion = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"]
    sec, nsec = np.divmod(stream.header_ns, 1_000_000_000)
    f = {k: np.asarray(v).tolist() for k, v in stream.fields.items()}

    def header(i: int) -> Any:
        stamp = Time(sec=int(sec[i]), nanosec=int(nsec[i]))
        if ros_version == 1:
            return Header(seq=i, stamp=stamp, frame_id=stream.frame_id)
        return Header(stamp=stamp, frame_id=stream.frame_id)

    def vec(prefix: str, i: int) -> Any:
        return Vector3(x=f[f"{prefix}.x"][i], y=f[f"{prefix}.y"][i], z=f[f"{prefix}.z"][i])

    out = []
    zeros9 = np.zeros(9)
    empty = np.zeros(0)
    for i in range(len(stream)):
        if stream.msgtype == "sensor_msgs/msg/Imu":
            q = Quaternion(x=f["orientation.x"][i], y=f["orientation.y"][i], z=f["orientation.z"][i],
                           w=f["orientation.w"][i])
            msg = T[stream.msgtype](header=header(i), orientation=q, orientation_covariance=zeros9,
                                    angular_velocity=vec("angular_velocity", i), angular_velocity_covariance=zeros9,
                                    linear_acceleration=vec("linear_acceleration", i),
                                    linear_acceleration_covariance=zeros9)
        elif stream.msgtype == "geometry_msgs/msg/Vector3Stamped":
            msg = T[stream.msgtype](header=header(i), vector=vec("vector", i))
        elif stream.msgtype == "geometry_msgs/msg/PointStamped":
            point = T["geometry_msgs/msg/Point"](x=f["point.x"][i], y=f["point.y"][i], z=f["point.z"][i])
            msg = T[stream.msgtype](header=header(i), point=point)
        elif stream.msgtype == DVL_TYPE:
            msg = T[DVL_TYPE](header=header(i), velocity=vec("velocity", i), bottom_lock=bool(f["bottom_lock"][i]),
                              altitude=float(f["altitude"][i]))
        elif stream.msgtype == "sensor_msgs/msg/JointState":
            msg = T[stream.msgtype](header=header(i), name=list(stream.joint_names), position=empty,
                                    velocity=np.asarray(stream.fields["velocity"][i], dtype=np.float64), effort=empty)
        elif stream.msgtype == RC_OUT_TYPE:
            msg = T[RC_OUT_TYPE](header=header(i), channels=np.asarray(stream.fields["channels"][i], dtype=np.uint16))
        elif stream.msgtype == OVERRIDE_TYPE:  # no header
            msg = T[OVERRIDE_TYPE](channels=np.asarray(stream.fields["channels"][i], dtype=np.uint16))
        elif stream.msgtype == "geometry_msgs/msg/TwistStamped":
            twist = T["geometry_msgs/msg/Twist"](linear=vec("twist.linear", i), angular=vec("twist.angular", i))
            msg = T[stream.msgtype](header=header(i), twist=twist)
        elif stream.msgtype == "std_msgs/msg/Float64":  # no header: only its log time says when
            msg = T[stream.msgtype](data=float(f["data"][i]))
        else:
            raise ValueError(f"no message builder for {stream.msgtype}")
        out.append(msg)
    return out


def _serialized(streams: dict[str, Stream], ros_version: int) -> list[tuple[int, int, str, bytes]]:
    """(log_ns, stream order, stream name, bytes) of every message, sorted by log time."""
    store = typestore(ros_version)
    rows = []
    for order, (name, stream) in enumerate(streams.items()):
        ser = store.serialize_ros1 if ros_version == 1 else store.serialize_cdr
        for i, msg in enumerate(_messages(stream, store, ros_version)):
            rows.append((int(stream.log_ns[i]), order, name, bytes(ser(msg, stream.msgtype))))
    rows.sort(key=lambda r: (r[0], r[1]))
    return rows


def _write_mcap(streams: dict[str, Stream], path: Path) -> None:
    from mcap.writer import Writer

    store = typestore(2)
    rows = _serialized(streams, 2)
    with open(path, "wb") as fh:
        writer = Writer(fh)
        writer.start(profile="ros2", library=_LIBRARY)
        channels: dict[str, int] = {}
        schemas: dict[str, int] = {}
        for name, stream in streams.items():
            if stream.msgtype not in schemas:
                text, _ = store.generate_msgdef(stream.msgtype, ros_version=2)
                schemas[stream.msgtype] = writer.register_schema(stream.msgtype, "ros2msg", text.encode())
            channels[name] = writer.register_channel(stream.topic, "cdr", schemas[stream.msgtype])
        seq: dict[str, int] = dict.fromkeys(streams, 0)
        for log_ns, _, name, data in rows:
            writer.add_message(channels[name], log_time=log_ns, data=data, publish_time=log_ns, sequence=seq[name])
            seq[name] += 1
        writer.finish()


def _write_rosbag1(streams: dict[str, Stream], path: Path) -> None:
    from rosbags.rosbag1 import Writer

    store = typestore(1)
    rows = _serialized(streams, 1)
    with Writer(path) as writer:
        conns = {name: writer.add_connection(s.topic, s.msgtype, typestore=store) for name, s in streams.items()}
        for log_ns, _, name, data in rows:
            writer.write(conns[name], log_ns, data)


def _write_rosbag2(streams: dict[str, Stream], path: Path, storage: str, definitions: bool) -> None:
    import sqlite3

    from rosbags.rosbag2 import StoragePlugin, Writer

    store = typestore(2)
    rows = _serialized(streams, 2)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        bare = {} if definitions else {"msgdef": "", "rihs01": "RIHS01_" + "0" * 64}
        conns = {name: writer.add_connection(s.topic, s.msgtype, typestore=store, **bare)
                 for name, s in streams.items()}
        for log_ns, _, name, data in rows:
            writer.write(conns[name], log_ns, data)
    if not definitions and storage == "sqlite3":
        con = sqlite3.connect(next(path.glob("*.db3")))
        try:  # a bag before Iron has no such table
            con.execute("DROP TABLE message_definitions")
            con.commit()
        finally:
            con.close()


def csv_column(field: str) -> str:
    """CSV column of a message field path: ``velocity[name=th1]`` -> ``velocity.th1``, ``channels[4]`` ->
    ``channels.4``."""
    if "[name=" in field:
        head, rest = field.split("[name=", 1)
        return f"{head}.{rest.rstrip(']')}"
    if field.endswith("]") and "[" in field:
        head, rest = field.split("[", 1)
        return f"{head}.{rest.rstrip(']')}"
    return field


def _ahrs_euler_deg(stream: Stream, convention: str) -> np.ndarray:
    q = np.stack([stream.fields[f"orientation.{a}"] for a in "xyzw"], axis=1)
    R = Rotation.from_quat(q).as_matrix()
    if convention == "flu_enu":
        R = _NED_ENU @ R @ _FRD_FLU
    return np.degrees(Rotation.from_matrix(R).as_euler("ZYX"))[:, ::-1]  # roll, pitch, yaw (FRD -> NED)


def _write_csv(streams: dict[str, Stream], path: Path, convention: str) -> None:
    path.mkdir(parents=True)
    for name, stream in streams.items():
        cols: dict[str, Any] = {"stamp_ns": stream.header_ns, "log_ns": stream.log_ns}
        if stream.msgtype == "sensor_msgs/msg/Imu":
            euler = _ahrs_euler_deg(stream, convention)
            cols.update(roll=euler[:, 0], pitch=euler[:, 1], yaw=euler[:, 2])
            rates = np.stack([stream.fields[f"angular_velocity.{a}"] for a in "xyz"], axis=1)
            if convention == "flu_enu":
                rates = rates @ _FRD_FLU
            cols.update({f"angular_velocity.{a}": rates[:, j] for j, a in enumerate("xyz")})
        elif stream.msgtype == "sensor_msgs/msg/JointState":
            cols.update({f"velocity.{n}": stream.fields["velocity"][:, j] for j, n in enumerate(stream.joint_names)})
        elif stream.msgtype == RC_OUT_TYPE:
            cols.update({csv_column(f"channels[{j}]"): c for j, c in enumerate(stream.fields["channels"].T)})
        else:
            for key, values in stream.fields.items():
                cols[key] = np.asarray(values).astype(int) if values.dtype == bool else values
        pd.DataFrame(cols).to_csv(path / f"{name}.csv", index=False, float_format="%.17g", lineterminator="\n")


def csv_vehicle(vehicle: Vehicle) -> Vehicle:
    """The vehicle config for the CSV layout written by ``write_trial(trial, "csv", dir)``.

    Each stream becomes ``file: <stream>.csv`` stamped by ``stamp_ns`` (header clock) or ``log_ns`` (log clock),
    with the same ``offset_s``; the AHRS quaternion becomes roll/pitch/yaw columns in degrees (FRD -> NED). A vehicle
    without ``sensors.attitude`` (a level, heave-only one) keeps its sensors as they are.
    """
    data = vehicle.model_dump(mode="json")
    quaternion = None if vehicle.sensors.attitude is None else vehicle.sensors.attitude.quaternion
    for name, stream in data["streams"].items():
        time_column = "log_ns" if stream["clock"] == "log" else "stamp_ns"
        signals = {}
        for signal, source in stream["signals"].items():
            if quaternion is not None and signal == quaternion:
                for axis in ("roll", "pitch", "yaw"):
                    signals[f"{axis}_rad"] = {"field": axis, "unit": "deg"}
            else:
                signals[signal] = {**source, "field": csv_column(source["field"])}
        data["streams"][name] = {
            "file": f"{name}.csv", "clock": "column", "offset_s": stream["offset_s"],
            "csv": {"time_column": time_column, "time_unit": "ns", "time_origin": "absolute"}, "signals": signals,
        }
    if quaternion is not None:
        data["sensors"]["attitude"] = {"roll": "roll_rad", "pitch": "pitch_rad", "yaw": "yaw_rad",
                                       "convention": "frd_ned"}
    out = parse(Vehicle, data, "<csv variant of the example vehicle>")
    out._base_dir = vehicle.resolve("")
    return out


def write_trial(trial: Any, fmt: str, path: str | Path, *, overwrite: bool = False, definitions: bool = True,
                topics: tuple[str, ...] | None = None) -> Path:
    """Write ``trial`` (a :class:`pipeline.sim.SimTrial`) as ``fmt`` at ``path`` (a file for mcap/ros1, a
    directory for ros2-* and csv). The path must not exist unless ``overwrite``. ``definitions=False`` (ROS 2 bags
    only): no message definitions; ``topics``: only these streams' topics."""
    if fmt not in FORMATS:
        raise ValueError(f"unknown format {fmt!r}; known: {FORMATS}")
    if not definitions and not fmt.startswith("ros2-"):
        raise ValueError(f"definitions=False is for ROS 2 bags, not {fmt!r}")
    streams = {k: s for k, s in trial.streams.items() if topics is None or s.topic in topics}
    path = Path(path)
    if path.exists():
        if not overwrite:
            raise FileExistsError(path)
        shutil.rmtree(path) if path.is_dir() else path.unlink()
    path.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "mcap":
        _write_mcap(streams, path)
    elif fmt == "ros1":
        _write_rosbag1(streams, path)
    elif fmt in ("ros2-sqlite3", "ros2-mcap"):
        _write_rosbag2(streams, path, fmt.removeprefix("ros2-"), definitions)
    else:
        _write_csv(streams, path, trial.sensors.ahrs_convention)
    log.info("wrote %s trial (%d messages) to %s", fmt, sum(len(s) for s in streams.values()), path)
    return path
