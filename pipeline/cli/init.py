"""``auvid init``: a starter vehicle config (YAML text) from what :func:`pipeline.io.inspect.inspect_log` sees.

Its first line, ``# yaml-language-server: $schema=./vehicle.schema.json``, names a copy of the vehicle JSON Schema
shipped in the package written beside the config (:func:`pipeline.config.schemas.copy_schema`; printed to stdout:
the package's schema by its absolute path), so editors validate and complete the file while the TODOs are filled
in, wherever the directory goes.

Recognised topics (by message type, then by topic name where the type says too little):

- ``sensor_msgs/Imu``: attitude quaternion and body rates (``<s>_quat``, ``p_<s>_radps``, ``q_<s>_radps``,
  ``r_<s>_radps``; r only when no dedicated gyro gives it);
- DVL-like (a type with ``velocity.x/.y[.z]`` that is no ROS standard type, or a topic named ``dvl``):
  ``dvl_x_mps`` ... and a bottom-lock / valid bool as ``dvl_valid_flag``; ``sensors.dvl`` with its mounting;
- ``sensor_msgs/JointState``: one thruster per joint name, ``n<k>_rpm`` from ``velocity[name=<joint>]`` in rad/s
  (the ROS unit of a joint velocity);
- ``nav_msgs/Odometry``: body velocity from the twist (``sensors.velocity``, when there is no DVL), attitude and
  rates when no IMU gives them;
- ``std_msgs/Float64`` (and ``Float32``), ``geometry_msgs/PointStamped``: depth when the topic is named
  depth / pressure; other Float64 topics are listed as commented-out streams, to be named with a unit suffix;
- ``geometry_msgs/Vector3Stamped`` named fog / gyro / rate: a yaw-rate gyro (``r_<s>_radps`` from ``vector.z``);
- mavros (ArduSub, PX4), recognised by type even where the log embeds no definition (a note then says to give the
  ``.msg`` files): the servo outputs ``mavros_msgs/RCOut`` (``/mavros/rc/out``) as the motors' PWM, one thruster
  ``pwm_signal`` per motor; where they are not logged, the pilot's inputs (``OverrideRCIn``, ``/mavros/rc/override``,
  else ``RCIn``, ``/mavros/rc/in``) in ArduSub's channel order with a ``mixing`` block whose frame is a TODO (the
  inputs are written, commented out, beside servo outputs; the vectored preset's matrix is shown as a comment);
  ``.../rel_alt`` (``std_msgs/Float64``, metres up) as ``depth_m`` with ``sign: -1``, else ``VfrHud``'s
  ``altitude`` (commented out beside ``rel_alt``); a ``/mavros``
  IMU in ROS axes (``convention: flu_enu``, rate signs [1, -1, -1]); ``local_position/velocity_body``
  (``TwistStamped``, body FLU) as ``sensors.velocity``; ``local_position/odom`` as any Odometry.

Each stream's ``clock`` is ``header`` when its type has a header and the stamp checks of :mod:`pipeline.stamps`
found the header stamps usable in every log, else ``log`` (with the reason as a comment); duplicate or quantized
stamps get the ``time: {rate_hz: R}`` remedy as a comment. A topic missing from some logs is ``optional``.

What the logs cannot tell (mass, inertia, added mass, thruster positions, directions and thrust curves, sensor
mounting, the attitude convention) is written as ``"TODO: <what to give>"``;
:func:`pipeline.config.load_vehicle` refuses a config with TODOs left and lists each with its key.
"""

from __future__ import annotations

import argparse
import json
import logging
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline.cli.common import EXIT_OK, check_paths, user_definitions
from pipeline.config.mixing import AXES, PRESETS
from pipeline.config.schemas import copy_schema, schema_modeline
from pipeline.errors import ConfigError
from pipeline.io.inspect import inspect_log, topic_fields
from pipeline.io.msgdefs import UserTypes

log = logging.getLogger(__name__)

