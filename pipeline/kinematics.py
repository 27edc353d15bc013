"""Frames, conventions and derivatives: from the synced table to body velocities and accelerations.

Two pure steps (the differentiate stage calls both):

1. :func:`body_kinematics` (synced table + vehicle config) -> ``t_ns``, ``segment``, measured body
   velocities at the reference point (``u_mps`` ... ``r_radps``), attitude ``roll_rad pitch_rad yaw_rad``
   of body FRD w.r.t. NED (yaw unwrapped), ``depth_m`` if configured, and every actuator signal (each
   thruster's speed, PWM or thrust; each control surface's angle: :meth:`Vehicle.actuator_signals`).

   - **Attitude** from a quaternion in the configured convention: ``frd_ned`` is body FRD -> NED (marine);
     ``flu_enu`` (ROS) is body FLU -> ENU and is converted explicitly, R_ned_frd = T R_enu_flu F with
     T = [[0,1,0],[1,0,0],[0,0,-1]] (ENU -> NED) and F = diag(1,-1,-1) (FRD -> FLU). Roll/pitch/yaw are
     the ZYX Euler angles of R_ned_frd. Or from roll/pitch/yaw signals, taken as FRD/NED angles as they are.
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
     (:mod:`pipeline.estimation.position`), their rates then rotated as earth-frame velocities.

2. :func:`differentiate` (that table + DifferentiateParams) -> adds ``u_smooth_mps`` ... and
   ``udot_mps2`` ... ``rdot_radps2``, per segment, and drops the samples near each segment's edges.

   - ``gaussian``: :func:`gaussian_derivative` = ``scipy.ndimage.gaussian_filter1d(order=1)`` divided by
     ``dt_s`` and by the second moment of the truncated, sampled kernel (so it is exact for polynomials up
     to degree 2 wherever the kernel lies inside the segment; scipy's raw kernel is ~3 % low at a 3-sigma
     truncation). The kernel is truncated at ``edge_sigmas`` sigma (4 when ``edge_sigmas`` < 1) and exactly
     the samples whose kernel would reach past a segment edge are dropped: ``round(edge_sigmas*sigma/dt)``
     on each side. Nothing is extrapolated across a gap: each segment is filtered alone.
     ``gaussian_degree=4`` uses :func:`local_cubic_weights` instead: a Gaussian-weighted local cubic whose
     derivative is exact to degree 4, cancelling the plain kernel's bias sigma^2/2 x'''. That bias is not
     harmless: with quadratic damping, x''' holds a term in sign(u) u_dot^2, so the damping target of the plain
     kernel steps by ~0.5 N across u = 0 on the simulator (0.25 s). At sigma 0.35 s the corrected kernel is also
     quieter than the plain one at 0.25 s (acceleration error std 0.0081 against 0.0089 m/s^2, 4 Hz DVL). It is
     not the default: with it, the coupled acceptance ranking changes (``docs/models.md``).
   - ``savgol``: ``scipy.signal.savgol_filter(deriv=1, delta=dt_s)`` with an odd window of about
     ``savgol_window_s``; half a window is dropped at each edge.
   - Smoothed velocities use the same filter with derivative order 0.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pandas as pd
from scipy.ndimage import correlate1d, gaussian_filter1d
from scipy.signal import savgol_filter

from pipeline.config.params import DifferentiateParams
from pipeline.config.vehicle import LinearVelocity, Vehicle
from pipeline.errors import SchemaError, SyncError
from pipeline.sync import quat_columns

log = logging.getLogger(__name__)

DOFS = ("u", "v", "w", "p", "q", "r")
VEL_UNIT = {"u": "mps", "v": "mps", "w": "mps", "p": "radps", "q": "radps", "r": "radps"}
ACC_UNIT = {"u": "mps2", "v": "mps2", "w": "mps2", "p": "radps2", "q": "radps2", "r": "radps2"}
VELOCITY = [f"{d}_{VEL_UNIT[d]}" for d in DOFS]
SMOOTH = [f"{d}_smooth_{VEL_UNIT[d]}" for d in DOFS]
ACCELERATION = [f"{d}dot_{ACC_UNIT[d]}" for d in DOFS]
ATTITUDE = ["roll_rad", "pitch_rad", "yaw_rad"]

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
    if att.quaternion is not None:
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
                          "positions are differentiated first (pipeline.kinematics.kinematics_report does it)",
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
    """Per sample (n, 3, 3), the rotation taking the velocity sensor's vector (padded with 0 to three components
    when planar) into body FRD axes.

    - ``body`` (a DVL or body-frame velocities): the constant mounting rotation R (``rotation_rpy_deg``, ZYX).
    - ``earth``: R_nb^T A, with R_nb = Rz(yaw) Ry(pitch) Rx(roll) the body attitude w.r.t. NED and A the earth
      axes' map to NED (identity, or ENU -> NED). A planar (two-signal) earth source is rotated by the heading
      alone, R_nb = Rz(yaw): its vertical velocity is not measured, so roll and pitch must not mix it in.
    """
    n = np.shape(yaw)[0]
    if source.frame == "body":
        return np.broadcast_to(mounting_matrix(source), (n, 3, 3))
    if source.frame != "earth":
        raise ValueError(f"unknown velocity frame {source.frame!r}; expected body or earth")
    planar = len(source.velocity) == 2
    zeros = np.zeros(n)
    R_nb = rpy_matrix(zeros, zeros, yaw) if planar else rpy_matrix(roll, pitch, yaw)
    A = _ENU_TO_NED if source.earth_axes == "enu" else np.eye(3)
    if planar and source.earth_axes == "enu":
        A = _ENU_TO_NED @ np.diag([1.0, 1.0, 0.0])  # x east, y north -> north, east; no vertical component
    return np.swapaxes(R_nb, 1, 2) @ A


def velocity_to_body(v_sensor: np.ndarray, source: LinearVelocity, roll: np.ndarray, pitch: np.ndarray,
                     yaw: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Body velocity (n, 3) of the reference point from the velocity sensor's signals (n, 2 or 3):
    v_ref = S v_sensor - omega x r (S: :func:`sensor_to_body`, r: the sensor's position). A planar source measures
    no w: its w column is 0 (as an unconfigured rate), not the vertical part of the lever-arm term."""
    v = np.asarray(v_sensor, dtype=float)
    if v.shape[1] == 2:
        v = np.column_stack([v, np.zeros(len(v))])
    r = np.asarray(source.position_m, dtype=float)
    if source.frame == "body":  # one constant rotation (the DVL's mounting): the plain product
        v_ref = v @ mounting_matrix(source).T - np.cross(omega, r)
    else:
        v_ref = np.einsum("nij,nj->ni", sensor_to_body(source, roll, pitch, yaw), v) - np.cross(omega, r)
    if len(source.velocity) == 2:
        v_ref[:, 2] = 0.0
    return v_ref


