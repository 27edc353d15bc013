"""Positions to be differentiated (``sensors.position``: motion capture, GNSS in a local earth frame).

The design, the simplest that keeps every variance honest:

1. **Per earth axis**, the positions at their own stamps (valid flag set) go through the same white-jerk smoother
   as every velocity sensor (:func:`pipeline.estimation.smoother.smooth`), with x = position: its state
   (x, x', x'') is the position, the earth-frame velocity and the earth-frame acceleration, each with its SD,
   on the synced grid. The position noise is estimated from the data (or ``noise_sd`` in params), the process
   noise by maximum likelihood, outliers gated; gaps are bridged with growing variance.
2. **Into body axes** at each grid sample by the logged attitude (the heading alone for a planar x, y source),
   exactly as an earth-frame velocity source (:func:`pipeline.kinematics.sensor_to_body`, S = R_nb^T A):
   v_b = S v_e - omega x r and, differentiating v_b = S v_e with dS/dt = -[omega]x S,
   v_b' = S a_e - omega x (S v_e) - omega' x r (r: the tracked point's position in body axes; omega, omega': the
   smoothed rates). Variances: var(v_b) = S^2 var(v_e), var(v_b') = S^2 var(a_e) (the rates' own error, far
   smaller at these speeds, is left out).

The ``kalman`` method takes these as the body velocities and accelerations directly: smoothing them a second
time, as measurements of the velocity smoother, would count the same position samples many times over (the
smoothed velocities' errors are correlated over the smoother's window) and report SDs too small by that factor.
The grid methods (``gaussian``, ``savgol``) filter the body velocities of step 2 as those of any other source.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import numpy as np
import pandas as pd
import pyarrow as pa

from pipeline.config.params import DifferentiateParams
from pipeline.config.vehicle import LinearVelocity, position_rate_column
from pipeline.errors import SyncError
from pipeline.estimation.measurements import native_stream, signal_noise
from pipeline.estimation.noise import NoiseEstimate
from pipeline.estimation.smoother import Measurements, Smoothed, smooth, smoothed_variances
from pipeline.kinematics import sensor_to_body, sensor_vector

log = logging.getLogger(__name__)

__all__ = ["smooth_positions", "with_position_rates", "body_motion_from_positions"]


def smooth_positions(synced: pd.DataFrame, source: LinearVelocity, params: DifferentiateParams,
                     streams: Mapping[str, pd.DataFrame | pa.Table] | None, noise: dict[str, NoiseEstimate]
                     ) -> list[Smoothed]:
    """Per position signal (earth axis), the smoother's position, velocity and acceleration on the synced grid,
    from the samples at their own stamps (without native streams, the synced grid's valid samples)."""
    grid = synced["t_ns"].to_numpy(dtype=np.int64)
    native = native_stream(streams, source.velocity[0])
    if native is not None and all(s in native[1] for s in source.velocity):
        t, cols = native
    else:
        t = grid
        cols = {c: synced[c].to_numpy(dtype=float) for c in (*source.velocity, source.valid) if c in synced}
    ok = np.all(np.isfinite(np.stack([cols[s] for s in source.velocity], axis=1)), axis=1)
    if source.valid is not None and source.valid in cols:
        ok &= np.nan_to_num(cols[source.valid], nan=0.0) != 0
    results = []
    for s in source.velocity:
        noise[s] = signal_noise(s, t[ok], cols[s][ok], params)
        try:
            results.append(smooth(grid, Measurements(t[ok], cols[s][ok], noise[s].sd ** 2), gate=params.gate_sigmas))
        except ValueError as err:
            raise SyncError(f"cannot smooth the positions of {s!r}: {err}", field=s) from err
    smoothed_variances(results)
    return results


def with_position_rates(synced: pd.DataFrame, source: LinearVelocity, results: list[Smoothed]) -> pd.DataFrame:
    """``synced`` with the earth-frame velocity of each position signal (:func:`position_rate_column`)."""
    return synced.assign(**{position_rate_column(s): res.xdot for s, res in zip(source.velocity, results,
                                                                                  strict=True)})


def body_motion_from_positions(results: list[Smoothed], source: LinearVelocity, roll: np.ndarray,
                               pitch: np.ndarray, yaw: np.ndarray, omega: np.ndarray, omega_dot: np.ndarray
                               ) -> dict[str, Smoothed]:
    """Body velocities and accelerations of the reference point (the DOFs the positions give: u, v; w; or u, v,
    w) with their SDs, as smoother results on the grid (see the module docstring); ``omega``, ``omega_dot``: (n, 3)
    smoothed rates and their derivatives."""
    def by_axis(values: list[np.ndarray]) -> np.ndarray:  # each earth axis given in its place, the others 0
        return sensor_vector(np.stack(values, axis=1), source)

    v_e, a_e = by_axis([r.xdot for r in results]), by_axis([r.xddot for r in results])
    var_v, var_a = by_axis([r.xdot_sd**2 for r in results]), by_axis([r.xddot_sd**2 for r in results])
    S = sensor_to_body(source, roll, pitch, yaw)
    lever = np.asarray(source.position_m, dtype=float)
    v_point = np.einsum("nij,nj->ni", S, v_e)
    v_ref = v_point - np.cross(omega, lever)
    a_ref = np.einsum("nij,nj->ni", S, a_e) - np.cross(omega, v_point) - np.cross(omega_dot, lever)
    sd_v, sd_a = np.sqrt((S**2) @ var_v[..., None])[..., 0], np.sqrt((S**2) @ var_a[..., None])[..., 0]
    out = {}
    for dof in source.dofs:
        j = "uvw".index(dof)
        out[dof] = Smoothed(x=v_ref[:, j], xdot=a_ref[:, j], q=float("nan"), loglik=float("nan"),
                            used=min(r.used for r in results), gated=max(r.gated for r in results),
                            x_sd=sd_v[:, j], xdot_sd=sd_a[:, j], h_s=results[0].h_s)
    return out