TODO = "TODO"
_RATE_NAME = re.compile(r"fog|gyro|rate", re.IGNORECASE)
_DEPTH_NAME = re.compile(r"depth|pressure", re.IGNORECASE)
_FLAG_NAME = re.compile(r"lock|valid", re.IGNORECASE)
_REL_ALT_NAME = re.compile(r"rel_alt", re.IGNORECASE)
#: ArduSub's default RC channels 1-6 (RCMAP_*): the pilot's inputs, in channel order
PILOT_AXES = ("pitch", "roll", "throttle", "yaw", "forward", "lateral")
#: motors proposed from servo outputs or a mixing frame: ArduSub's vectored frame (the BlueROV2) has six
MOTORS = 6
_MAVROS_RC = ("mavros_msgs/RCOut", "mavros_msgs/OverrideRCIn", "mavros_msgs/RCIn")
_STANDARD_PREFIXES = ("std_msgs/", "geometry_msgs/", "sensor_msgs/", "nav_msgs/", "builtin_interfaces/",
                      "tf2_msgs/", "rosgraph_msgs/", "diagnostic_msgs/")
_STAMP_REMEDY = ("duplicates", "quantized", "steps_back")
_SCALARS = ("std_msgs/Float64", "std_msgs/Float32")
_PWM_TABLE = ("thrust table with a PWM column, e.g. {table: t200.csv, table_pwm_column: 'PWM (µs)', "
              "table_thrust_column: 'Force (Kg f)', table_thrust_unit: kgf, table_voltage_column: 'Voltage (V)', "
              "voltage_V: 16.0}")


@dataclass
class Starter:
    """The starter config: its YAML text, the streams it maps (name -> topic), TODOs left, notes for the user."""

    text: str
    streams: dict[str, str]
    todo_count: int
    notes: list[str] = field(default_factory=list)


@dataclass
class _Topic:
    topic: str
    msgtype: str
    has_header: bool
    clocks: list[str]
    warnings: list[dict[str, Any]]
    present: int
    decodable: bool
    reason: str | None


@dataclass
class _Stream:
    name: str
    topic: _Topic
    signals: dict[str, tuple[str, str | None]]  # signal -> (field, unit)
    comment: str = ""
    sign: dict[str, int] = field(default_factory=dict)  # signal -> -1 where the sensor's axis is the other way
    mixing: list[str] = field(default_factory=list)     # YAML lines of a mixing block, under the stream
    disabled: bool = False                               # written commented out (an alternative to a mapped one)


def _short(msgtype: str) -> str:
    return msgtype.replace("/msg/", "/")


def _stream_name(topic: str, taken: set[str]) -> str:
    parts = [re.sub(r"[^A-Za-z0-9_]", "_", p) for p in topic.strip("/").split("/") if p]
    if len(parts) > 1 and parts[0] == "mavros":  # /mavros/rc/out -> rc_out, /mavros/imu/data -> imu
        parts = [re.sub(r"^(global|local)_position_|_data$", "", "_".join(parts[1:]))]
    name = (parts[0] if parts else "stream").lower() or "stream"
    i = 1
    while name in taken:
        i += 1
        name = "_".join(parts[:i]).lower() if i <= len(parts) else f"{parts[0].lower()}{i}"
    taken.add(name)
    return name


def _gather(logs: list[Path], definitions: UserTypes | None) -> dict[str, _Topic]:
    topics: dict[str, _Topic] = {}
    for path in logs:
        info = inspect_log(path, definitions=definitions)
        if info["format"] == "csv":
            raise ConfigError("`auvid init` reads ROS logs (MCAP, bags); for text files run `auvid inspect` and "
                              "write the `file:` streams from its sniffed csv options", file=path)
        for name, t in info["topics"].items():
            seen = topics.get(name)
            if seen is None:
                topics[name] = _Topic(name, t["msgtype"], t["has_header"], [t["suggested_clock"]],
                                      list(t["stamp_warnings"]), 1, t["decodable"], t["undecodable_reason"])
            else:
                seen.clocks.append(t["suggested_clock"])
                seen.warnings += t["stamp_warnings"]
                seen.present += 1
    return topics


def _fields(logs: list[Path], topic: str, definitions: UserTypes | None) -> dict[str, Any]:
    for path in logs:
        try:
            return topic_fields(path, topic, definitions=definitions)
        except Exception as err:  # noqa: BLE001 - not in this log or undecodable: try the next one
            log.debug("%s: no fields of %s: %s", path, topic, err)
    return {"fields": []}