def gaussian_truncate(edge_sigmas: float) -> float:
    """Kernel truncation in sigmas: ``edge_sigmas`` (so kept samples never see a segment edge), 4 below 1."""
    return edge_sigmas if edge_sigmas >= 1.0 else 4.0


def gaussian_derivative(x: np.ndarray, dt_s: float, sigma_s: float, truncate: float = 4.0) -> np.ndarray:
    """Gaussian-smoothed first derivative of uniformly sampled ``x`` (along axis 0), in units of x per second.

    ``gaussian_filter1d(order=1)`` gives a derivative per sample, with a kernel -k phi(k)/sigma^2 whose
    discrete second moment is slightly below 1 once sampled and truncated; dividing by that moment and by
    ``dt_s`` makes the result exact for polynomials of degree <= 2 where the kernel lies inside the data.
    Edges use reflection (biased: trim them).
    """
    sd = sigma_s / dt_s
    radius = int(truncate * sd + 0.5)
    k = np.arange(-radius, radius + 1, dtype=float)
    phi = np.exp(-0.5 * (k / sd) ** 2)
    phi /= phi.sum()
    moment = float(np.sum(k * k * phi)) / sd**2
    raw = gaussian_filter1d(np.asarray(x, dtype=float), sd, axis=0, order=1, mode="reflect", truncate=truncate)
    return raw / (moment * dt_s)


