"""IMU accelerometers as measurements of the body accelerations, for the kalman method's second pass.

An accelerometer at body position r measures the specific force f = a_r - g_b: a_r the inertial acceleration of
its own point in body axes, g_b = R^T (0, 0, g) gravity in body axes (FRD; at rest and level it reads
(0, 0, -g)). With nu_lin the body velocity of the reference point and omega the body rates,

    a_r = nu_lin_dot + omega x nu_lin + omega_dot x r + omega x (omega x r),

so the reference point's acceleration, what the smoother's velocity DOFs differentiate, is

    nu_lin_dot = f + g_b - omega x nu_lin - omega_dot x r - omega x (omega x r)      (:func:`reference_acceleration`)

with roll and pitch from the AHRS (the synced grid, at each sample's stamp) and omega, omega_dot, nu_lin from a
first smoother pass without accelerometers. Each sample becomes a measurement of x' (``order`` 1) of u, v (and
w, where the velocity source measures it), with variance: the accelerometer axis's noise (params
``noise_sd.<signal>`` or estimated from the data) plus the first pass's uncertainty propagated through the
omega x nu_lin and omega_dot x r terms.

Bias: accelerometers carry a constant offset (0.01-0.05 m/s^2 for a MEMS IMU), and a roll or pitch offset of the
AHRS adds g times it. Per DOF, the median over the trial of (accelerometer-derived acceleration - the first
pass's acceleration) at the samples where the first pass's velocity is within ``max_velocity_sd_mps`` is taken
as a constant bias, subtracted, and reported. The first pass's acceleration is noisy but unbiased, so the
median over a trial of hundreds of seconds finds the bias to a few mm/s^2.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from pipeline.config.params import DifferentiateParams
from pipeline.config.vehicle import AccelerometerSource, Vehicle
from pipeline.errors import SyncError
from pipeline.estimation.measurements import interp_finite, native_stream, signal_noise
from pipeline.estimation.noise import NoiseEstimate, estimate_noise
from pipeline.estimation.smoother import Measurements, Smoothed, smooth

log = logging.getLogger(__name__)

__all__ = ["accelerometer_measurements", "gravity_body", "reference_acceleration", "specific_force_frd"]

_FLU_TO_FRD = np.array([1.0, -1.0, -1.0])


def gravity_body(roll_rad: np.ndarray, pitch_rad: np.ndarray, g_mps2: float) -> np.ndarray:
    """Gravity (n, 3) in body FRD axes, R^T (0, 0, g) for the NED earth frame (independent of yaw)."""
    roll, pitch = np.asarray(roll_rad, dtype=float), np.asarray(pitch_rad, dtype=float)
    return g_mps2 * np.stack([-np.sin(pitch), np.cos(pitch) * np.sin(roll), np.cos(pitch) * np.cos(roll)], axis=1)


def specific_force_frd(f: np.ndarray, source: AccelerometerSource) -> np.ndarray:
    """The accelerometer's samples (n, 3) in body FRD axes."""
    f = np.asarray(f, dtype=float)
    return f * _FLU_TO_FRD if source.axes == "flu" else f


def reference_acceleration(f_frd: np.ndarray, position_m: np.ndarray, roll_rad: np.ndarray, pitch_rad: np.ndarray,
                           omega: np.ndarray, omega_dot: np.ndarray, nu_lin: np.ndarray, g_mps2: float) -> np.ndarray:
    """nu_lin_dot (n, 3) of the reference point from the specific force ``f_frd`` (n, 3, m/s^2) measured at
    ``position_m``: f + g_b - omega x nu_lin - omega_dot x r - omega x (omega x r) (see the module docstring)."""
    r = np.broadcast_to(np.asarray(position_m, dtype=float), np.shape(f_frd))
    return (f_frd + gravity_body(roll_rad, pitch_rad, g_mps2) - np.cross(omega, nu_lin)
            - np.cross(omega_dot, r) - np.cross(omega, np.cross(omega, r)))


def _cross_variance(a: np.ndarray, var_a: np.ndarray, b: np.ndarray, var_b: np.ndarray) -> np.ndarray:
    """First-order variance of a x b for independent components: (a_j^2 var b_k + b_k^2 var a_j) summed."""
    out = np.zeros_like(a)
    for i, (j, k) in enumerate(((1, 2), (2, 0), (0, 1))):
        out[:, i] = (a[:, j] ** 2 * var_b[:, k] + b[:, k] ** 2 * var_a[:, j]
                     + a[:, k] ** 2 * var_b[:, j] + b[:, j] ** 2 * var_a[:, k])
    return out