def _dvl_like(t: _Topic, fields: list[str]) -> bool:
    has_velocity = {"velocity.x", "velocity.y"} <= set(fields)
    standard = t.msgtype.startswith(_STANDARD_PREFIXES)
    return (has_velocity and not standard) or ("dvl" in t.topic.lower() and has_velocity)


def _classify(topics: dict[str, _Topic], logs: list[Path], definitions: UserTypes | None
              ) -> tuple[list[_Stream], dict[str, Any], list[str], list[str]]:
    """Streams, the sensors section (signal names or TODO strings), thruster names (joint order), and notes."""
    taken: set[str] = set()
    streams: list[_Stream] = []
    notes: list[str] = []
    roles: dict[str, Any] = {}
    joints: list[str] = []
    gyro = [t for t in topics.values() if _short(t.msgtype) == "geometry_msgs/Vector3Stamped"
            and _RATE_NAME.search(t.topic)]
    kinds = {_short(t.msgtype) for t in topics.values()}
    # the motors' PWM: servo outputs where logged, else one pilot-input topic mixed (override before RC in)
    pilot = next((k for k in _MAVROS_RC[1:] if k in kinds), None) if _MAVROS_RC[0] not in kinds else None
    depth_topic = any(_short(t.msgtype) in _SCALARS and (_DEPTH_NAME.search(t.topic) or _REL_ALT_NAME.search(t.topic))
                      for t in topics.values())
    for name in sorted(topics):
        t = topics[name]
        kind = _short(t.msgtype)
        if kind in _MAVROS_RC or kind == "mavros_msgs/VfrHud":
            if not t.decodable:
                notes.append(f"{name} ({t.msgtype}) cannot be decoded yet: give its .msg files (--msgs DIR, a "
                             "mavros checkout works) and list them under message_definitions")
            streams.append(_mavros_stream(t, kind, pilot, depth_topic, taken, roles))
            continue
        if not t.decodable:
            notes.append(f"{name} ({t.msgtype}) cannot be decoded: {t.reason}")
            continue
        if kind == "sensor_msgs/Imu":
            s = _stream_name(name, taken)
            sig = {f"{s}_quat": ("orientation", None), f"p_{s}_radps": ("angular_velocity.x", "rad/s"),
                   f"q_{s}_radps": ("angular_velocity.y", "rad/s")}
            if "quaternion" not in roles and name.startswith("/mavros/"):
                roles["ros_axes"] = s  # mavros publishes in ROS axes: body FLU, earth ENU
            roles.setdefault("quaternion", f"{s}_quat")
            roles.setdefault("p", f"p_{s}_radps")
            roles.setdefault("q", f"q_{s}_radps")
            if not gyro:
                sig[f"r_{s}_radps"] = ("angular_velocity.z", "rad/s")
                roles.setdefault("r", f"r_{s}_radps")
            streams.append(_Stream(s, t, sig, "attitude and body rates"))
        elif kind == "geometry_msgs/TwistStamped" and "velocity_body" in name:
            s = _stream_name(name, taken)
            sig = {f"{a}_{s}_mps": (f"twist.linear.{x}", "m/s") for a, x in zip("uvw", "xyz", strict=True)}
            roles.setdefault("velocity_body", list(sig))
            streams.append(_Stream(s, t, sig, "body velocity in ROS axes (FLU)"))
        elif kind == "geometry_msgs/Vector3Stamped" and t in gyro:
            s = _stream_name(name, taken)
            streams.append(_Stream(s, t, {f"r_{s}_radps": ("vector.z", "rad/s")},
                                   "yaw-rate gyro (check the axis and sign)"))
            roles["r"] = f"r_{s}_radps"
        elif kind == "sensor_msgs/JointState":
            names = _fields(logs, name, definitions).get("joint_names") or []
            if not names:
                notes.append(f"{name}: no joint names in its first message; map the thrusters by hand")
                continue
            s = _stream_name(name, taken)
            sig = {}
            for joint in names:
                k = len(joints) + 1
                joints.append(joint)
                sig[f"n{k}_rpm"] = (f"velocity[name={joint}]", "rad/s")
            streams.append(_Stream(s, t, sig, "propeller speeds (a joint velocity is rad/s in ROS)"))
        elif kind == "nav_msgs/Odometry":
            s = _stream_name(name, taken)
            sig = {f"u_{s}_mps": ("twist.twist.linear.x", "m/s"), f"v_{s}_mps": ("twist.twist.linear.y", "m/s"),
                   f"w_{s}_mps": ("twist.twist.linear.z", "m/s"), f"{s}_quat": ("pose.pose.orientation", None),
                   f"p_{s}_radps": ("twist.twist.angular.x", "rad/s"),
                   f"q_{s}_radps": ("twist.twist.angular.y", "rad/s"),
                   f"r_{s}_radps": ("twist.twist.angular.z", "rad/s")}
            roles.setdefault("odometry", s)
            streams.append(_Stream(s, t, sig, "twist in the child frame (ROS: FLU; check the signs of v, w)"))
        elif kind in _SCALARS and _REL_ALT_NAME.search(name) and "depth" not in roles:
            s = _stream_name(name, taken)
            streams.append(_Stream(s, t, {"depth_m": ("data", "m")}, "relative altitude, m up (ArduSub: the depth "
                                   "sensor's): depth is down, so sign -1", sign={"depth_m": -1}))
            roles["depth"] = "depth_m"
        elif kind in (*_SCALARS, "geometry_msgs/PointStamped") \
                and _DEPTH_NAME.search(name) and "depth" not in roles:
            s = _stream_name(name, taken)
            fld = "point.z" if kind == "geometry_msgs/PointStamped" else "data"
            streams.append(_Stream(s, t, {"depth_m": (fld, "m")}, "depth (positive down; check it is not pressure)"))
            roles["depth"] = "depth_m"
        elif kind in _SCALARS:
            notes.append(f"{name} ({kind}): a scalar of unknown meaning; see the commented-out stream")
            streams.append(_Stream(_stream_name(name, taken), t, {}, "unknown scalar"))
        else:
            fields = _fields(logs, name, definitions).get("fields") or []
            if _dvl_like(t, fields) and "dvl" not in roles:
                s = _stream_name(name, taken)
                has_z = "velocity.z" in fields
                sig = {f"dvl_{a}_mps": (f"velocity.{a}", "m/s") for a in ("xyz" if has_z else "xy")}
                flag = next((f for f in fields if "." not in f and _FLAG_NAME.search(f)), None)
                if flag is not None:
                    sig["dvl_valid_flag"] = (flag, None)
                streams.append(_Stream(s, t, sig, "DVL velocity in its own frame"))
                roles["dvl"] = (list(sig)[:3 if has_z else 2], "dvl_valid_flag" if flag else None)
            else:
                notes.append(f"{name} ({t.msgtype}) not recognised; `auvid inspect LOG --fields {name}` lists its "
                             "fields")
    return streams, roles, joints, notes