def gaussian_smooth(x: np.ndarray, dt_s: float, sigma_s: float, truncate: float = 4.0) -> np.ndarray:
    return gaussian_filter1d(np.asarray(x, dtype=float), sigma_s / dt_s, axis=0, mode="reflect", truncate=truncate)


def local_cubic_weights(dt_s: float, sigma_s: float, truncate: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """``(smooth, derivative)`` weights of a Gaussian-weighted least-squares cubic, centred, sampled and truncated.

    ``smooth = (a + b k^2) phi(k)`` with ``sum smooth = 1`` and ``sum smooth k^2 = 0``; ``derivative = (c k + e k^3)
    phi(k) / dt`` with ``sum derivative k = 1/dt`` and ``sum derivative k^3 = 0``. By symmetry the smoothing is exact
    for polynomials of degree <= 3 and the derivative for degree <= 4, so the plain Gaussian's O(sigma^2) bias,
    sigma^2/2 times x'' (smoothing) or x''' (derivative), cancels; the price is more noise at the same sigma.
    """
    sd = sigma_s / dt_s
    radius = int(truncate * sd + 0.5)
    k = np.arange(-radius, radius + 1, dtype=float)
    phi = np.exp(-0.5 * (k / sd) ** 2)
    mom = {j: float(np.sum(k**j * phi)) for j in (0, 2, 4, 6)}
    a, b = np.linalg.solve([[mom[0], mom[2]], [mom[2], mom[4]]], [1.0, 0.0])
    c, e = np.linalg.solve([[mom[2], mom[4]], [mom[4], mom[6]]], [1.0, 0.0])
    return (a + b * k**2) * phi, (c * k + e * k**3) * phi / dt_s


def apply_weights(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Centred correlation with ``weights`` along axis 0 (edges reflected, as the Gaussian filters: trim them)."""
    return correlate1d(np.asarray(x, dtype=float), weights, axis=0, mode="reflect")


def gaussian_filters(x: np.ndarray, dt_s: float, sigma_s: float, degree: int = 4, truncate: float = 4.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """``(smoothed, derivative)`` of uniformly sampled ``x`` along axis 0: the plain Gaussian kernels
    (``degree=2``: :func:`gaussian_smooth`, :func:`gaussian_derivative`) or the bias-corrected ones (``degree=4``:
    :func:`local_cubic_weights`). Edges are reflected: trim them."""
    if degree == 2:
        return gaussian_smooth(x, dt_s, sigma_s, truncate), gaussian_derivative(x, dt_s, sigma_s, truncate)
    if degree != 4:
        raise ValueError(f"gaussian_degree {degree}: expected 2 or 4")
    w_smooth, w_deriv = local_cubic_weights(dt_s, sigma_s, truncate)
    return apply_weights(x, w_smooth), apply_weights(x, w_deriv)


def edge_samples(params: DifferentiateParams, dt_s: float, sigma_s: float | None = None,
                 window: int | None = None) -> int:
    """Samples dropped at each end of a segment (for one width: ``sigma_s`` / ``window`` when ``auto``)."""
    if params.method == "gaussian":
        sigma = params.sigma_s if sigma_s is None else sigma_s
        return int(gaussian_truncate(params.edge_sigmas) * sigma / dt_s + 0.5) if params.edge_sigmas else 0
    return (savgol_window(params, dt_s) if window is None else window) // 2


def savgol_window(params: DifferentiateParams, dt_s: float, window_s: float | None = None) -> int:
    width = params.savgol_window_s if window_s is None else window_s
    window = max(int(round(width / dt_s)), params.savgol_order + 1)
    return window if window % 2 == 1 else window + 1


def grid_step_s(t_ns: np.ndarray, segment: np.ndarray) -> float:
    """The uniform sample interval (s) within segments; SchemaError if it is not uniform."""
    same = segment[1:] == segment[:-1]
    steps = np.diff(t_ns)[same & (segment[1:] >= 0)]
    if steps.size == 0:
        raise SyncError("no segment with two or more samples to differentiate")
    if steps.min() != steps.max():
        raise SchemaError(f"grid is not uniform within segments: steps {steps.min()}..{steps.max()} ns",
                          field="t_ns")
    return float(steps[0]) / 1e9


def _widths(params: DifferentiateParams, widths: dict[str, float] | None) -> dict[str, float]:
    """Per velocity column, the Gaussian sigma (s) or the Savitzky-Golay window (s)."""
    fixed = params.sigma_s if params.method == "gaussian" else params.savgol_window_s
    out = {}
    for col in VELOCITY:
        if params.method == "gaussian" and col in params.sigma_s_per_signal:
            out[col] = float(params.sigma_s_per_signal[col])
        elif widths is not None and col in widths:
            out[col] = float(widths[col])
        elif fixed == "auto":
            raise SchemaError(f"{params.method}: width 'auto' needs the widths chosen from the data "
                              f"(pipeline.kinematics.kinematics does it); none given for {col!r}", field=col)
        else:
            out[col] = float(fixed)
    return out


def differentiate(table: pd.DataFrame, params: DifferentiateParams, widths: dict[str, float] | None = None
                  ) -> pd.DataFrame:
    """Smoothed velocities and accelerations per segment; edge samples dropped; other columns passed through.

    ``widths``: per velocity column, the Gaussian sigma or Savitzky-Golay window in seconds (``auto``: from
    :func:`auto_widths`); a segment loses the edge samples of its widest filter.
    """
    if params.method not in ("gaussian", "savgol"):
        raise ValueError(f"differentiate() filters the grid (gaussian, savgol); {params.method!r} is "
                         "pipeline.estimation.estimate_motion")
    missing = [c for c in ("t_ns", "segment", *VELOCITY) if c not in table.columns]
    if missing:
        raise SchemaError(f"columns {missing} missing from the kinematics input", field=missing[0])
    seg = table["segment"].to_numpy(dtype=np.int32)
    t = table["t_ns"].to_numpy(dtype=np.int64)
    dt_s = grid_step_s(t, seg)
    width = _widths(params, widths)
    truncate = gaussian_truncate(params.edge_sigmas)
    if params.method == "gaussian":
        edge = max(edge_samples(params, dt_s, sigma_s=w) for w in width.values())
        window = {}
    else:
        window = {c: savgol_window(params, dt_s, w) for c, w in width.items()}
        edge = max(window.values()) // 2
    parts = []
    for sid in np.unique(seg[seg >= 0]):
        rows = np.flatnonzero(seg == sid)
        if len(rows) <= 2 * edge or (params.method == "savgol" and len(rows) < max(window.values())):
            log.info("segment %d: %d samples, too short for %d edge samples each side; dropped", sid, len(rows), edge)
            continue
        part = table.iloc[rows].reset_index(drop=True)
        for j, col in enumerate(VELOCITY):
            nu = part[col].to_numpy(dtype=float)
            if params.method == "gaussian":
                smooth, acc = gaussian_filters(nu, dt_s, width[col], params.gaussian_degree, truncate)
            else:
                smooth = savgol_filter(nu, window[col], params.savgol_order, mode="interp")
                acc = savgol_filter(nu, window[col], params.savgol_order, deriv=1, delta=dt_s, mode="interp")
            part[SMOOTH[j]] = smooth
            part[ACCELERATION[j]] = acc
        parts.append(part.iloc[edge: len(part) - edge])
    if not parts:
        raise SyncError(f"no segment longer than {2 * edge} samples ({2 * edge * dt_s:g} s) to differentiate")
    out = pd.concat(parts, ignore_index=True)
    first = ["t_ns", "segment", *VELOCITY, *SMOOTH, *ACCELERATION]
    return out[first + [c for c in out.columns if c not in first]]


def auto_widths(body: pd.DataFrame, synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams,
                streams=None) -> tuple[dict[str, float], dict[str, Any]]:
    """Per velocity column, the width of least estimated mean-square derivative error
    (:func:`pipeline.estimation.widths.optimal_sigma`; for Savitzky-Golay, the window of equal noise gain,
    8 sigma), from each sensor's noise and rate at its native stamps; and the noise estimates used."""
    from pipeline.estimation.motion import sensor_noise
    from pipeline.estimation.widths import optimal_sigma

    seg = body["segment"].to_numpy()
    dt_s = grid_step_s(body["t_ns"].to_numpy(dtype=np.int64), seg)
    per_dof, noise = sensor_noise(synced, body, vehicle, params, streams)
    widths: dict[str, float] = {}
    for col, dof in zip(VELOCITY, DOFS, strict=True):
        if dof not in per_dof:
            widths[col] = 0.05 if params.method == "gaussian" else 8 * 0.05
            continue
        sd, native_dt = per_dof[dof]
        x = body[col].to_numpy(dtype=float)
        pieces = [x[seg == sid] for sid in np.unique(seg[seg >= 0])]
        sigma = optimal_sigma(pieces, dt_s, sd, native_dt)
        widths[col] = sigma if params.method == "gaussian" else 8.0 * sigma
    report = {"method": params.method, "widths_s": widths,
              "noise": {name: est.as_dict() for name, est in sorted(noise.items())}}
    return widths, report


def kinematics_report(synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams, streams=None
                      ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The kinematics table of the contract and the stage's report (noise per signal, widths or smoother)."""
    if params.method == "kalman":
        from pipeline.estimation.motion import estimate_motion

        return estimate_motion(synced, vehicle, params, streams)
    auto = (params.sigma_s if params.method == "gaussian" else params.savgol_window_s) == "auto"
    source = vehicle.sensors.linear_velocity()
    if source.differentiated:  # positions: earth velocities from the white-jerk smoother, then as any source
        from pipeline.estimation.position import smooth_positions, with_position_rates

        if auto:
            raise SchemaError(f"{params.method}: width 'auto' is not available for {source.key} (the positions "
                              "are differentiated by the smoother first); give the width, or method: kalman",
                              field="sigma_s")
        synced = with_position_rates(synced, source, smooth_positions(synced, source, params, streams, {}))
    body = body_kinematics(synced, vehicle)
    widths, report = auto_widths(body, synced, vehicle, params, streams) if auto else (None, {
        "method": params.method, "widths_s": _widths(params, None), "noise": {}})
    out = differentiate(body, params, widths)
    report.update(grid_samples=len(synced), usable_samples=len(out), usable_fraction=len(out) / max(len(synced), 1),
                  synced_segment_fraction=float(np.mean(synced["segment"].to_numpy() >= 0)))
    return out, report


def kinematics(synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams, streams=None) -> pd.DataFrame:
    """The kinematics table of the contract from a synced table (and, for the smoother and ``auto`` widths,
    the trial's native streams)."""
    return kinematics_report(synced, vehicle, params, streams)[0]


__all__ = ["ACCELERATION", "ATTITUDE", "SMOOTH", "VELOCITY", "attitude_from_quaternion", "body_kinematics",
           "sensor_to_body", "velocity_to_body",
           "differentiate", "gaussian_derivative", "kinematics_report", "auto_widths",
           "gaussian_filters", "kinematics", "local_cubic_weights"]
