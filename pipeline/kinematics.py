"""Frames, conventions and mounting: from the synced table to body velocities and attitude on the grid.

:func:`body_kinematics` (synced table + vehicle config) -> ``t_ns``, ``segment``, measured body velocities at the
reference point (``u_mps`` ... ``r_radps``), attitude ``roll_rad pitch_rad yaw_rad`` of body FRD w.r.t. NED (yaw
unwrapped), ``depth_m`` if configured, and every actuator signal (each thruster's speed, PWM or thrust; each
control surface's angle: :meth:`Vehicle.actuator_signals`). The differentiate stage
(:mod:`pipeline.estimation.differentiate`) smooths and differentiates them.

- **Attitude** from a quaternion in the configured convention: ``frd_ned`` is body FRD -> NED (marine);
  ``flu_enu`` (ROS) is body FLU -> ENU and is converted explicitly, R_ned_frd = T R_enu_flu F with
  T = [[0,1,0],[1,0,0],[0,0,-1]] (ENU -> NED) and F = diag(1,-1,-1) (FRD -> FLU). Roll/pitch/yaw are
  the ZYX Euler angles of R_ned_frd. Or from roll/pitch/yaw signals, taken as FRD/NED angles as they are.
  Without ``sensors.attitude`` the vehicle is level, roll = pitch = yaw = 0 (a warning): a heave-only vehicle.
- **Rates**: p, q, r from the configured rate signals times ``signs`` (gyro axis mapping). A rate that is
  not configured (a 3-DOF vehicle with only a FOG for r) is **0**, not the derivative of the attitude:
  differentiating roll/pitch would be noisy and, at the small angles of a horizontal-plane vehicle,
  zero within noise. The derive stage then sees zeros for those DOFs (see :mod:`pipeline.derive`).
- **DVL**: v_ref = R v_dvl - omega x r_dvl, with R the mounting rotation (``rotation_rpy_deg``, ZYX:
  R = Rz(yaw) Ry(pitch) Rx(roll), DVL frame -> body) and r_dvl the DVL position in body axes.
- **Other velocity sources** (``sensors.velocity``): body-frame velocities as they are (R = I; ``axes: flu``,
  ROS axes such as an Odometry twist in its child frame: R = diag(1, -1, -1)); earth-frame
  velocities (towing-tank x/y rates, GNSS) rotated at each sample by the logged attitude, v_body = R_nb^T v_ned
  (ENU axes converted to NED first), then the same lever-arm term. Two signals make a planar source: u, v
  only (w = 0, not measured), and earth x/y rates are rotated by the heading alone (:func:`sensor_to_body`).
- **Positions** (``sensors.position``): differentiated per earth axis by the white-jerk smoother first
  (:mod:`pipeline.estimation.position`), their rates then rotated as earth-frame velocities. A source gives
  axes by name (``components``): each signal goes into its own axis, the others 0; a depth alone (z) gives w only.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from pipeline.config.vehicle import LinearVelocity, Vehicle
from pipeline.errors import SchemaError
from pipeline.sync import quat_columns
from pipeline.vocabulary import VELOCITY

__all__ = ["attitude_from_quaternion", "body_kinematics", "matrix_to_rpy", "mounting_matrix", "quat_to_matrix",
           "rpy_matrix", "sensor_to_body", "sensor_vector", "unwrap_finite", "velocity_to_body"]

log = logging.getLogger(__name__)

_ENU_TO_NED = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FRD_TO_FLU = np.diag([1.0, -1.0, -1.0])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (n, 3, 3) of quaternions (n, 4) ordered w, x, y, z (normalized here)."""
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], axis=-1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], axis=-1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1),
    ], axis=1)


def rpy_matrix(roll: np.ndarray | float, pitch: np.ndarray | float, yaw: np.ndarray | float) -> np.ndarray:
    """ZYX rotation matrix Rz(yaw) Ry(pitch) Rx(roll), (n, 3, 3) (or (3, 3) for scalars)."""
    cr, sr = np.cos(roll), np.sin(roll)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cy, sy = np.cos(yaw), np.sin(yaw)
    return np.stack([
        np.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], axis=-1),
        np.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], axis=-1),
        np.stack([-sp, cp * sr, cp * cr], axis=-1),
    ], axis=-2)