def _smoothed_angle(grid_ns: np.ndarray, angle_rad: np.ndarray) -> np.ndarray:
    """Roll or pitch on the grid through the white-jerk smoother (noise estimated, process noise by maximum
    likelihood): the AHRS's angle noise, times g, would otherwise be the largest error of the accelerations."""
    ok = np.isfinite(angle_rad)
    est = estimate_noise(grid_ns[ok] / 1e9, angle_rad[ok])
    if not np.isfinite(est.sd) or est.sd <= 0 or ok.sum() < 3:
        return angle_rad
    return smooth(grid_ns, Measurements(grid_ns[ok], angle_rad[ok], est.sd**2)).x


def accelerometer_measurements(synced: pd.DataFrame, body: pd.DataFrame,
                               streams: Mapping[str, pd.DataFrame | pa.Table] | None, vehicle: Vehicle,
                               params: DifferentiateParams, first: Mapping[str, Smoothed],
                               noise: dict[str, NoiseEstimate]) -> tuple[dict[str, Measurements], dict[str, Any]]:
    """Measurements of u_dot, v_dot (w_dot) per velocity DOF the first pass ``first`` smoothed (its variances
    filled), bias removed; and the report (bias per DOF, samples). Noise per signal goes into ``noise``."""
    acc = vehicle.sensors.accelerometer
    assert acc is not None
    native = native_stream(streams, acc.signals[0])
    if native is not None and all(s in native[1] for s in acc.signals):
        t, cols = native
        f = np.stack([cols[s] for s in acc.signals], axis=1)
    else:
        missing = [s for s in acc.signals if s not in synced.columns]
        if missing:
            raise SyncError(f"sensors.accelerometer: signals {missing} are in neither the streams nor the synced "
                            "table", field=missing[0])
        t = synced["t_ns"].to_numpy(dtype=np.int64)
        f = np.stack([synced[s].to_numpy(dtype=float) for s in acc.signals], axis=1)
    ok = np.all(np.isfinite(f), axis=1)
    t, f = t[ok], f[ok]
    for j, s in enumerate(acc.signals):
        noise[s] = signal_noise(s, t, f[:, j], params)
    sd = np.array([noise[s].sd for s in acc.signals])
    grid = body["t_ns"].to_numpy(dtype=np.int64)

    def at_stamps(values: np.ndarray) -> np.ndarray:
        return interp_finite(t, grid, values)

    def first_pass(dofs: str, what: str) -> np.ndarray:
        return np.stack([at_stamps(getattr(first[d], what)) if d in first else np.zeros(t.size) for d in dofs],
                        axis=1)

    omega, omega_dot, nu_lin = first_pass("pqr", "x"), first_pass("pqr", "xdot"), first_pass("uvw", "x")
    var_omega, var_omega_dot = first_pass("pqr", "x_sd") ** 2, first_pass("pqr", "xdot_sd") ** 2
    var_nu = first_pass("uvw", "x_sd") ** 2
    roll, pitch = (at_stamps(_smoothed_angle(grid, body[c].to_numpy(dtype=float))) for c in ("roll_rad", "pitch_rad"))
    position = np.asarray(acc.position_m, dtype=float)
    a = reference_acceleration(specific_force_frd(f, acc), position, roll, pitch, omega, omega_dot, nu_lin,
                               vehicle.rigid_body.gravity_mps2)
    r = np.broadcast_to(position, a.shape)
    # the errors left (attitude, the first pass's rates and velocities) change slowly, not from sample to sample:
    # the accelerometer counts as one measurement per grid step, its variance times the samples in a step
    per_step = max((grid[1] - grid[0]) / float(np.median(np.diff(t))), 1.0) if t.size > 1 else 1.0
    var = per_step * (sd**2)[None, :] + _cross_variance(omega, var_omega, nu_lin, var_nu) \
        + _cross_variance(omega_dot, var_omega_dot, r, np.zeros_like(r))

    out: dict[str, Measurements] = {}
    report: dict[str, Any] = {"signals": list(acc.signals), "position_m": list(acc.position_m), "axes": acc.axes,
                              "samples": int(t.size), "bias_mps2": {}}
    for j, dof in enumerate("uvw"):
        if dof not in first:
            continue
        ref = first_pass(dof, "xdot")[:, 0]
        sure = first_pass(dof, "x_sd")[:, 0] <= params.max_velocity_sd_mps
        if sure.sum() < 10:
            raise SyncError(f"sensors.accelerometer: too few samples ({int(sure.sum())}) where the first pass knows "
                            f"{dof} to estimate the accelerometer's bias", field=acc.signals[j])
        bias = float(np.median(a[sure, j] - ref[sure]))
        report["bias_mps2"][dof] = bias
        out[dof] = Measurements(t, a[:, j] - bias, var[:, j], order=1)
    log.info("accelerometer: %d samples, bias %s m/s^2", t.size,
             {d: round(b, 4) for d, b in report["bias_mps2"].items()})
    return out, report
