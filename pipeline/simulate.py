"""Free-run simulation of velocity with learned models, error growth per horizon, and DVL-outage bridging.

Dynamics are callables ``f(nu (B, k), inputs (B, m)) -> nudot (B, k)`` over a batch of B trajectories:

- :class:`DecoupledDynamics`: ``M nudot = tau - C(nu) nu - d(nu)`` with one damping function per DOF
  (``inputs`` = generalized forces of the simulated DOFs, already minus restoring forces if any). M is the
  sub-matrix of the simulated DOFs (the others held at zero velocity and acceleration).
- :class:`CoupledDynamics`: ``nudot = F(nu, n)`` for any fitted estimator with ``predict(X)``,
  ``X = [nu..., n...]`` (e.g. ``[u v r n1 n2 n3]`` -> ``[udot vdot rdot]``).

:func:`rollout` integrates a batch with fixed-step RK4 (or Euler) at the grid rate, inputs held constant over a
step (zero-order hold). Learned 1-D damping models are evaluated through :class:`Table1D`, a dense uniform
lookup table (linear interpolation, linear extrapolation beyond), so a rollout costs numpy operations instead of
one scikit-learn ``predict`` per step; the table error is far below the noise (tested). A trajectory that leaves
``divergence_factor x`` the measured range of a DOF, or becomes non-finite, is frozen and reported as
``diverged`` at that time. Gaps (``segment == -1`` or a jump in ``t_ns``) restart the rollout from measurement.

The GP's band: Monte Carlo over posterior *functions* (``DampingGP.sample_functions`` on the table grid, fixed
seed), each rolled out as one member of the batch; the band is the mean +- 2 sd of the members.

Bridging (:func:`bridge_outages`): in each window of an outage length the DVL velocities are replaced by a
rollout from the last DVL velocity (the gyro's rates and the attitude stay measured), and position is dead
reckoned in NED with the measured yaw; the error at the window's end is against dead reckoning with the measured
velocity, next to the baseline of holding the last DVL velocity.
"""

from __future__ import annotations

import copy
import functools
import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.units import axis_label

log = logging.getLogger(__name__)

DOFS = ("u", "v", "w", "p", "q", "r")
VELOCITY_COLUMNS = {"u": "u_mps", "v": "v_mps", "w": "w_mps", "p": "p_radps", "q": "q_radps", "r": "r_radps"}
TAU_COLUMNS = {"u": "tau_u_N", "v": "tau_v_N", "w": "tau_w_N", "p": "tau_p_Nm", "q": "tau_q_Nm", "r": "tau_r_Nm"}
DAMPING_COLUMNS = {"u": "d_u_N", "v": "d_v_N", "w": "d_w_N", "p": "d_p_Nm", "q": "d_q_Nm", "r": "d_r_Nm"}

Dynamics = Callable[[np.ndarray, np.ndarray], np.ndarray]


class Table1D:
    """A function of one variable on a uniform grid; ``values`` is ``(G,)`` or one table per batch member ``(B, G)``.

    Linear interpolation inside ``[lo, hi]``, linear extrapolation with the end slopes outside.
    """

    def __init__(self, lo: float, hi: float, values: np.ndarray) -> None:
        self.lo, self.hi = float(lo), float(hi)
        self.values = np.asarray(values, dtype=float)
        self.n = self.values.shape[-1]
        self.h = (self.hi - self.lo) / (self.n - 1)

    @classmethod
    def from_model(cls, model: Any, lo: float, hi: float, n_points: int = 2001) -> Table1D:
        grid = np.linspace(lo, hi, n_points)
        return cls(lo, hi, np.asarray(model.predict(grid[:, None]), dtype=float).ravel())

    def grid(self) -> np.ndarray:
        return np.linspace(self.lo, self.hi, self.n)

    def take(self, members: np.ndarray) -> Table1D:
        """The tables of batch members ``members`` (repeats allowed); a shared ``(G,)`` table is returned as is."""
        return self if self.values.ndim == 1 else Table1D(self.lo, self.hi, self.values[members])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        s = (np.asarray(x, dtype=float) - self.lo) / self.h
        i = np.fmin(np.fmax(s, 0.0), self.n - 2).astype(np.intp)  # fmax/fmin drop NaN; truncation = floor here
        w = s - i
        if self.values.ndim == 1:
            a, b = self.values[i], self.values[i + 1]
        else:
            rows = np.arange(self.values.shape[0])
            a, b = self.values[rows, i], self.values[rows, i + 1]
        return a + w * (b - a)


def table_range(x: np.ndarray, margin: float = 1.0) -> tuple[float, float]:
    """The table span for measured values ``x``: their range widened by ``margin`` ranges on each side."""
    lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
    width = max(hi - lo, 1e-6)
    return lo - margin * width, hi + margin * width


