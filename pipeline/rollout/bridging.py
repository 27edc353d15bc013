"""DVL-outage bridging: in each window of an outage length the DVL velocities are replaced by a rollout from the
last DVL velocity (the gyro's rates and the attitude stay measured), and position is dead reckoned in NED with the
measured yaw; the error at the window's end is against dead reckoning with the measured velocity, next to the
baseline of holding the last DVL velocity.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from pipeline.rollout.dynamics import Dynamics, stack
from pipeline.rollout.integrate import rollout_ragged
from pipeline.rollout.runs import divergence_bound, grid_step_s, windows

log = logging.getLogger(__name__)


def dead_reckon(u: np.ndarray, v: np.ndarray, yaw: np.ndarray, dt_s: float) -> np.ndarray:
    """North/east displacement from body velocities and yaw (rows of a batch or one run); ``[..., N, 2]``.

    Left Riemann sums on the grid: ``p[0] = 0``, ``p[i+1] = p[i] + R(yaw[i]) [u[i], v[i]] dt``.
    """
    north = u * np.cos(yaw) - v * np.sin(yaw)
    east = u * np.sin(yaw) + v * np.cos(yaw)
    vel = np.stack([north, east], axis=-1)
    zero = np.zeros_like(vel[..., :1, :])
    return np.concatenate([zero, np.cumsum(vel[..., :-1, :], axis=-2) * dt_s], axis=-2)


def bridge_outages(models: Mapping[str, Dynamics], t_ns: np.ndarray, nu_meas: np.ndarray, inputs: np.ndarray,
                   yaw: np.ndarray, dofs: Sequence[str], outage_windows_s: Sequence[float], *,
                   dvl_dofs: Sequence[str] = ("u", "v", "w"), segment: np.ndarray | None = None,
                   divergence_factor: float = 10.0, method: str = "rk4") -> list[dict[str, Any]]:
    """Position error at the end of simulated DVL outages, per outage length and model (+ ``hold_last``).

    Windows of each length tile the valid runs; in each, the DVL DOFs are rolled out from their last measured
    value while the other DOFs (gyro rates) stay measured. Needs ``u`` and ``v`` among ``dofs``. Every window
    of every length and model is one member of one batch (:func:`rollout_ragged` over :func:`stack` of the
    models).
    """
    dt_s = grid_step_s(t_ns)
    bound = divergence_bound(nu_meas, divergence_factor)
    ju, jv = dofs.index("u"), dofs.index("v")
    clamp_mask = np.array([d not in dvl_dofs for d in dofs])
    plan = []  # (length, starts, n) of the lengths that fit
    for length in outage_windows_s:
        starts = windows(t_ns, segment, dt_s, length)
        if starts.size == 0:
            log.warning("no %g s window fits in the valid runs", length)
            continue
        plan.append((length, starts, int(round(length / dt_s)) + 1))
    names = list(models)
    start = np.concatenate([st for _ in names for _, st, _ in plan] or [np.arange(0)]).astype(np.intp)
    count = np.concatenate([np.full(st.size, n) for _ in names for _, st, n in plan] or [np.arange(0)])
    group = np.concatenate([np.full(st.size, g) for g in range(len(names)) for _, st, _ in plan] or [np.arange(0)])
    flat, div = rollout_ragged(stack([models[m] for m in names], group), nu_meas[start], inputs, start,
                               count, dt_s, bound=bound, clamp=nu_meas, clamp_mask=clamp_mask, method=method)
    rows: list[dict[str, Any]] = []
    first = {(m, length): 0 for m in names for length, _, _ in plan}
    b = 0
    for m in names:
        for length, st, _ in plan:
            first[(m, length)] = b
            b += st.size
    for length, starts, n in plan:
        idx = starts[:, None] + np.arange(n)
        ref = dead_reckon(nu_meas[idx, ju], nu_meas[idx, jv], yaw[idx], dt_s)[:, -1]
        held = np.repeat(nu_meas[starts][:, None], n, axis=1)
        candidates: dict[str, tuple[np.ndarray, np.ndarray]] = {"hold_last": (held, np.full(starts.size, -1))}
        for m in names:
            a = first[(m, length)]
            off = int(count[:a].sum())
            candidates[m] = (flat[off:off + starts.size * n].reshape(starts.size, n, -1), div[a:a + starts.size])
        for name, (traj, dv) in candidates.items():
            ok = dv < 0
            err = np.full(starts.size, np.nan)
            if ok.any():
                pos = dead_reckon(traj[ok, :, ju], traj[ok, :, jv], yaw[idx[ok]], dt_s)[:, -1]
                err[ok] = np.hypot(*(pos - ref[ok]).T)
            rows.append({
                "window_s": float(length), "model": name, "n_windows": int(starts.size),
                "n_diverged": int((~ok).sum()),
                "mean_error_m": float(np.nanmean(err)) if ok.any() else None,
                "median_error_m": float(np.nanmedian(err)) if ok.any() else None,
                "max_error_m": float(np.nanmax(err)) if ok.any() else None,
                "mean_distance_m": float(np.mean(np.hypot(*ref.T))),
            })
    return rows
