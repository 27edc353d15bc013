"""Free runs and error growth over horizons: every model rolled out over a trial's valid runs from its measured
initial velocity, and from measurement at the start of consecutive windows of each horizon.

Gaps (``segment == -1`` or a jump in ``t_ns``) restart a rollout from measurement. The GP's band: Monte Carlo over
posterior *functions* (``DampingGP.sample_functions`` on the table grid, fixed seed), each rolled out as one member
of the batch; the band is the mean +- 2 sd of the members. Every run, band member and window of every model that
reads the same inputs is one member of one batch (:func:`run_models`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from pipeline.rollout.dynamics import Dynamics, stack
from pipeline.rollout.integrate import rollout_ragged
from pipeline.rollout.tables import take

log = logging.getLogger(__name__)


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
    """One model's free run over a trial; ``predicted`` is NaN where not rolled out (gaps, after divergence)."""

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
    (:func:`run_model`).
    """
    return run_model(name, f, t_ns, nu_meas, inputs, dofs, segment=segment, divergence_factor=divergence_factor,
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
    horizons one batch, :func:`run_model`)."""
    return run_model("", f, t_ns, nu_meas, inputs, dofs, horizons_s, segment=segment,
                          divergence_factor=divergence_factor, method=method, free=False)[1]


def run_model(name: str, f: Dynamics, t_ns: np.ndarray, nu_meas: np.ndarray, inputs: np.ndarray,
                   dofs: Sequence[str], horizons_s: Sequence[float] = (), *, segment: np.ndarray | None = None,
                   divergence_factor: float = 10.0, method: str = "rk4", band_f: Dynamics | None = None,
                   band_members: int = 0, free: bool = True) -> tuple[FreeRun | None, dict[str, Any]]:
    """One model's free run (``free``; with ``band_f``'s members) and horizon errors from one batched rollout
    (:func:`run_models`). Returns ``(FreeRun or None, horizons)``."""
    return run_models({name: (f, band_f)}, t_ns, nu_meas, inputs, dofs, horizons_s, segment=segment,
                           divergence_factor=divergence_factor, method=method, band_members=band_members,
                           free=free)[name]


def run_models(models: Mapping[str, tuple[Dynamics, Dynamics | None]], t_ns: np.ndarray, nu_meas: np.ndarray,
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
