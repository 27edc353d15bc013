"""A `nav_msgs/msg/Odometry` as the velocity source, from a ROS 2 bag to the kinematics table.

The bag is written with rosbags' own writer: the odometry at 20 Hz (header stamps on the 50-ms grid), its twist in
the child frame in ROS FLU axes (x forward, y left, z up) and its pose in ENU; a Float64 propeller speed. The vehicle
config states the twist as `sensors.velocity: {frame: body, axes: flu}` and the pose's orientation as a `flu_enu`
quaternion.

The known answer: a vehicle turning from heading 0 to 90 deg (NED) with u, v and w all different and varying, and
v, w of the sign that FLU flips (starboard, down): u, v, w on the grid equal the body velocities exactly; the
smoothed ones are within 1e-3 m/s. Taking the twist as FRD (no axes conversion) gets v and w with the wrong sign.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from pipeline import layout
from pipeline.config import Params, Vehicle, load_vehicle, parse
from pipeline.errors import ConfigError
from pipeline.tableio import read_parquet
from stages import differentiate as differentiate_stage
from stages import ingest as ingest_stage
from stages import sync as sync_stage

T0_NS = 1_700_000_000_000_000_000   # a multiple of the 50-ms grid period
DURATION_S = 30.0
ODOM = "nav_msgs/msg/Odometry"

VEHICLE = """
name: odom_boat
rigid_body: {mass_kg: 20.0, inertia_kgm2: [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]}
added_mass: [[2, 0, 0, 0, 0, 0], [0, 9, 0, 0, 0, 0], [0, 0, 9, 0, 0, 0], [0, 0, 0, 0.1, 0, 0], [0, 0, 0, 0, 0.2, 0],
             [0, 0, 0, 0, 0, 0.5]]
thrusters:
  - {name: prop, speed_signal: n1_rpm, position_m: [-0.5, 0.0, 0.0], direction: [1, 0, 0],
     thrust: {k_fwd_N_per_rpm2: 1.0e-5}}
sensors:
  velocity: {frame: body, axes: flu, signals: [u_odom_mps, v_odom_mps, w_odom_mps]}   # the twist, child frame
  attitude: {quaternion: odom_quat, convention: flu_enu}                              # the pose
  rates: {p: p_odom_radps, q: q_odom_radps, r: r_odom_radps, signs: [1.0, -1.0, -1.0]}  # FLU -> FRD
streams:
  odom:
    topic: /odom
    clock: header
    signals:
      u_odom_mps: {field: twist.twist.linear.x}
      v_odom_mps: {field: twist.twist.linear.y}
      w_odom_mps: {field: twist.twist.linear.z}
      odom_quat: {field: pose.pose.orientation}
      p_odom_radps: {field: twist.twist.angular.x}
      q_odom_radps: {field: twist.twist.angular.y}
      r_odom_radps: {field: twist.twist.angular.z}
  prop:
    topic: /prop_rpm
    clock: log
    signals:
      n1_rpm: {field: data}
"""


def motion(t_s: np.ndarray) -> dict[str, np.ndarray]:
    """Body FRD velocities and NED heading of a vehicle turning from 0 to 90 deg; u, v, w differ and vary."""
    w = np.pi / DURATION_S
    return {"u": 1.0 + 0.3 * np.sin(0.3 * t_s), "v": 0.25 + 0.1 * np.cos(0.5 * t_s),
            "w": 0.08 + 0.03 * np.sin(0.7 * t_s), "psi": np.pi / 4 * (1 - np.cos(w * t_s)),
            "r": np.pi / 4 * w * np.sin(w * t_s)}


def write_bag(path: Path) -> Path:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    t = np.arange(int(DURATION_S * 20) + 1) * 0.05
    k = motion(t)
    vec3 = lambda x, y, z: T["geometry_msgs/msg/Vector3"](x=float(x), y=float(y), z=float(z))  # noqa: E731
    cov = np.zeros(36)
    with Writer(path, version=9) as w:
        odom = w.add_connection("/odom", ODOM, typestore=ts)
        prop = w.add_connection("/prop_rpm", "std_msgs/msg/Float64", typestore=ts)
        for j, t_s in enumerate(t):
            ns = T0_NS + round(t_s * 1e9)
            stamp = T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)
            half = (np.pi / 2 - k["psi"][j]) / 2  # ENU yaw of the FLU body = 90 deg - NED heading
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=float(np.sin(half)),
                                                              w=float(np.cos(half))))
            twist = T["geometry_msgs/msg/Twist"](linear=vec3(k["u"][j], -k["v"][j], -k["w"][j]),  # FRD -> FLU
                                                 angular=vec3(0.0, 0.0, -k["r"][j]))
            msg = T[ODOM](header=T["std_msgs/msg/Header"](stamp=stamp, frame_id="odom"), child_frame_id="base_link",
                          pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=cov),
                          twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov))
            w.write(odom, ns + 10_000_000, bytes(ts.serialize_cdr(msg, ODOM)))
            w.write(prop, ns + 3_000_000, bytes(ts.serialize_cdr(T["std_msgs/msg/Float64"](data=600.0),
                                                                 "std_msgs/msg/Float64")))
    return path


@pytest.fixture(scope="module")
def kinematics(tmp_path_factory: pytest.TempPathFactory):
    home = tmp_path_factory.mktemp("odom")
    (home / "boat.yaml").write_text(VEHICLE, encoding="utf-8")
    write_bag(home / "run01")
    vehicle = load_vehicle(home / "boat.yaml")
    noise = {s: 1e-3 for s in ("u_odom_mps", "v_odom_mps", "w_odom_mps", "p_odom_radps", "q_odom_radps",
                               "r_odom_radps")}
    # the log's motion is a kinematic formula, not the response to its thrusters: the white-jerk smoother alone
    params = Params.model_validate({"differentiate": {"noise_sd": noise, "model_passes": 0}})
    root = home / "out"
    for stage, extra in ((ingest_stage, {"logs": [home / "run01"]}), (sync_stage, {}), (differentiate_stage, {})):
        result = stage.run(root, vehicle, params, **extra)
        assert not result.quarantined, (stage.NAME, result.quarantined)
    return read_parquet(layout.kinematics_path(root, "run01"))[0].to_pandas()


def test_an_odometry_twist_in_flu_axes_gives_the_body_frd_velocities(kinematics) -> None:
    kin = kinematics
    t = (kin["t_ns"].to_numpy() - T0_NS) / 1e9
    truth = motion(t)
    assert t.max() - t.min() > 0.8 * DURATION_S
    assert truth["psi"].max() > np.deg2rad(80) and truth["v"].min() > 0.1 and truth["w"].min() > 0.04
    # the measured values on the grid: exact (the stamps lie on the grid)
    for dof in "uvw":
        np.testing.assert_allclose(kin[f"{dof}_meas_mps"], truth[dof], atol=1e-9)
    np.testing.assert_allclose(kin["r_meas_radps"], truth["r"], atol=1e-9)  # FLU z up -> FRD z down
    np.testing.assert_allclose(np.unwrap(kin["yaw_rad"]), truth["psi"], atol=1e-9)
    # the smoothed ones, within the stated 1e-3 m/s noise
    for dof in "uvw":
        np.testing.assert_allclose(kin[f"{dof}_smooth_mps"], truth[dof], atol=1e-3)


def test_axes_name_body_axes_only() -> None:
    data = yaml.safe_load(VEHICLE)
    data["sensors"]["velocity"]["frame"] = "earth"
    with pytest.raises(ConfigError, match="`axes` names body axes"):
        parse(Vehicle, data)