def matrix_to_rpy(R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZYX Euler angles (roll, pitch, yaw) of rotation matrices (n, 3, 3); yaw in (-pi, pi]."""
    roll = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    pitch = -np.arcsin(np.clip(R[:, 2, 0], -1.0, 1.0))
    yaw = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    return roll, pitch, yaw


def attitude_from_quaternion(q: np.ndarray, convention: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Roll, pitch, yaw of body FRD w.r.t. NED from quaternions (n, 4: w x y z) in either convention."""
    R = quat_to_matrix(q)
    if convention == "flu_enu":
        R = _ENU_TO_NED @ R @ _FRD_TO_FLU
    elif convention != "frd_ned":
        raise ValueError(f"unknown quaternion convention {convention!r}; expected frd_ned or flu_enu")
    return matrix_to_rpy(R)


def unwrap_finite(angle: np.ndarray) -> np.ndarray:
    """np.unwrap over the finite values, NaN kept in place."""
    out = np.array(angle, dtype=float)
    ok = np.isfinite(out)
    out[ok] = np.unwrap(out[ok])
    return out


def _column(table: pd.DataFrame, name: str, what: str) -> np.ndarray:
    if name not in table.columns:
        raise SchemaError(f"{what}: column {name!r} not in the synced table", field=name)
    return table[name].to_numpy(dtype=float)


def body_kinematics(synced: pd.DataFrame, vehicle: Vehicle) -> pd.DataFrame:
    """Measured body velocities, attitude, depth and thruster speeds on the synced grid (all rows kept)."""
    sensors = vehicle.sensors
    n = len(synced)
    out: dict[str, np.ndarray] = {"t_ns": synced["t_ns"].to_numpy(dtype=np.int64)}
    if "segment" not in synced.columns:
        raise SchemaError("the synced table has no segment column", field="segment")
    out["segment"] = synced["segment"].to_numpy(dtype=np.int32)

    att = sensors.attitude
    if att is None:
        log.warning("sensors.attitude not given: the vehicle is taken as level (roll = pitch = 0, heading 0)")
        roll, pitch, yaw = np.zeros(n), np.zeros(n), np.zeros(n)
    elif att.quaternion is not None:
        q = np.stack([_column(synced, c, "sensors.attitude.quaternion") for c in quat_columns(att.quaternion)],
                     axis=1)
        roll, pitch, yaw = attitude_from_quaternion(q, att.convention)
    else:
        def angle(name: str | None, key: str) -> np.ndarray:
            return np.zeros(n) if name is None else _column(synced, name, f"sensors.attitude.{key}")

        roll, pitch, yaw = angle(att.roll, "roll"), angle(att.pitch, "pitch"), angle(att.yaw, "yaw")

    rates = sensors.rates
    omega = np.zeros((n, 3))
    for j, (name, sign) in enumerate(zip((rates.p, rates.q, rates.r), rates.signs, strict=True)):
        if name is not None:
            omega[:, j] = sign * _column(synced, name, f"sensors.rates.{'pqr'[j]}")

    source = sensors.linear_velocity()
    if source.differentiated and not all(c in synced.columns for c in source.velocity_columns):
        raise SchemaError(f"{source.key}: the positions' rates {list(source.velocity_columns)} are not in the table; "
                          "positions are differentiated first "
                          "(pipeline.estimation.differentiate.differentiate does it)",
                          field=source.velocity_columns[0])
    v_sensor = np.stack([_column(synced, s, f"{source.key}.velocity") for s in source.velocity_columns], axis=1)
    v_ref = velocity_to_body(v_sensor, source, roll, pitch, unwrap_finite(yaw), omega)

    for j, name in enumerate(VELOCITY[:3]):
        out[name] = v_ref[:, j]
    for j, name in enumerate(VELOCITY[3:]):
        out[name] = omega[:, j]
    out["roll_rad"], out["pitch_rad"], out["yaw_rad"] = roll, pitch, unwrap_finite(yaw)
    if sensors.depth is not None:
        out["depth_m"] = _column(synced, sensors.depth, "sensors.depth")
    for thr in vehicle.thrusters:
        out[thr.input_signal] = _column(synced, thr.input_signal, f"thrusters[{thr.name}].{thr.input_kind}_signal")
    for surface in vehicle.control_surfaces:
        out[surface.angle_signal] = _column(synced, surface.angle_signal,
                                            f"control_surfaces[{surface.name}].angle_signal")
    return pd.DataFrame(out)


def mounting_matrix(source: LinearVelocity) -> np.ndarray:
    """The constant rotation (3, 3) of a body-frame source into body FRD axes: the mounting R (``rotation_rpy_deg``,
    ZYX; a DVL's), times the axes map F = diag(1, -1, -1) for ROS FLU axes (``axes: flu``, an Odometry twist)."""
    R = rpy_matrix(*np.deg2rad(source.rotation_rpy_deg))
    if source.axes == "flu":
        return R @ _FRD_TO_FLU  # F is its own inverse: FLU -> FRD
    if source.axes != "frd":
        raise ValueError(f"unknown body axes {source.axes!r}; expected frd or flu")
    return R


def sensor_to_body(source: LinearVelocity, roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Per sample (n, 3, 3), the rotation taking the velocity sensor's vector (each signal in its axis, the axes
    not given 0: :func:`sensor_vector`) into body FRD axes.

    - ``body`` (a DVL or body-frame velocities): the constant mounting rotation R (``rotation_rpy_deg``, ZYX).
    - ``earth``: R_nb^T A, with R_nb = Rz(yaw) Ry(pitch) Rx(roll) the body attitude w.r.t. NED and A the earth
      axes' map to NED (identity, or ENU -> NED). An earth source without all three axes (planar x, y; a depth's
      z) is rotated by the heading alone, R_nb = Rz(yaw): the axes it does not measure are not known to be 0, so
      roll and pitch must not mix them in.
    """
    n = np.shape(yaw)[0]
    if source.frame == "body":
        return np.broadcast_to(mounting_matrix(source), (n, 3, 3))
    if source.frame != "earth":
        raise ValueError(f"unknown velocity frame {source.frame!r}; expected body or earth")
    given = _given(source)
    zeros = np.zeros(n)
    R_nb = rpy_matrix(roll, pitch, yaw) if given.all() else rpy_matrix(zeros, zeros, yaw)
    A = _ENU_TO_NED if source.earth_axes == "enu" else np.eye(3)
    return np.swapaxes(R_nb, 1, 2) @ A @ np.diag(given.astype(float))


def _given(source: LinearVelocity) -> np.ndarray:
    """(3,) bool: which of the sensor's axes x, y, z its signals give."""
    return np.array([a in source.axes_given for a in "xyz"])