def _mavros_stream(t: _Topic, kind: str, pilot: str | None, depth_topic: bool, taken: set[str],
                   roles: dict[str, Any]) -> _Stream:
    """A mavros topic's stream: servo outputs as motor PWMs; pilot inputs, mixed where they are all there is
    (``pilot``: the pilot-input type chosen), else commented out; VFR_HUD's altitude as depth where no depth or
    rel_alt topic is logged, else commented out."""
    s = _stream_name(t.topic, taken)
    if kind == "mavros_msgs/VfrHud":
        stream = _Stream(s, t, {"depth_m": ("altitude", "m")}, "VFR_HUD: altitude, m up (ArduSub: the depth "
                         "sensor's); sign -1 for a depth", sign={"depth_m": -1}, disabled=depth_topic)
        if not depth_topic:
            roles["depth"] = "depth_m"
        return stream
    if kind == "mavros_msgs/RCOut":
        pwm = [f"pwm{k}_s" for k in range(1, MOTORS + 1)]
        roles["pwm"] = pwm
        sig: dict[str, tuple[str, str | None]] = {n: (f"channels[{k}]", "us") for k, n in enumerate(pwm)}
        return _Stream(s, t, sig, "servo outputs: the PWM each motor got (channels[i]: motor i+1)")
    sig = {f"{a}_s": (f"channels[{k}]", "us") for k, a in enumerate(PILOT_AXES)}
    what = "pilot inputs (ArduSub's RC 1-6: pitch, roll, throttle, yaw, forward, lateral), mixed by the autopilot"
    if kind != pilot:
        why = "the thrusters take the servo outputs" if pilot is None else f"{_short(pilot)}'s inputs are mixed"
        return _Stream(s, t, sig, f"{what}; {why}", disabled=True)
    pwm = [f"pwm{k}_s" for k in range(1, MOTORS + 1)]
    roles["pwm"] = pwm
    frame = _todo("ardusub_vectored (the BlueROV2, FRAME_CONFIG 1), or `matrix:` rows of "
                  "[roll, pitch, yaw, throttle, forward, lateral] per motor")
    inputs = ", ".join(f"{a}: {a}_s" for a in PILOT_AXES)
    shown = [f"  #   motor {i}: {_v([int(x) if float(x).is_integer() else x for x in row])}"
             for i, row in enumerate(PRESETS["ardusub_vectored"], start=1)]
    mixing = ["mixing:  # manual-mode trials only: a controller's additions are not in the pilot's inputs",
              f"  frame: {frame}",
              f"  # ardusub_vectored's factors per motor, [{', '.join(AXES)}] (AP_Motors6DOF); the thrusters'",
              "  # directions must make forward push +X, lateral +Y, yaw +N, throttle up (checked when loaded):",
              *shown, f"  inputs: {{{inputs}}}", f"  outputs: {_v(pwm)}",
              "  # directions: [1, 1, 1, 1, 1, 1]  # ArduSub's MOT_n_DIRECTION"]
    return _Stream(s, t, sig, what + " into motor PWMs (docs/user-guide.md 8.1)", mixing=mixing)


