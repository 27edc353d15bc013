"""The grid methods of the differentiate stage (``gaussian``, ``savgol``): filters of the synced grid.

:func:`filter_motion` (synced table + vehicle + params) -> the kinematics table + a report:

1. body velocities and attitude on the grid (:func:`pipeline.kinematics.body_kinematics`); positions
   (``sensors.position``) are differentiated first by the white-jerk smoother (:mod:`pipeline.estimation.position`);
2. per velocity column, the filter width: fixed, per signal (``sigma_s_per_signal``) or ``auto``
   (:func:`auto_widths`, from each sensor's noise and rate at its native stamps);
3. :func:`filter_segments`: per segment, smoothed velocities (``u_smooth_mps`` ...) and accelerations
   (``udot_mps2`` ...) by :mod:`pipeline.estimation.gaussian` or :mod:`pipeline.estimation.savgol` (their
   covariance ``u_udot_cov_m2ps3`` ... 0: a filter gives no SDs), and the
   samples near each segment's edges dropped (a segment loses the edge samples of its widest filter). Nothing is
   extrapolated across a gap: each segment is filtered alone.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
import pandas as pd

from pipeline.config.params import DifferentiateParams
from pipeline.config.vehicle import Vehicle
from pipeline.errors import SchemaError, SyncError
from pipeline.estimation.gaussian import edge_samples, gaussian_filters, gaussian_truncate
from pipeline.estimation.measurements import sensor_noise
from pipeline.estimation.position import smooth_positions, with_position_rates
from pipeline.estimation.savgol import savgol_filters, savgol_window
from pipeline.estimation.widths import optimal_sigma
from pipeline.kinematics import body_kinematics
from pipeline.vocabulary import ACCELERATION, DOFS, SMOOTH, VELOCITY, cov_column

log = logging.getLogger(__name__)

__all__ = ["auto_widths", "filter_motion", "filter_segments", "filter_widths", "grid_step_s"]


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


def filter_widths(params: DifferentiateParams, widths: dict[str, float] | None) -> dict[str, float]:
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
                              "(pipeline.estimation.differentiate.differentiate does it); none given for "
                              f"{col!r}", field=col)
        else:
            out[col] = float(fixed)
    return out


def filter_segments(table: pd.DataFrame, params: DifferentiateParams, widths: dict[str, float] | None = None
                    ) -> pd.DataFrame:
    """Smoothed velocities and accelerations per segment; edge samples dropped; other columns passed through.

    ``widths``: per velocity column, the Gaussian sigma or Savitzky-Golay window in seconds (``auto``: from
    :func:`auto_widths`); a segment loses the edge samples of its widest filter.
    """
    if params.method not in ("gaussian", "savgol"):
        raise ValueError(f"filter_segments() filters the grid (gaussian, savgol); {params.method!r} is "
                         "pipeline.estimation.kalman.estimate_motion")
    missing = [c for c in ("t_ns", "segment", *VELOCITY) if c not in table.columns]
    if missing:
        raise SchemaError(f"columns {missing} missing from the kinematics input", field=missing[0])
    seg = table["segment"].to_numpy(dtype=np.int32)
    t = table["t_ns"].to_numpy(dtype=np.int64)
    dt_s = grid_step_s(t, seg)
    width = filter_widths(params, widths)
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
                smooth, acc = savgol_filters(nu, window[col], params.savgol_order, dt_s)
            part[SMOOTH[j]] = smooth
            part[ACCELERATION[j]] = acc
            part[cov_column(DOFS[j])] = 0.0  # the filters give no covariance (nor SDs): the contract's columns
        parts.append(part.iloc[edge: len(part) - edge])
    if not parts:
        raise SyncError(f"no segment longer than {2 * edge} samples ({2 * edge * dt_s:g} s) to differentiate")
    out = pd.concat(parts, ignore_index=True)
    first = ["t_ns", "segment", *VELOCITY, *SMOOTH, *ACCELERATION, *(cov_column(d) for d in DOFS)]
    return out[first + [c for c in out.columns if c not in first]]


def auto_widths(body: pd.DataFrame, synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams,
                streams=None) -> tuple[dict[str, float], dict[str, Any]]:
    """Per velocity column, the width of least estimated mean-square derivative error
    (:func:`pipeline.estimation.widths.optimal_sigma`; for Savitzky-Golay, the window of equal noise gain,
    8 sigma), from each sensor's noise and rate at its native stamps; and the noise estimates used."""
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


def filter_motion(synced: pd.DataFrame, vehicle: Vehicle, params: DifferentiateParams, streams=None
                  ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The kinematics table of the contract and the stage's report (noise per signal, widths) by a grid method;
    see the module docstring. ``streams``: the trial's native streams, for ``auto`` widths."""
    auto = (params.sigma_s if params.method == "gaussian" else params.savgol_window_s) == "auto"
    source = vehicle.sensors.linear_velocity()
    if source.differentiated:  # positions: earth velocities from the white-jerk smoother, then as any source
        if auto:
            raise SchemaError(f"{params.method}: width 'auto' is not available for {source.key} (the positions "
                              "are differentiated by the smoother first); give the width, or method: kalman",
                              field="sigma_s")
        synced = with_position_rates(synced, source, smooth_positions(synced, source, params, streams, {}))
    body = body_kinematics(synced, vehicle)
    widths, report = auto_widths(body, synced, vehicle, params, streams) if auto else (None, {
        "method": params.method, "widths_s": filter_widths(params, None), "noise": {}})
    out = filter_segments(body, params, widths)
    report.update(grid_samples=len(synced), usable_samples=len(out), usable_fraction=len(out) / max(len(synced), 1),
                  synced_segment_fraction=float(np.mean(synced["segment"].to_numpy() >= 0)))
    return out, report