def sensor_vector(v_sensor: np.ndarray, source: LinearVelocity) -> np.ndarray:
    """The sensor's signals (n, k, in signal order) as 3-vectors (n, 3): each in its axis, the others 0."""
    v = np.asarray(v_sensor, dtype=float)
    out = np.zeros((v.shape[0], 3))
    for j, axis in enumerate(source.axes_given):
        out[:, "xyz".index(axis)] = v[:, j]
    return out


def velocity_to_body(v_sensor: np.ndarray, source: LinearVelocity, roll: np.ndarray, pitch: np.ndarray,
                     yaw: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Body velocity (n, 3) of the reference point from the velocity sensor's signals (n, 1 to 3):
    v_ref = S v_sensor - omega x r (S: :func:`sensor_to_body`, r: the sensor's position). The DOFs the source does
    not measure (w of a planar source; u, v of a depth) are 0 (as an unconfigured rate), not the lever-arm term."""
    v = sensor_vector(v_sensor, source)
    r = np.asarray(source.position_m, dtype=float)
    if source.frame == "body":  # one constant rotation (the DVL's mounting): the plain product
        v_ref = v @ mounting_matrix(source).T - np.cross(omega, r)
    else:
        v_ref = np.einsum("nij,nj->ni", sensor_to_body(source, roll, pitch, yaw), v) - np.cross(omega, r)
    for j, dof in enumerate("uvw"):
        if dof not in source.dofs:
            v_ref[:, j] = 0.0
    return v_ref
