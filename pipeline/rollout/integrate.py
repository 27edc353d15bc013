"""The rollout integrator: a batch of trajectories stepped together with fixed-step RK4 (:mod:`pipeline.rk4`) or
Euler at the grid rate, inputs held constant over a step (zero-order hold).

A trajectory that leaves its bound (``divergence_factor x`` the measured range of a DOF) or becomes non-finite is
frozen and reported as diverged at that step; DOFs can be clamped to measured values at every step (the gyro's
rates while the DVL velocities are rolled out).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from pipeline.rk4 import rk4_slopes
from pipeline.rollout.dynamics import Dynamics
from pipeline.rollout.tables import take


def rollout(f: Dynamics, nu0: np.ndarray, inputs: np.ndarray, dt_s: float, *, bound: np.ndarray | None = None,
            clamp: np.ndarray | None = None, clamp_mask: np.ndarray | None = None,
            method: str = "rk4", n_steps: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Integrate a batch: ``nu0 (B, k)``, ``inputs (B, N, m)`` held over each step; returns ``(nu (B, N, k),
    diverged_step (B,))`` with ``nu[:, 0] = nu0`` and ``-1`` for members that stayed within ``bound (k,)``.

    ``n_steps (B,)`` (default all ``N``): member ``b`` has ``n_steps[b]`` samples; its later values are NaN.
    DOFs in ``clamp_mask`` are taken from ``clamp (B, N, k)`` at every step (measured, e.g. gyro rates).
    A diverged member is frozen at its last state within bounds; its later values are NaN. See
    :func:`rollout_ragged` for members that read their inputs from one trial's rows.
    """
    nu0 = np.atleast_2d(np.asarray(nu0, dtype=float))
    n_batch, n_max = inputs.shape[0], inputs.shape[1]
    k = nu0.shape[1]
    length = np.full(n_batch, n_max) if n_steps is None else np.minimum(np.asarray(n_steps, dtype=int), n_max)
    first = np.arange(n_batch) * n_max
    flat, diverged = rollout_ragged(f, nu0, inputs.reshape(n_batch * n_max, -1), first, length, dt_s, bound=bound,
                                    clamp=None if clamp is None else clamp.reshape(n_batch * n_max, k),
                                    clamp_mask=clamp_mask, method=method, offsets=first, n_out=n_batch * n_max)
    return flat.reshape(n_batch, n_max, k), diverged


def rollout_ragged(f: Dynamics, nu0: np.ndarray, inputs: np.ndarray, starts: np.ndarray, n_steps: np.ndarray,
                   dt_s: float, *, bound: np.ndarray | None = None, clamp: np.ndarray | None = None,
                   clamp_mask: np.ndarray | None = None, method: str = "rk4", offsets: np.ndarray | None = None,
                   n_out: int | None = None, progress: Callable[..., Any] | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Integrate a batch of members of different lengths that read one table of rows: member ``b`` starts at
    ``nu0[b]`` and takes its input at its step ``i`` from ``inputs[starts[b] + i]`` (``inputs (n, m)``, a
    trial's rows; ``clamp (n, k)`` likewise) for ``n_steps[b]`` samples.

    Returns ``(out, diverged_step (B,))``: ``out[offsets[b] + i]`` is member ``b`` at step ``i`` (``offsets``
    defaults to the members laid end to end, ``out`` then has ``sum(n_steps)`` rows; NaN after divergence).
    All members are stepped together: each RK4 stage calls ``f`` once, on the members still running
    (``take(f, members)`` when that set changes), so members that ended or diverged cost nothing.
    ``progress(done, total, desc)`` (optional) is called about every 1 % of the steps.
    """
    nu0 = np.atleast_2d(np.asarray(nu0, dtype=float))
    starts, length = np.asarray(starts, dtype=np.intp), np.asarray(n_steps, dtype=np.intp)
    n_batch, k = nu0.shape
    if offsets is None:
        offsets = np.concatenate([[0], np.cumsum(length)[:-1]]).astype(np.intp)
        n_out = int(length.sum())
    out = np.full((int(n_out), k), np.nan)
    diverged = np.full(n_batch, -1)
    free = np.ones(k) if clamp_mask is None else (~np.asarray(clamp_mask, dtype=bool)).astype(float)
    clamped = clamp is not None and clamp_mask is not None
    act = np.flatnonzero(length > 0)  # members still running, and their states
    state = nu0[act].copy()
    g, g_size = f, -1

    def g_free(x: np.ndarray, u: np.ndarray) -> np.ndarray:  # clamped DOFs do not move
        return g(x, u) * free

    n_steps_max = int(length.max(initial=0))
    every = max(1, n_steps_max // 100)
    for i in range(n_steps_max):
        if progress is not None and i % every == 0:
            progress(i, n_steps_max, "rollout steps")
        if clamped:
            state[:, clamp_mask] = clamp[starts[act] + i][:, clamp_mask]
        bad = ~np.all(np.isfinite(state), axis=1)
        if bound is not None:
            bad |= np.any(np.abs(state) > bound, axis=1)
        if bad.any():
            diverged[act[bad]] = i
        out[offsets[act[~bad]] + i] = state[~bad]
        keep = ~bad & (length[act] > i + 1)
        if not keep.all():
            act, state = act[keep], state[keep]
        if act.size == 0:
            break
        if act.size != g_size:  # the running set only shrinks: the same size is the same members
            g, g_size = take(f, act), act.size
        u = inputs[starts[act] + i]
        with np.errstate(all="ignore"):
            step = g(state, u) if method == "euler" else rk4_slopes(g_free, state, u, dt_s) / 6.0
            state = state + dt_s * step * free
    if progress is not None:
        progress(n_steps_max, n_steps_max, "rollout steps")
    return out, diverged
