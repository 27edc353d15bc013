"""Measurements at their own stamps, shared by every estimator of the differentiate stage.

- :func:`native_stream`: the trial's native stream that carries a signal (stamps sorted), or None;
- :func:`signal_noise`: a signal's noise, from params (``noise_sd``) or estimated (:mod:`pipeline.estimation.noise`);
- :func:`interp_finite`: a grid column at other stamps, over its finite values;
- :func:`velocity_measurements`, :func:`rate_measurements`: the velocity sensor's and the rate sensors' samples
  as smoother measurements in body axes at the reference point, each with its variance;
- :func:`sensor_noise`: per measured DOF, the noise in body axes and the native sample interval (for ``auto``
  filter widths).

Without native streams (a table built in memory), the synced grid's valid samples stand in.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np
import pandas as pd
import pyarrow as pa

from pipeline.config.params import DifferentiateParams
from pipeline.config.vehicle import Vehicle
from pipeline.errors import SchemaError, SyncError
from pipeline.estimation.noise import NoiseEstimate, estimate_noise
from pipeline.estimation.smoother import Measurements
from pipeline.kinematics import mounting_matrix, sensor_to_body, velocity_to_body

__all__ = ["interp_finite", "native_stream", "rate_measurements", "sensor_noise", "signal_noise",
           "velocity_measurements"]

log = logging.getLogger(__name__)


def native_stream(streams: Mapping[str, pd.DataFrame | pa.Table] | None, signal: str
                  ) -> tuple[np.ndarray, dict[str, np.ndarray]] | None:
    """(t_ns sorted, all columns) of the stream carrying ``signal``, or None."""
    if not streams:
        return None
    for name in sorted(streams):
        table = streams[name]
        cols = table.column_names if isinstance(table, pa.Table) else list(table.columns)
        if signal in cols:
            arrays = {c: (table.column(c).to_numpy() if isinstance(table, pa.Table) else table[c].to_numpy())
                      for c in cols}
            t = np.asarray(arrays.pop("t_ns"), dtype=np.int64)
            order = np.argsort(t, kind="stable")
            return t[order], {c: np.asarray(v, dtype=float)[order] for c, v in arrays.items()}
    return None


def signal_noise(signal: str, t_ns: np.ndarray, x: np.ndarray, params: DifferentiateParams) -> NoiseEstimate:
    """The signal's noise: ``noise_sd`` in params, or estimated from its samples; SyncError if it cannot be."""
    if signal in params.noise_sd:
        return NoiseEstimate(float(params.noise_sd[signal]), float("nan"), 0, "config")
    est = estimate_noise(t_ns / 1e9, x, gate=params.gate_sigmas)
    if not np.isfinite(est.sd) or est.sd <= 0:
        raise SyncError(f"cannot estimate the noise of signal {signal!r} ({est.samples} usable residuals); give "
                        f"it in params: differentiate.noise_sd.{signal}", field=signal)
    if est.source == "floor":  # simulated data, or a sensor stuck at one value
        log.warning("signal %r looks noise-free (constant or simulated without noise): its noise SD is set to the "
                    "floor %.3g; give differentiate.noise_sd.%s if you know it", signal, est.sd, signal)
    return est