def _clock(t: _Topic, n_logs: int) -> tuple[str, list[str]]:
    comments = []
    clock = "header" if t.has_header and all(c == "header" for c in t.clocks) else "log"
    if t.has_header and clock == "log":
        bad = sorted({w["check"] for w in t.warnings if w["check"] in ("zero", "constant", "far_from_log")})
        comments.append(f"header stamps unusable ({', '.join(bad)}): log time")
    remedies = {w["check"]: w["remedy"] for w in t.warnings if w["check"] in _STAMP_REMEDY}
    for check, remedy in sorted(remedies.items()):
        comments.append(f"{check} stamps: {remedy}")
    return clock, comments


def _v(value: Any) -> str:
    return json.dumps(value, ensure_ascii=False)


def _todo(what: str) -> str:
    return _v(f"{TODO}: {what}")


def starter_config(logs: list[str | Path] | list[Path], *, name: str | None = None,
                   definitions: UserTypes | None = None, definition_dirs: list[Path] | None = None,
                   base_dir: Path | None = None, schema_beside: bool = False) -> Starter:
    """The starter config of a vehicle from its logs (see the module docstring); nothing is written.
    ``schema_beside``: the first line names ``./vehicle.schema.json`` (the caller copies the schema there)."""
    paths = [Path(p) for p in logs]
    if not paths:
        raise ValueError("give at least one log")
    topics = _gather(paths, definitions)
    streams, roles, joints, notes = _classify(topics, paths, definitions)
    vehicle_name = name or re.sub(r"[^A-Za-z0-9_\-]", "_", paths[0].name.split(".")[0]) or "vehicle"
    out: list[str] = [
        schema_modeline("vehicle", beside=schema_beside),
        f"# Starter vehicle config written by `auvid init` from {len(paths)} log(s): "
        + ", ".join(p.name for p in paths[:5]) + (" ..." if len(paths) > 5 else ""),
        "# Fill in every TODO (the loader lists those left). Body axes FRD, world NED; matrices in the DOF",
        "# order [u v w p q r]. See docs/user-guide.md, section 2.",
        f"name: {_v(vehicle_name)}",
    ]
    if definition_dirs:
        rel = [str(_relative(d, base_dir)) for d in definition_dirs]
        out.append(f"message_definitions: {_v(rel)}")
    elif any(not t.decodable for t in topics.values() if _short(t.msgtype) in _MAVROS_RC):
        out.append(f"message_definitions: [{_todo('directory of the mavros_msgs .msg files (a mavros checkout)')}]")
    out += [
        "rigid_body:",
        f"  mass_kg: {_todo('mass in air, kg')}",
        f"  inertia_kgm2: {_todo('inertia about the CG, body axes, kg m^2: [[Ixx, 0, 0], [0, Iyy, 0], [0, 0, Izz]]')}",
        f"  cg_m: {_todo('centre of gravity [x, y, z] in body axes, m')}",
        f"  cb_m: {_todo('centre of buoyancy [x, y, z] in body axes, m')}",
        f"  buoyancy_N: {_todo('buoyancy in N (null: equal to the weight)')}",
        f"added_mass: {_todo('6x6 added-mass matrix M_A, [u v w p q r] order')}",
    ]
    if joints:
        out.append("thrusters:")
        for k, joint in enumerate(joints, start=1):
            where = _todo(f"position of {joint} [x, y, z] in body axes, m")
            towards = _todo(f"thrust direction of {joint} in body axes, e.g. [1, 0, 0]")
            out += [
                f"  - name: {_v(joint)}",
                f"    speed_signal: n{k}_rpm",
                f"    position_m: {where}",
                f"    direction: {towards}",
                f"    thrust: {_todo('thrust curve: {k_fwd_N_per_rpm2: K, k_bwd_N_per_rpm2: K} or a table')}",
            ]
    elif "pwm" in roles:
        out.append("thrusters:  # one per motor (ArduSub's vectored frame: 1-4 horizontal, 5-6 vertical); a "
                   "frame with more motors: add them")
        for k, pwm in enumerate(roles["pwm"], start=1):
            out += [
                f"  - name: t{k}",
                f"    pwm_signal: {pwm}",
                f"    position_m: {_todo(f'position of motor {k} [x, y, z] in body axes, m')}",
                f"    direction: {_todo(f'thrust direction of motor {k} in body axes (FRD), e.g. [1, 0, 0]')}",
                f"    thrust: {_todo(_PWM_TABLE)}",
            ]
    else:
        what = ("one entry per thruster: name, speed_signal / pwm_signal / thrust_signal, position_m, direction, "
                "thrust (no JointState topic found)")
        out.append(f"thrusters: {_todo(what)}")
    out += _sensors(roles)
    out.append("streams:")
    mapped: dict[str, str] = {}
    for s in streams:
        clock, comments = _clock(s.topic, len(paths))
        prefix = "  " if s.signals and not s.disabled else "  # "
        out.append(f"{prefix}{s.name}:" + f"  # {_short(s.topic.msgtype)}: {s.comment}")
        out.append(f"{prefix}  topic: {_v(s.topic.topic)}")
        out.append(f"{prefix}  clock: {clock}" + (f"  # {'; '.join(comments)}" if comments else ""))
        out.append(f"{prefix}  offset_s: 0.0  # constant offset added to the stamps, if the sensor clock is known "
                   "to lead or lag")
        if s.topic.present < len(paths):
            out.append(f"{prefix}  optional: true  # in {s.topic.present} of {len(paths)} logs")
        out.append(f"{prefix}  signals:")
        if s.signals:
            if not s.disabled:
                mapped[s.name] = s.topic.topic
            for sig, (fld, unit) in s.signals.items():
                unit_part = f", unit: {_v(unit)}" if unit else ""
                sign_part = f", sign: {s.sign[sig]}" if sig in s.sign else ""
                out.append(f"{prefix}    {sig}: {{field: {_v(fld)}{unit_part}{sign_part}}}")
            out += [f"{prefix}  {line}" for line in s.mixing]
        else:
            out.append(f"{prefix}    {s.name}_<unit>: {{field: data, unit: ...}}  # e.g. rudder_rad (unit: deg), "
                       "then list it under control_surfaces")
    if not mapped:
        out.append(f"  todo: {_todo('no topic recognised; map topics to signals (auvid inspect LOG --fields TOPIC)')}")
    for note in notes:
        out.append(f"# note: {note}")
    text = "\n".join(out) + "\n"
    return Starter(text=text, streams=mapped, todo_count=text.count(f'"{TODO}:'), notes=notes)


