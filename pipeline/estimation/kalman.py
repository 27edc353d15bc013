"""The ``kalman`` method of the differentiate stage: body velocities, accelerations and their SDs from every
velocity and rate sensor at its own stamps, each with its own noise.

:func:`estimate_motion` (synced table + native streams + vehicle + params) -> the kinematics table + a report.

- **Measurements.** The velocity sensor's samples at their own stamps (valid flag set; for a DVL, bottom lock and
  non-zero, as in sync), turned into the reference point's body velocity, v_ref = S v - omega x r with the rates
  interpolated to the sample (:func:`pipeline.kinematics.velocity_to_body`): S is a DVL's constant mounting
  rotation, or, for earth-frame velocities, the attitude at the sample's own stamp (interpolated from the grid),
  so the variance sum_j S_ij^2 sigma_j^2 varies per sample as the vehicle turns. One measurement of u, v (and w,
  unless the source is planar) each. Each configured rate signal (FOG, gyro) at its own stamps, times its sign.
  Without native streams (a table built in memory), the synced grid's valid samples stand in.
- **Rate biases** (``rate_bias: estimate``): per rate signal, a constant bias from the logged attitude
  (:mod:`pipeline.estimation.rate_bias`), subtracted from its samples; its variance is added to the smoothed
  rate's (a constant error shifts every sample), and the report's ``rate_bias`` gives each one with its SD.
- **Positions** (``sensors.position``): differentiated per earth axis by the same smoother, then rotated into
  body axes with their accelerations and SDs (:mod:`pipeline.estimation.position`); not smoothed again.
- **Accelerometers** (``sensors.accelerometer``, optional): a second pass adds, per velocity DOF, the IMU's
  specific force turned into the reference point's acceleration with the first pass's rates and velocities and
  the AHRS attitude, a constant bias per axis removed and reported (:mod:`pipeline.estimation.accelerometer`).
- **Noise.** Each signal's SD and outlier rate estimated from the data (:mod:`pipeline.estimation.noise`),
  unless ``noise_sd`` in params gives it.
- **Smoother.** Per DOF, :func:`pipeline.estimation.smoother.smooth`: white-jerk process, process noise by
  maximum likelihood (unless ``process_noise`` gives it), residual gating at ``gate_sigmas``.
- **Validity.** A grid sample is usable where every measured DOF's smoothed velocity SD is within
  ``max_velocity_sd_mps`` / ``max_rate_sd_radps`` and the other required signals (attitude, thruster speeds)
  are valid in the synced table. Segments are renumbered on that (``min_segment_s``), so a short loss of bottom
  lock no longer cuts a segment: the smoother bridges it and says how sure it is.
- **Columns.** ``u_mps`` ... ``r_radps`` and ``u_smooth_mps`` ... are the smoothed estimate (the models' inputs: a
  bridged sample has no measurement), ``udot_mps2`` ... its derivative, ``u_smooth_std_mps`` ... and
  ``udot_std_mps2`` ... their SDs, ``u_udot_cov_m2ps3`` ... the covariance of the two (0 where velocities come
  from positions), ``u_meas_mps`` ... the measured value on the grid as sync resampled it (NaN
  without bottom lock). DOFs without a sensor (rates not configured) are 0 with SD 0, as before.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa

from pipeline.config.params import DifferentiateParams
from pipeline.config.vehicle import Vehicle
from pipeline.errors import SchemaError, SyncError
from pipeline.estimation.accelerometer import accelerometer_measurements
from pipeline.estimation.clock_offset import MIN_STEP_FRACTION, estimate_actuator_offset, shift_columns, shifted
from pipeline.estimation.dvl_alignment import estimate_misalignment, turned, widen_for_misalignment
from pipeline.estimation.forced import excitation_report, force_model, smooth_passes, smooth_with_input
from pipeline.estimation.measurements import rate_measurements, velocity_measurements
from pipeline.estimation.noise import NoiseEstimate
from pipeline.estimation.position import body_motion_from_positions, smooth_positions, with_position_rates
from pipeline.estimation.rate_bias import debias, rate_biases
from pipeline.estimation.smoother import Measurements, Smoothed, smoothed_variances
from pipeline.kinematics import body_kinematics
from pipeline.sync import segments, valid_column
from pipeline.vocabulary import (
    ACCELERATION,
    DOFS,
    SMOOTH,
    VEL_UNIT,
    VELOCITY,
    accel_std_column,
    cov_column,
    meas_column,
    std_column,
)

log = logging.getLogger(__name__)

__all__ = ["estimate_motion"]


def _other_required_valid(synced: pd.DataFrame, vehicle: Vehicle) -> np.ndarray:
    """Grid samples where attitude (if configured) and every actuator signal are valid (the velocities are the
    smoother's)."""
    att = vehicle.sensors.attitude
    names = [] if att is None else [att.quaternion] if att.quaternion is not None else [
        s for s in (att.roll, att.pitch, att.yaw) if s]
    names += vehicle.actuator_signals()
    ok = np.ones(len(synced), dtype=bool)
    for name in names:
        col = valid_column(name)
        if col not in synced.columns:
            raise SchemaError(f"the synced table has no validity column {col!r}", field=col)
        ok &= synced[col].to_numpy(dtype=bool)
    return ok


def _process_noise_source(dof: str, res: Smoothed, key: str, params: DifferentiateParams) -> str:
    if np.isnan(res.q):  # from positions: each earth axis has its own
        return f"{key} (positions smoothed per earth axis)"
    return "config" if dof in params.process_noise else "maximum likelihood"


def _passes_report(passes: dict, results: dict[str, Smoothed]) -> dict[str, Any]:
    """The smoother's passes for the report: each pass's model and log-likelihood per DOF, and which one each DOF
    kept (0: the kinematic smoother)."""
    return {"force_model": passes["force_model"],
            "passes": passes["passes"],
            "passes_after_misalignment": passes.get("after_misalignment"),
            "passes_before_actuator_offset": passes.get("before_offset"),
            "chosen_pass": {dof: passes["chosen"][dof] for dof in results if dof in passes["chosen"]}}


def estimate_motion(synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams,
                    streams: Mapping[str, pd.DataFrame | pa.Table] | None = None
                    ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The kinematics table (rows in usable segments) and the estimation report; see the module docstring."""
    source = vehicle.sensors.linear_velocity()
    noise: dict[str, NoiseEstimate] = {}
    if source.differentiated:  # positions: earth velocity and acceleration per axis from the smoother
        positions = smooth_positions(synced, source, params, streams, noise)
        synced = with_position_rates(synced, source, positions)
    body = body_kinematics(synced, vehicle)
    for dof, col in zip(DOFS, VELOCITY, strict=True):
        body[meas_column(dof)] = body[col]
    grid = body["t_ns"].to_numpy(dtype=np.int64)
    steps = np.diff(grid)
    if grid.size < 3 or steps.min() != steps.max():
        raise SchemaError("the synced grid must be uniform with at least 3 samples", field="t_ns")
    h_s = float(steps[0]) / 1e9

    meas = {} if source.differentiated else velocity_measurements(synced, body, streams, vehicle, params, noise)
    rates = rate_measurements(synced, streams, vehicle, params, noise)
    estimate_biases = params.rate_bias == "estimate" and vehicle.sensors.attitude is not None  # from the attitude
    biases = rate_biases(synced, body, vehicle, rates) if estimate_biases else {}
    meas.update(debias(rates, biases))

    meas = {dof: meas[dof] for dof in DOFS if dof in meas}
    model = force_model(synced, body, vehicle) if params.model_passes and meas else None
    try:
        results, inputs, passes = smooth_passes(grid, meas, model, passes=params.model_passes,
                                                process_noise=params.process_noise, gate=params.gate_sigmas,
                                                dofs=DOFS)
    except ValueError as err:
        raise SyncError(f"cannot smooth {err}", field=str(err).split(":")[0]) from err
    offset = None
    if model is not None:
        offset = estimate_actuator_offset(grid, meas, results, inputs, passes["chosen"], model, DOFS).with_prior(
            params.actuator_offset_sd_s, min_s=MIN_STEP_FRACTION * h_s)
        if offset.applied:  # the thrust read that much later, the passes run again
            log.info("actuators: clock offset %.3f s (SD %.3f) found and applied", offset.posterior_s,
                     offset.posterior_sd_s)
            model = shifted(model, offset.posterior_s, h_s)
            before = passes["passes"]
            results, inputs, passes = smooth_passes(grid, meas, model, passes=params.model_passes,
                                                    process_noise=params.process_noise,
                                                    gate=params.gate_sigmas, dofs=DOFS)
            passes["before_offset"] = before
    misalignment = None
    if model is not None and "u" in meas and "v" in meas and not source.differentiated:
        misalignment = estimate_misalignment(grid, meas["u"], meas["v"], results["u"], results["v"],
                                             inputs["u"], inputs["v"]).with_prior(params.mount_yaw_sd_deg)
        if misalignment.applied:  # smooth again from the measurements turned back
            log.info("velocity sensor: yaw misalignment %.2f deg (SD %.2f) found and undone",
                     misalignment.posterior_deg, misalignment.posterior_sd_deg)
            meas["u"], meas["v"] = turned(meas["u"], meas["v"], np.radians(misalignment.posterior_deg))
            others = {d: r for d, r in results.items() if d not in ("u", "v")}
            again, again_inputs, again_passes = smooth_passes(
                grid, {d: meas[d] for d in ("u", "v")}, model, passes=params.model_passes,
                process_noise=params.process_noise, gate=params.gate_sigmas, dofs=DOFS, fixed=others)
            results.update(again)
            inputs.update(again_inputs)
            passes["chosen"].update(again_passes["chosen"])
            passes["after_misalignment"] = again_passes["passes"]
        widen_for_misalignment(results["u"], results["v"], misalignment)
    accelerometer = None
    if vehicle.sensors.accelerometer is not None:
        if source.differentiated:
            log.warning("sensors.accelerometer is not used with sensors.position (positions are differentiated "
                        "per earth axis)")
        else:  # a second pass: the accelerometers' accelerations beside the velocity measurements
            acc, accelerometer = accelerometer_measurements(synced, body, streams, vehicle, params, results, noise)
            for dof, extra in acc.items():
                try:
                    results[dof] = smooth_with_input(grid, Measurements.concat(meas[dof], extra), inputs[dof],
                                                     q=params.process_noise.get(dof), gate=params.gate_sigmas)
                except ValueError as err:
                    raise SyncError(f"cannot smooth {dof} with the accelerometer: {err}", field=dof) from err
            smoothed_variances([results[dof] for dof in acc])
    if source.differentiated:
        omega, omega_dot = np.zeros((len(grid), 3)), np.zeros((len(grid), 3))
        for j, dof in enumerate("pqr"):
            if dof in results:
                omega[:, j], omega_dot[:, j] = results[dof].x, results[dof].xdot
        results.update(body_motion_from_positions(
            positions, source, body["roll_rad"].to_numpy(dtype=float), body["pitch_rad"].to_numpy(dtype=float),
            body["yaw_rad"].to_numpy(dtype=float), omega, omega_dot))

    for dof, est in biases.items():  # a constant error: it shifts every sample of the smoothed rate alike
        if est.identifiable and dof in results:
            results[dof].x_sd = np.sqrt(results[dof].x_sd**2 + est.sd_radps**2)

    usable = _other_required_valid(synced, vehicle)
    if offset is not None and offset.applied:  # derive forms tau from these: the timing the smoother found
        usable &= shift_columns(body, synced, list(dict.fromkeys(t.input_signal for t in vehicle.thrusters)),
                                offset.posterior_s, h_s)
    for dof, res in results.items():
        limit = params.max_velocity_sd_mps if VEL_UNIT[dof] == "mps" else params.max_rate_sd_radps
        usable &= res.x_sd <= limit
    seg = segments(usable, int(np.ceil(params.min_segment_s / h_s - 1e-9)))
    if not np.any(seg >= 0):
        raise SyncError(f"no stretch of at least {params.min_segment_s} s where the smoothed velocities are known "
                        f"within the limits ({int(usable.sum())} of {len(grid)} grid samples usable)")

    out = body.copy()
    out["segment"] = seg
    for j, dof in enumerate(DOFS):
        res = results.get(dof)
        zeros = np.zeros(len(out))
        x, xdot = (res.x, res.xdot) if res else (zeros, zeros)
        out[VELOCITY[j]] = x
        out[SMOOTH[j]] = x
        out[ACCELERATION[j]] = xdot
        out[std_column(dof)] = res.x_sd if res else zeros
        out[accel_std_column(dof)] = res.xdot_sd if res else zeros
        # cov(x, x'): d's SD needs it (positions, rotated per sample, come without it: 0)
        out[cov_column(dof)] = res.x_xdot_cov if res is not None and res.x_xdot_cov is not None else zeros
    kept = out[seg >= 0].reset_index(drop=True)
    first = ["t_ns", "segment", *VELOCITY, *SMOOTH, *ACCELERATION,
             *[std_column(d) for d in DOFS], *[accel_std_column(d) for d in DOFS], *[cov_column(d) for d in DOFS],
             *[meas_column(d) for d in DOFS]]
    kept = kept[first + [c for c in kept.columns if c not in first]]

    report = {
        "method": "kalman",
        "grid_samples": int(len(grid)),
        "usable_samples": int(len(kept)),
        "usable_fraction": float(len(kept) / len(grid)),
        "synced_segment_fraction": float(np.mean(synced["segment"].to_numpy() >= 0)),
        "segments": int(seg.max()) + 1,
        "noise": {name: est.as_dict() for name, est in sorted(noise.items())},
        "dofs": {dof: {"process_noise": None if np.isnan(res.q) else res.q,
                       "process_noise_source": _process_noise_source(dof, res, source.key, params),
                       "measurements": res.used + res.gated, "gated": res.gated,
                       "gated_fraction": res.gated / max(res.used + res.gated, 1),
                       "median_velocity_sd": float(np.median(res.x_sd)),
                       "median_acceleration_sd": float(np.median(res.xdot_sd))}
                 for dof, res in results.items()},
    }
    report["model"] = _passes_report(passes, results)
    report["excitation"] = excitation_report(grid, model, meas, passes["passes"])
    if offset is not None:
        report["actuator_clock_offset"] = offset.as_dict()
    if misalignment is not None:
        report["velocity_misalignment"] = misalignment.as_dict()
    if accelerometer is not None:
        report["accelerometer"] = accelerometer
    if estimate_biases:
        report["rate_bias"] = {dof: est.as_dict() for dof, est in biases.items()}
    log.info("kalman: %d of %d grid samples usable (%.0f %%, sync's segments alone: %.0f %%), %d segment(s)",
             len(kept), len(grid), 100 * report["usable_fraction"], 100 * report["synced_segment_fraction"],
             report["segments"])
    return kept, report