def interp_finite(t_ns: np.ndarray, grid_ns: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` on ``grid_ns`` interpolated at ``t_ns`` over its finite samples (zeros if none is finite)."""
    ok = np.isfinite(values)
    if not ok.any():
        return np.zeros(t_ns.size)
    return np.interp(t_ns.astype(float), grid_ns[ok].astype(float), values[ok])


def velocity_measurements(synced: pd.DataFrame, body: pd.DataFrame, streams, vehicle: Vehicle,
                          params: DifferentiateParams, noise: dict[str, NoiseEstimate]) -> dict[str, Measurements]:
    """The linear-velocity sensor's samples at their own stamps, in body axes at the reference point: one
    measurement of each DOF it measures (u, v; and w unless planar), with its variance per sample."""
    source = vehicle.sensors.linear_velocity()
    if source.differentiated:
        raise SchemaError(f"{source.key}: positions have no velocity measurements of their own (they are "
                          "differentiated by pipeline.estimation.position); a width 'auto' needs them",
                          field=source.key)
    native = native_stream(streams, source.velocity[0])
    if native is not None and all(s in native[1] for s in source.velocity):
        t, cols = native
        v = np.stack([cols[s] for s in source.velocity], axis=1)
        ok = np.all(np.isfinite(v), axis=1)
        if source.valid is not None and source.valid in cols:
            ok &= np.nan_to_num(cols[source.valid], nan=0.0) != 0
        if source.zero_is_invalid:
            ok &= ~np.all(v == 0.0, axis=1)
    else:  # no native stream: the synced grid's valid samples
        t = synced["t_ns"].to_numpy(dtype=np.int64)
        v = np.stack([synced[s].to_numpy(dtype=float) for s in source.velocity], axis=1)
        ok = np.all(np.isfinite(v), axis=1)
    k = len(source.velocity)
    sd = np.zeros(3)
    for j, s in enumerate(source.velocity):
        noise[s] = signal_noise(s, t[ok], v[ok, j], params)
        sd[j] = noise[s].sd
    t, v = t[ok], v[ok]
    grid = body["t_ns"].to_numpy(dtype=np.int64)

    def at_stamps(column: str) -> np.ndarray:
        return interp_finite(t, grid, body[column].to_numpy(dtype=float))

    omega = np.stack([at_stamps(f"{d}_radps") for d in "pqr"], axis=1)
    if source.frame == "earth":  # the attitude at each sample's own stamp (yaw is unwrapped on the grid)
        roll, pitch, yaw = at_stamps("roll_rad"), at_stamps("pitch_rad"), at_stamps("yaw_rad")
    else:
        roll = pitch = yaw = np.zeros(t.size)
    v_ref = velocity_to_body(v, source, roll, pitch, yaw, omega)
    if source.frame == "body":
        R = mounting_matrix(source)
        var = (R**2) @ (sd**2)  # constant: one value per DOF, as the DVL always had
        return {d: Measurements(t, v_ref[:, j], var[j]) for j, d in enumerate(source.dofs)}
    var_n = (sensor_to_body(source, roll, pitch, yaw) ** 2) @ (sd**2)  # per sample: the rotation changes
    return {d: Measurements(t, v_ref[:, j], var_n[:, j]) for j, d in enumerate(source.dofs[:k])}


def rate_measurements(synced: pd.DataFrame, streams, vehicle: Vehicle, params: DifferentiateParams,
                      noise: dict[str, NoiseEstimate]) -> dict[str, Measurements]:
    """Each configured rate signal (p, q, r) at its own stamps, times its sign, with its noise variance."""
    rates = vehicle.sensors.rates
    out: dict[str, Measurements] = {}
    for dof, name, sign in zip("pqr", (rates.p, rates.q, rates.r), rates.signs, strict=True):
        if name is None:
            continue
        native = native_stream(streams, name)
        if native is not None:
            t, x = native[0], native[1][name]
        else:
            t, x = synced["t_ns"].to_numpy(dtype=np.int64), synced[name].to_numpy(dtype=float)
        ok = np.isfinite(x)
        noise[name] = signal_noise(name, t[ok], x[ok], params)
        out[dof] = Measurements(t[ok], sign * x[ok], noise[name].sd ** 2)
    return out


def sensor_noise(synced: pd.DataFrame, body: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams,
                 streams: Mapping[str, pd.DataFrame | pa.Table] | None = None
                 ) -> tuple[dict[str, tuple[float, float]], dict[str, NoiseEstimate]]:
    """Per measured DOF, (noise SD in body axes, median native sample interval in s); and the noise per signal.
    ``body``: :func:`pipeline.kinematics.body_kinematics` of ``synced``."""
    noise: dict[str, NoiseEstimate] = {}
    meas = velocity_measurements(synced, body, streams, vehicle, params, noise)
    meas.update(rate_measurements(synced, streams, vehicle, params, noise))
    per_dof = {dof: (float(np.sqrt(np.median(m.var))), float(np.median(np.diff(m.t_ns))) / 1e9)
               for dof, m in meas.items() if m.t_ns.size > 1}
    return per_dof, noise