def _relative(path: Path, base: Path | None) -> Path:
    if base is None:
        return path
    try:
        return path.resolve().relative_to(base.resolve())
    except ValueError:
        return path.resolve()


def _sensors(roles: dict[str, Any]) -> list[str]:
    out = ["sensors:"]
    if "dvl" in roles:
        velocity, valid = roles["dvl"]
        out += ["  dvl:", f"    velocity: {_v(velocity)}"]
        if valid:
            out.append(f"    valid: {valid}")
        out += ["    zero_is_invalid: true",
                f"    position_m: {_todo('DVL position [x, y, z] in body axes, m')}",
                f"    rotation_rpy_deg: {_todo('DVL frame -> body frame, [roll, pitch, yaw] in deg')}"]
    elif "odometry" in roles:
        s = roles["odometry"]
        signals = [f"u_{s}_mps", f"v_{s}_mps", f"w_{s}_mps"]
        out += ["  velocity:", "    frame: body", "    axes: flu  # a ROS twist, in its child frame: FLU -> FRD",
                f"    signals: {_v(signals)}"]
    elif "velocity_body" in roles:
        out += ["  velocity:", "    frame: body", "    axes: flu  # mavros's body velocity: ROS axes, FLU -> FRD",
                f"    signals: {_v(roles['velocity_body'])}"]
    elif "depth" in roles:  # a depth alone: the heave of a depth-hold trial (a DVL or velocity source: replace it)
        out += ["  position:  # the depth differentiated: heave (w) only; a dvl or velocity source gives u, v too",
                f"    signals: [{roles['depth']}]", "    components: [z]"]
    else:
        out.append(f"  velocity: {_todo('a velocity source: dvl (with mounting) or velocity (frame, signals)')}")
    quat = roles.get("quaternion") or (f"{roles.get('odometry')}_quat" if "odometry" in roles else None)
    if quat and "ros_axes" in roles:
        out += ["  attitude:", f"    quaternion: {quat}", "    convention: flu_enu  # mavros: body FLU -> ENU"]
    elif quat:
        out += ["  attitude:", f"    quaternion: {quat}",
                f"    convention: {_todo('frd_ned (body FRD -> NED, marine) or flu_enu (ROS body FLU -> ENU)')}"]
    elif "dvl" not in roles and "odometry" not in roles and "velocity_body" not in roles and "depth" in roles:
        out.append("  # attitude: none logged: the vehicle is taken as level (roll = pitch = 0)")
    else:
        out.append(f"  attitude: {_todo('quaternion signal, or roll/pitch/yaw signals')}")
    odom = roles.get("odometry")
    rates = {a: roles.get(a) or (f"{a}_{odom}_radps" if odom else None) for a in "pqr"}
    if any(rates.values()):
        out.append("  rates:")
        out += [f"    {a}: {sig}" for a, sig in rates.items() if sig]
        imu = roles.get("ros_axes")
        if odom and any(rates[a] == f"{a}_{odom}_radps" for a in "qr"):
            # ROS twists are FLU: q (about y left) and r (about z up) change sign in the body FRD axes
            signs = [-1.0 if a != "p" and rates[a] == f"{a}_{odom}_radps" else 1.0 for a in "pqr"]
            out.append(f"    signs: {_v(signs)}  # the odometry's angular twist is FLU")
        elif imu and any(rates[a] == f"{a}_{imu}_radps" for a in "qr"):
            signs = [-1.0 if a != "p" and rates[a] == f"{a}_{imu}_radps" else 1.0 for a in "pqr"]
            out.append(f"    signs: {_v(signs)}  # mavros's gyro is FLU")
    if "depth" in roles:
        out.append(f"  depth: {roles['depth']}")
    return out


def cmd_init(args: argparse.Namespace) -> int:
    check_paths(args.logs, "log(s)")
    definitions, _ = user_definitions(args)
    out = args.out
    if str(out) != "-" and out.exists() and not args.force:
        raise ConfigError(f"{out} exists; choose another --out or give --force")
    base = Path.cwd() if str(out) == "-" else out.resolve().parent
    starter = starter_config(args.logs, name=args.name, definitions=definitions,
                             definition_dirs=[Path(d).resolve() for d in args.definitions], base_dir=base,
                             schema_beside=str(out) != "-")
    if str(out) == "-":
        print(starter.text, end="")
    else:
        out.write_text(starter.text, encoding="utf-8")
        copy_schema(base, "vehicle")
        print(f"wrote {out}: {len(starter.streams)} stream(s), {starter.todo_count} TODO(s) to fill in")
    for note in starter.notes:
        print(f"  {note}", file=sys.stderr)
    return EXIT_OK