class DecoupledDynamics:
    """``nudot = M_k^-1 (inputs - C(nu) nu - d(nu))`` over the DOFs ``dofs``.

    ``M`` is 6x6; ``coriolis(M, nu6 (B, 6)) -> (B, 6)`` (e.g. ``pipeline.physics.coriolis_force``) or None;
    ``damping[dof](x (B,)) -> (B,)`` (a :class:`Table1D`, or any callable).
    """

    def __init__(self, M: np.ndarray, dofs: Sequence[str], damping: Mapping[str, Callable[[np.ndarray], np.ndarray]],
                 coriolis: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None) -> None:
        self.M = np.asarray(M, dtype=float)
        self.dofs = list(dofs)
        self.idx = [DOFS.index(d) for d in self.dofs]
        self.M_inv = np.linalg.inv(self.M[np.ix_(self.idx, self.idx)])
        self.damping = dict(damping)
        self.coriolis = coriolis
        self.Q = None if coriolis is None else self._quadratic_form(coriolis)

    def _quadratic_form(self, coriolis: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray | None:
        """``C(nu) nu`` restricted to the DOFs is a quadratic form ``Q[i, j, l] nu_j nu_l``: probe it once
        (polarization), check it at random points, and evaluate it with one einsum per call from then on."""
        k = len(self.idx)

        def c(x: np.ndarray) -> np.ndarray:
            nu6 = np.zeros((x.shape[0], 6))
            nu6[:, self.idx] = x
            return np.asarray(coriolis(self.M, nu6), dtype=float)[:, self.idx]

        eye = np.eye(k)
        diag = c(eye)
        pairs = (eye[:, None, :] + eye[None, :, :]).reshape(k * k, k)
        both = c(pairs).reshape(k, k, k)
        Q = 0.5 * (both - diag[:, None, :] - diag[None, :, :])
        Q[np.arange(k), np.arange(k)] = diag
        Q = np.transpose(Q, (2, 0, 1))  # Q[i, j, l]
        x = np.random.default_rng(0).standard_normal((4, k))
        direct = c(x)
        if not np.allclose(np.einsum("ijl,bj,bl->bi", Q, x, x), direct, rtol=1e-9, atol=1e-9 * np.abs(direct).max()):
            log.info("C(nu) nu is not a quadratic form in the simulated DOFs; calling it at every step")
            return None
        return Q

    def take(self, members: np.ndarray) -> DecoupledDynamics:
        """The dynamics of batch members ``members`` (per-member damping tables taken, see :func:`take`)."""
        damping = {d: take(t, members) for d, t in self.damping.items()}
        if all(damping[d] is self.damping[d] for d in damping):
            return self
        other = copy.copy(self)
        other.damping = damping
        return other

    def __call__(self, nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
        rhs = tau - np.column_stack([self.damping[d](nu[:, j]) for j, d in enumerate(self.dofs)])
        if self.Q is not None:
            rhs = rhs - np.einsum("ijl,bj,bl->bi", self.Q, nu, nu, optimize=False)
        elif self.coriolis is not None:
            nu6 = np.zeros((nu.shape[0], 6))
            nu6[:, self.idx] = nu
            rhs = rhs - self.coriolis(self.M, nu6)[:, self.idx]
        return rhs @ self.M_inv.T


class CoupledDynamics:
    """``nudot = estimator.predict([nu, inputs])`` for a fitted multi-output estimator (a protocol, any library).

    A rollout calls it four times per step with a small batch, where scikit-learn's per-call input validation
    costs more than the kernel sums; for the project's SVRs (:func:`svr_kernel_predictor`) the same sums are done
    in plain numpy (equal to libsvm's to float rounding). ``fast=False`` always calls ``predict``.
    """

    def __init__(self, estimator: Any, *, fast: bool = True) -> None:
        self.estimator = estimator
        self._predict = (svr_kernel_predictor(estimator) if fast else None) or estimator.predict

    def __call__(self, nu: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        out = np.asarray(self._predict(np.hstack([nu, inputs])), dtype=float)
        return out.reshape(nu.shape)


def svr_kernel_predictor(estimator: Any) -> Callable[[np.ndarray], np.ndarray] | None:
    """``predict`` of a fitted :class:`pipeline.models.svr.PerOutputRegressor` of scaled-RBF SVRs as numpy sums
    over the support vectors, without scikit-learn's per-call checks; None for any other estimator ("not mine").

    Per output: ``z = (x - mean) / scale * sqrt(gamma)`` (the estimator's own transform), ``y = sum_j a_j
    exp(-|z - s_j|^2) + b`` (libsvm's RBF with gamma = 1; ``a`` the dual coefficients, ``b`` the intercept), with
    ``|z - s|^2 = |z|^2 + |s|^2 - 2 z.s`` about the support vectors' centroid, so a batch costs one BLAS matrix
    product per output instead of a ``(B, n_sv, n_features)`` difference array.
    """
    from sklearn.svm import SVR

    parts = []
    for est in getattr(estimator, "estimators_", None) or []:
        svr, scaler, scale = (getattr(est, k, None) for k in ("svr_", "scaler_", "feature_scale_"))
        if not isinstance(svr, SVR) or svr.kernel != "rbf" or getattr(svr, "_gamma", None) != 1.0 or \
                scale is None or getattr(scaler, "mean_", None) is None or getattr(scaler, "scale_", None) is None:
            return None
        sv = np.asarray(svr.support_vectors_, dtype=float)
        centre = sv.mean(axis=0)  # distances from the centroid: less cancellation in |z|^2 + |s|^2 - 2 z.s
        sv_c = sv - centre
        parts.append((scaler.mean_, scaler.scale_, np.asarray(scale, dtype=float), centre, sv_c,
                      np.einsum("ij,ij->i", sv_c, sv_c), np.asarray(svr.dual_coef_[0], dtype=float),
                      float(svr.intercept_[0])))
    if not parts or getattr(estimator, "_y_1d", True):
        return None

    def predict(X: np.ndarray) -> np.ndarray:
        X = np.asarray(X, dtype=float)
        out = np.empty((X.shape[0], len(parts)))
        for k, (mean, std, scale, centre, sv_c, sv_sq, coef, b) in enumerate(parts):
            z = (X - mean) / std * scale - centre
            d2 = z @ sv_c.T  # one matrix product per output for the whole batch
            d2 *= -2.0
            d2 += np.einsum("ij,ij->i", z, z)[:, None]
            d2 += sv_sq
            np.maximum(d2, 0.0, out=d2)
            np.exp(-d2, out=d2)
            out[:, k] = d2 @ coef + b
        return out

    return predict


def damping_tables(models: Mapping[str, Any], ranges: Mapping[str, tuple[float, float]], n_points: int = 2001
                   ) -> dict[str, Table1D]:
    """A :class:`Table1D` of each DOF's fitted damping model over ``ranges[dof]`` (see :func:`table_range`)."""
    return {d: Table1D.from_model(m, *ranges[d], n_points=n_points) for d, m in models.items()}


def band_tables(models: Mapping[str, Any], ranges: Mapping[str, tuple[float, float]], n_samples: int, seed: int = 0,
                n_points: int = 401) -> dict[str, Table1D]:
    """Per DOF, ``n_samples`` posterior functions of a GP-like model (``sample_functions``) as batch tables."""
    out = {}
    for j, (d, m) in enumerate(models.items()):
        grid = np.linspace(*ranges[d], n_points)
        out[d] = Table1D(*ranges[d], m.sample_functions(grid[:, None], n_samples, random_state=seed + j))
    return out


def take(f: Any, members: np.ndarray) -> Any:
    """``f`` restricted to (or repeated over) the batch members ``members``: ``f.take(members)`` where ``f`` has
    per-member parameters (a :class:`Table1D` of ``(B, G)`` values, dynamics built on such tables), else ``f``
    itself (a function of each row alone)."""
    method = getattr(f, "take", None)
    return f if method is None else method(np.asarray(members, dtype=np.intp))


class TableStack:
    """Batch members' 1-D tables on different grids in one call: member ``b`` reads the table at ``offset[b]`` of
    ``flat`` (``n[b]`` points from ``lo[b]`` in steps ``h[b]``), with :class:`Table1D`'s arithmetic."""

    def __init__(self, flat: np.ndarray, offset: np.ndarray, lo: np.ndarray, h: np.ndarray, n: np.ndarray) -> None:
        self.flat, self.offset, self.lo, self.h, self.n = flat, offset, lo, h, n

    @classmethod
    def of(cls, tables: Sequence[Table1D], group: np.ndarray, local: np.ndarray) -> TableStack:
        """Member ``b`` gets ``tables[group[b]]`` (its row ``local[b]`` where that table is per member)."""
        blocks = [t.values.ravel() for t in tables]
        base = np.concatenate([[0], np.cumsum([x.size for x in blocks])[:-1]]).astype(np.intp)
        per_member = np.array([t.values.ndim == 2 for t in tables])
        size = np.array([t.n for t in tables], dtype=np.intp)
        offset = base[group] + np.where(per_member[group], local * size[group], 0)
        return cls(np.concatenate(blocks), offset, np.array([t.lo for t in tables])[group],
                   np.array([t.h for t in tables])[group], (size[group] - 2).astype(float))

    def take(self, members: np.ndarray) -> TableStack:
        return TableStack(self.flat, self.offset[members], self.lo[members], self.h[members], self.n[members])

    def __call__(self, x: np.ndarray) -> np.ndarray:
        s = (np.asarray(x, dtype=float) - self.lo) / self.h
        i = np.fmin(np.fmax(s, 0.0), self.n).astype(np.intp)
        w = s - i
        a, b = self.flat[self.offset + i], self.flat[self.offset + i + 1]
        return a + w * (b - a)


def stack(dynamics: Sequence[Dynamics], group: np.ndarray) -> Dynamics:
    """Member ``b`` of a batch follows ``dynamics[group[b]]`` (row ``b``'s rank in its group of that one's
    per-member tables). :class:`DecoupledDynamics` with the same M, DOFs and Coriolis term and
    :class:`Table1D` damping become one such dynamics over a :class:`TableStack` (one call per RK4 stage for all
    of them); anything else a :class:`MemberStack` (one call per dynamics)."""
    group = np.asarray(group, dtype=np.intp)
    first = dynamics[0] if dynamics else None
    if not isinstance(first, DecoupledDynamics) or not all(
            isinstance(g, DecoupledDynamics) and g.dofs == first.dofs and np.array_equal(g.M, first.M)
            and g.coriolis is first.coriolis and all(isinstance(g.damping[d], Table1D) for d in g.dofs)
            for g in dynamics):
        return MemberStack(dynamics, group)
    local = np.empty(group.size, dtype=np.intp)
    for j in range(len(dynamics)):
        rows = np.flatnonzero(group == j)
        local[rows] = np.arange(rows.size)
    out = copy.copy(first)
    out.damping = {d: TableStack.of([g.damping[d] for g in dynamics], group, local) for d in first.dofs}
    return out


class MemberStack:
    """Several dynamics stepped as one batch: member ``b`` follows ``dynamics[group[b]]`` (one call per distinct
    dynamics and RK4 stage, on its rows only)."""

    def __init__(self, dynamics: Sequence[Dynamics], group: np.ndarray) -> None:
        self.dynamics = list(dynamics)
        self.group = np.asarray(group, dtype=np.intp)
        self._rows = [np.flatnonzero(self.group == g) for g in range(len(self.dynamics))]

    def __call__(self, nu: np.ndarray, inputs: np.ndarray) -> np.ndarray:
        out = np.empty_like(nu, dtype=float)
        for g, rows in zip(self.dynamics, self._rows, strict=True):
            if rows.size:
                out[rows] = g(nu[rows], inputs[rows])
        return out

    def take(self, members: np.ndarray) -> MemberStack:
        local = np.empty(self.group.size, dtype=np.intp)  # each member's row within its own group
        for rows in self._rows:
            local[rows] = np.arange(rows.size)
        group = self.group[members]
        return MemberStack([take(g, local[members[group == j]]) for j, g in enumerate(self.dynamics)], group)


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
            if method == "euler":
                step = g(state, u)
            else:
                k1 = g(state, u) * free
                k2 = g(state + 0.5 * dt_s * k1, u) * free
                k3 = g(state + 0.5 * dt_s * k2, u) * free
                k4 = g(state + dt_s * k3, u) * free
                step = (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
            state = state + dt_s * step * free
    if progress is not None:
        progress(n_steps_max, n_steps_max, "rollout steps")
    return out, diverged


def segment_runs(t_ns: np.ndarray, segment: np.ndarray | None, dt_s: float) -> list[tuple[int, int]]:
    """``[start, stop)`` index ranges of contiguous valid samples: same segment id >= 0 and no time gap."""
    t_ns = np.asarray(t_ns)
    n = t_ns.size
    seg = np.zeros(n, dtype=int) if segment is None else np.asarray(segment, dtype=int)
    brk = np.flatnonzero((np.diff(seg) != 0) | (np.diff(t_ns) > 1.5 * dt_s * 1e9)) + 1
    runs = []
    for a, b in zip(np.r_[0, brk], np.r_[brk, n], strict=True):
        if b - a >= 2 and seg[a] >= 0:
            runs.append((int(a), int(b)))
    return runs


def grid_step_s(t_ns: np.ndarray) -> float:
    return float(np.median(np.diff(np.asarray(t_ns, dtype=np.int64)))) * 1e-9


def divergence_bound(nu_meas: np.ndarray, factor: float) -> np.ndarray:
    """Per DOF: ``factor`` times the largest measured magnitude (a floor keeps a DOF at rest from tripping)."""
    scale = np.nanmax(np.abs(nu_meas), axis=0)
    return factor * np.maximum(scale, 1e-3)


def _metrics(meas: np.ndarray, pred: np.ndarray, dofs: Sequence[str]) -> dict[str, dict[str, float | None]]:
    out: dict[str, dict[str, float | None]] = {}
    for j, d in enumerate(dofs):
        ok = np.isfinite(pred[:, j]) & np.isfinite(meas[:, j])
        if not ok.any():
            out[d] = {"mae": None, "r2": None, "n": 0}
            continue
        e = pred[ok, j] - meas[ok, j]
        ss = float(np.sum((meas[ok, j] - meas[ok, j].mean()) ** 2))
        out[d] = {"mae": float(np.mean(np.abs(e))), "r2": float(1 - np.sum(e**2) / ss) if ss > 0 else None,
                  "n": int(ok.sum())}
    return out


@dataclass
class FreeRun:
    """One model's free run over a trial; ``predicted`` is NaN where not simulated (gaps, after divergence)."""

    name: str
    dofs: list[str]
    t_s: np.ndarray
    measured: np.ndarray
    predicted: np.ndarray
    status: str = "ok"
    diverged_at_s: float | None = None
    band: tuple[np.ndarray, np.ndarray] | None = None
    metrics: dict[str, Any] = field(default_factory=dict)

    def summary(self) -> dict[str, Any]:
        out = {"model": self.name, "status": self.status, "diverged_at_s": self.diverged_at_s,
               "metrics": self.metrics}
        if self.band is not None:
            lo, hi = self.band
            inside = (self.measured >= lo) & (self.measured <= hi)
            ok = np.isfinite(lo) & np.isfinite(self.measured)
            out["band_coverage"] = {d: float(inside[ok[:, j], j].mean()) if ok[:, j].any() else None
                                    for j, d in enumerate(self.dofs)}
        return out


def free_run(name: str, f: Dynamics, t_ns: np.ndarray, nu_meas: np.ndarray, inputs: np.ndarray, dofs: Sequence[str],
             *, segment: np.ndarray | None = None, divergence_factor: float = 10.0, method: str = "rk4",
             band_f: Dynamics | None = None, band_members: int = 0) -> FreeRun:
    """Roll ``f`` out over every valid run of the trial from its measured initial velocity.

    ``band_f`` (optional) is a dynamics over a batch of ``band_members`` posterior members (per-member tables);
    its mean +- 2 sd becomes :attr:`FreeRun.band`. All runs (and band members) are one batch
    (:func:`simulate_model`).
    """
    return simulate_model(name, f, t_ns, nu_meas, inputs, dofs, segment=segment, divergence_factor=divergence_factor,
                          method=method, band_f=band_f, band_members=band_members)[0]


def windows(t_ns: np.ndarray, segment: np.ndarray | None, dt_s: float, length_s: float) -> np.ndarray:
    """Start indices of consecutive, non-overlapping windows of ``length_s`` inside the valid runs."""
    n = int(round(length_s / dt_s)) + 1
    starts = [np.arange(a, b - n + 1, n - 1) for a, b in segment_runs(t_ns, segment, dt_s) if b - a >= n]
    return np.concatenate(starts) if starts else np.arange(0)


def horizon_errors(f: Dynamics, t_ns: np.ndarray, nu_meas: np.ndarray, inputs: np.ndarray, dofs: Sequence[str],
                   horizons_s: Sequence[float], *, segment: np.ndarray | None = None,
                   divergence_factor: float = 10.0, method: str = "rk4") -> dict[str, Any]:
    """Error growth: for each horizon H, rollouts re-initialized from measurement at the start of consecutive
    H-second windows; mean |error| at the window's end and over the window, per DOF (all windows of all
    horizons one batch, :func:`simulate_model`)."""
    return simulate_model("", f, t_ns, nu_meas, inputs, dofs, horizons_s, segment=segment,
                          divergence_factor=divergence_factor, method=method, free=False)[1]


def simulate_model(name: str, f: Dynamics, t_ns: np.ndarray, nu_meas: np.ndarray, inputs: np.ndarray,
                   dofs: Sequence[str], horizons_s: Sequence[float] = (), *, segment: np.ndarray | None = None,
                   divergence_factor: float = 10.0, method: str = "rk4", band_f: Dynamics | None = None,
                   band_members: int = 0, free: bool = True) -> tuple[FreeRun | None, dict[str, Any]]:
    """One model's free run (``free``; with ``band_f``'s members) and horizon errors from one batched rollout
    (:func:`simulate_models`). Returns ``(FreeRun or None, horizons)``."""
    return simulate_models({name: (f, band_f)}, t_ns, nu_meas, inputs, dofs, horizons_s, segment=segment,
                           divergence_factor=divergence_factor, method=method, band_members=band_members,
                           free=free)[name]


def simulate_models(models: Mapping[str, tuple[Dynamics, Dynamics | None]], t_ns: np.ndarray, nu_meas: np.ndarray,
                    inputs: np.ndarray, dofs: Sequence[str], horizons_s: Sequence[float] = (), *,
                    segment: np.ndarray | None = None, divergence_factor: float = 10.0, method: str = "rk4",
                    band_members: int = 0, free: bool = True, progress: Callable[..., Any] | None = None
                    ) -> dict[str, tuple[FreeRun | None, dict[str, Any]]]:
    """Free runs (``free``) and horizon errors of models ``{name: (f, band_f or None)}`` that read the same
    ``inputs``, from one batched rollout: every valid run, every band member of every run and every window of
    every horizon of every model is a member of one :func:`rollout_ragged` call over :func:`stack` of the
    dynamics (one call per RK4 stage for the whole batch where they merge, e.g. decoupled models on tables).
    Returns ``{name: (FreeRun or None, horizons)}``, equal to rolling each member out alone. ``progress``: see
    :func:`rollout_ragged`."""
    if not models:
        return {}
    dt_s = grid_step_s(t_ns)
    bound = divergence_bound(nu_meas, divergence_factor)
    runs = segment_runs(t_ns, segment, dt_s) if free else []
    seg_a = np.array([a for a, _ in runs], dtype=np.intp)
    seg_n = np.array([b - a for a, b in runs], dtype=np.intp)
    win = {h: windows(t_ns, segment, dt_s, h) for h in horizons_s}
    win_n = {h: int(round(h / dt_s)) + 1 for h in horizons_s}
    starts: list[np.ndarray] = []
    lengths: list[np.ndarray] = []
    groups: list[np.ndarray] = []
    dynamics: list[Dynamics] = []
    layout: dict[str, tuple[int, bool]] = {}  # name -> (first member, has a band)
    n_members = 0

    def add(st: np.ndarray, n: np.ndarray) -> None:
        nonlocal n_members
        starts.append(st)
        lengths.append(n)
        groups.append(np.full(st.size, len(dynamics) - 1, dtype=np.intp))
        n_members += st.size

    for name, (f, band_f) in models.items():
        band = free and band_f is not None and band_members > 0
        layout[name] = (n_members, band)
        dynamics.append(f)
        add(seg_a, seg_n)
        for h in horizons_s:
            add(win[h], np.full(win[h].size, win_n[h], dtype=np.intp))
        if band:  # run-major: the members of run s are rows s*M .. s*M + M - 1 of the band dynamics
            dynamics.append(take(band_f, np.tile(np.arange(band_members), seg_a.size)))
            add(np.repeat(seg_a, band_members), np.repeat(seg_n, band_members))
    start, length, group = (np.concatenate(x) for x in (starts, lengths, groups))
    dyn = dynamics[0] if len(dynamics) == 1 else stack(dynamics, group)
    flat, div = rollout_ragged(dyn, nu_meas[start], inputs, start, length, dt_s, bound=bound, method=method,
                               progress=progress)
    offset = np.concatenate([[0], np.cumsum(length)]).astype(np.intp)
    t_s = (np.asarray(t_ns) - t_ns[0]) * 1e-9

    results: dict[str, tuple[FreeRun | None, dict[str, Any]]] = {}
    for name, (first, band) in layout.items():
        run = None
        if free:
            pred = np.full_like(nu_meas, np.nan, dtype=float)
            lo, hi = np.full_like(pred, np.nan), np.full_like(pred, np.nan)
            status, at = "ok", None
            band_first = first + seg_a.size + sum(win[h].size for h in horizons_s)
            for s, (a, b) in enumerate(runs):
                pred[a:b] = flat[offset[first + s]:offset[first + s + 1]]
                if div[first + s] >= 0 and status == "ok":
                    status, at = "diverged", float(t_s[a + div[first + s]])
                    log.warning("%s diverged at t=%.2f s", name, at)
                if band:
                    m0 = band_first + s * band_members
                    members = flat[offset[m0]:offset[m0 + band_members]].reshape(band_members, b - a, -1)
                    with np.errstate(all="ignore"):
                        m, sd = np.nanmean(members, axis=0), np.nanstd(members, axis=0)
                    lo[a:b], hi[a:b] = m - 2 * sd, m + 2 * sd
            run = FreeRun(name, list(dofs), t_s, nu_meas, pred, status, at, (lo, hi) if band else None)
            run.metrics = _metrics(nu_meas, pred, dofs)
        out: dict[str, Any] = {}
        w0 = first + seg_a.size
        for h in horizons_s:
            count, n = win[h].size, win_n[h]
            if count == 0:
                out[f"{h:g}"] = {"n_windows": 0, "n_diverged": 0, "mae_end": None, "mae_window": None}
                continue
            traj = flat[offset[w0]:offset[w0 + count]].reshape(count, n, -1)
            ok = div[w0:w0 + count] < 0
            idx = win[h][:, None] + np.arange(n)
            err = np.abs(traj[ok] - nu_meas[idx[ok]])
            out[f"{h:g}"] = {
                "n_windows": int(count), "n_diverged": int((~ok).sum()),
                "mae_end": {d: float(err[:, -1, j].mean()) if ok.any() else None for j, d in enumerate(dofs)},
                "mae_window": {d: float(err[:, :, j].mean()) if ok.any() else None for j, d in enumerate(dofs)},
            }
            w0 += count
        results[name] = (run, out)
    return results


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


def bridging_markdown(rows: Sequence[Mapping[str, Any]]) -> str:
    """The bridging table as markdown (one row per outage length and model)."""
    def fmt(x: Any) -> str:
        return "-" if x is None else f"{x:.2f}"
    lines = ["| outage (s) | model | windows | diverged | mean error (m) | median (m) | max (m) | distance (m) |",
             "| ---: | --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for r in rows:
        lines.append(f"| {r['window_s']:g} | {r['model']} | {r['n_windows']} | {r['n_diverged']} | "
                     f"{fmt(r['mean_error_m'])} | {fmt(r['median_error_m'])} | {fmt(r['max_error_m'])} | "
                     f"{fmt(r['mean_distance_m'])} |")
    return "\n".join(lines) + "\n"


# --- figures -------------------------------------------------------------------------------------------------------

def plot_free_runs(runs: Sequence[FreeRun], target: Any, title: str = "") -> Any:
    """Fig. 4-like: measured vs predicted velocity per DOF; a diverged model ends with an x and its time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.tableio import atomic_path

    dofs = runs[0].dofs
    fig, axes = plt.subplots(len(dofs), 1, figsize=(10, 2.6 * len(dofs)), sharex=True, squeeze=False)
    for j, d in enumerate(dofs):
        ax = axes[j, 0]
        ax.plot(runs[0].t_s, runs[0].measured[:, j], color="k", lw=1.2, label="measured")
        for run in runs:
            line, = ax.plot(run.t_s, run.predicted[:, j], lw=0.9,
                            label=f"{run.name}" + (f" (diverged at {run.diverged_at_s:.1f} s)"
                                                   if run.status == "diverged" else ""))
            if run.band is not None:  # drawn with its edges, so that it shows among the other models' lines
                ax.fill_between(run.t_s, run.band[0][:, j], run.band[1][:, j], color=line.get_color(), alpha=0.3,
                                lw=0, label=f"{run.name} 2σ band")
                for edge in run.band:
                    ax.plot(run.t_s, edge[:, j], color=line.get_color(), lw=0.6, ls="--")
            if run.status == "diverged" and run.diverged_at_s is not None:
                last = np.flatnonzero(np.isfinite(run.predicted[:, j]) & (run.t_s <= run.diverged_at_s))
                if last.size:
                    ax.plot(run.t_s[last[-1]], run.predicted[last[-1], j], "x", ms=9, color=line.get_color())
        ax.set_ylabel(axis_label(VELOCITY_COLUMNS[d]))
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=7, ncol=3, loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
    return target


def plot_bridging(rows: Sequence[Mapping[str, Any]], target: Any) -> Any:
    """Mean position error at the end of the outage vs outage length, one line per model."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pipeline.tableio import atomic_path

    fig, ax = plt.subplots(figsize=(6, 4))
    for name in dict.fromkeys(r["model"] for r in rows):
        pts = [(r["window_s"], r["mean_error_m"]) for r in rows if r["model"] == name and r["mean_error_m"] is not None]
        if pts:
            x, y = zip(*pts, strict=True)
            ax.plot(x, y, marker="o", label=name, ls="--" if name == "hold_last" else "-")
    ax.set_xlabel("DVL outage (s)")
    ax.set_ylabel("mean position error at end (m)")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(target) as tmp:
        fig.savefig(tmp, format="png", dpi=110, metadata={"Software": None})
    plt.close(fig)
    return target


# --- a synthetic plant with known damping (tests, benchmarks, and the demo until pipeline.sim is used) -------------

def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                     a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]], axis=1)


def coriolis_from_mass(M: np.ndarray, nu: np.ndarray) -> np.ndarray:
    """``C(nu) nu`` of Fossen's skew-symmetric form derived from a 6x6 M, for ``nu (n, 6)``."""
    M = 0.5 * (np.asarray(M) + np.asarray(M).T)
    a = nu @ M[:3].T  # M11 nu1 + M12 nu2
    b = nu @ M[3:].T  # M21 nu1 + M22 nu2
    lin, ang = nu[:, :3], nu[:, 3:]
    return np.hstack([_cross(ang, a), _cross(lin, a) + _cross(ang, b)])


@dataclass
class SyntheticPlant:
    """3 DOF (u, v, r) with diagonal M, damping ``d = l x + q x|x| + c x^3`` (+ a deadband of width ``dead``),
    three thrusters (two surge at +-0.25 m, one lateral at +0.4 m), ``T = k n|n|``."""

    m: tuple[float, float, float] = (80.0, 120.0, 20.0)
    lin: tuple[float, float, float] = (10.0, 20.0, 5.0)
    quad: tuple[float, float, float] = (40.0, 80.0, 10.0)
    cub: tuple[float, float, float] = (60.0, 150.0, 20.0)
    dead: tuple[float, float, float] = (0.0, 0.0, 0.0)
    k_thrust: float = 2e-5

    dofs = ("u", "v", "r")

    def mass_matrix(self) -> np.ndarray:
        return np.diag([self.m[0], self.m[1], 1.0, 1.0, 1.0, self.m[2]])

    def damping(self, dof: str, x: np.ndarray) -> np.ndarray:
        j = self.dofs.index(dof)
        y = self.lin[j] * x + self.quad[j] * x * np.abs(x) + self.cub[j] * x**3
        if self.dead[j] > 0:
            y = y + self.lin[j] * 3 * np.clip(x, -self.dead[j], self.dead[j])
        return y

    def tau(self, rpm: np.ndarray) -> np.ndarray:
        thrust = self.k_thrust * rpm * np.abs(rpm)
        return np.column_stack([thrust[:, 0] + thrust[:, 1], thrust[:, 2],
                                0.25 * (thrust[:, 1] - thrust[:, 0]) + 0.4 * thrust[:, 2]])

    def dynamics(self, nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The true ``nudot(nu, tau)`` over (u, v, r), a :data:`Dynamics`."""
        return self.as_dynamics()(nu, tau)

    def as_dynamics(self) -> DecoupledDynamics:
        return DecoupledDynamics(self.mass_matrix(), self.dofs,
                                 {d: functools.partial(self.damping, d) for d in self.dofs}, coriolis_from_mass)


def synthetic_trial(plant: SyntheticPlant, duration_s: float = 300.0, rate_hz: float = 20.0, seed: int = 0,
                    nu_noise: tuple[float, float, float] = (0.005, 0.005, 0.002), d_noise: float = 2.0,
                    substeps: int = 2, gap_s: tuple[float, float] | None = None) -> Any:
    """A trial table in the feature-store columns, integrated at ``rate_hz * substeps`` with thrust held per
    sample: ``t_ns segment u_mps v_mps r_radps (w p q zero) n1_rpm n2_rpm n3_rpm tau_* d_* (measured: truth +
    noise) dtrue_* yaw_rad x_m y_m``. ``gap_s = (start, stop)`` marks an invalid stretch (segment -1)."""
    import pandas as pd

    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    rpm = np.zeros((n, 3))
    for j, amp in enumerate((2200.0, 2200.0, 2000.0)):
        periods = rng.uniform(15.0, 60.0, 3)
        phases = rng.uniform(0, 2 * np.pi, 3)
        sig = sum(np.sin(2 * np.pi * t / p + ph) for p, ph in zip(periods, phases, strict=True)) / 2.0
        steps = np.repeat(rng.uniform(-0.4, 0.4, n // 200 + 1), 200)[:n]
        rpm[:, j] = amp * np.clip(sig + steps, -1, 1)
    tau = plant.tau(rpm)
    f = plant.as_dynamics()
    dt = 1.0 / rate_hz
    h = dt / substeps
    nu = np.zeros((n, 3))
    yaw = np.zeros(n)
    pos = np.zeros((n, 2))
    state = np.zeros((1, 3))
    psi, p = 0.0, np.zeros(2)
    for i in range(n):
        nu[i], yaw[i], pos[i] = state[0], psi, p
        for _ in range(substeps):
            k1 = f(state, tau[i][None])
            k2 = f(state + 0.5 * h * k1, tau[i][None])
            k3 = f(state + 0.5 * h * k2, tau[i][None])
            k4 = f(state + h * k3, tau[i][None])
            u, v, r = state[0]
            p = p + h * np.array([u * np.cos(psi) - v * np.sin(psi), u * np.sin(psi) + v * np.cos(psi)])
            psi += h * r
            state = state + h * (k1 + 2 * k2 + 2 * k3 + k4) / 6
    meas = nu + rng.standard_normal(nu.shape) * np.asarray(nu_noise)
    cols: dict[str, Any] = {"t_ns": (t * 1e9).round().astype(np.int64), "segment": np.zeros(n, dtype=np.int32)}
    for j, d in enumerate(plant.dofs):
        cols[VELOCITY_COLUMNS[d]] = meas[:, j]
    for d in ("w", "p", "q"):
        cols[VELOCITY_COLUMNS[d]] = np.zeros(n)
    for j in range(3):
        cols[f"n{j + 1}_rpm"] = rpm[:, j]
    for d in DOFS:
        j = plant.dofs.index(d) if d in plant.dofs else None
        cols[TAU_COLUMNS[d]] = tau[:, j] if j is not None else np.zeros(n)
        true = plant.damping(d, nu[:, j]) if j is not None else np.zeros(n)
        cols[DAMPING_COLUMNS[d]] = true + (d_noise * rng.standard_normal(n) if j is not None else 0.0)
        cols["dtrue_" + DAMPING_COLUMNS[d][2:]] = true
    cols.update(yaw_rad=yaw, x_m=pos[:, 0], y_m=pos[:, 1], roll_rad=np.zeros(n), pitch_rad=np.zeros(n))
    df = pd.DataFrame(cols)
    if gap_s is not None:
        df.loc[(t >= gap_s[0]) & (t < gap_s[1]), "segment"] = -1
        df.loc[t >= gap_s[1], "segment"] = 1
    return df
