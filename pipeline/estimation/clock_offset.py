"""The actuator stream's clock offset, found per trial from how well the vehicle's model explains the motion.

A thruster speed logged ``delta`` late (a Hall counter stamps the mean speed over its counting window at the
window's end: half a window late) puts an error of about delta times the input's rate of change into the model's
acceleration a(t) = M^-1 (tau - ...) of :mod:`pipeline.estimation.forced`: an error that follows the thrust, slow
and correlated, which neither the white input error e nor the smooth unknown b describes. The signals alone do not
show a delay; the motion does. The estimate is a profile likelihood, as for the velocity sensor's misalignment
(:mod:`pipeline.estimation.dvl_alignment`): tau(t + delta) for each delta of a grid (the thrust map is pointwise, so
shifting tau is shifting the actuator signals before it is formed; between grid steps tau is interpolated linearly),
each DOF that took the model smoothed with its final pass's input so shifted (the damping fitted again on the
shifted thrust: fitted on the late one, it takes up part of the delay's error and pulls the estimate towards 0) and
its process noises, their log-likelihoods summed; a parabola through the best grid point and its two neighbours
gives delta and its SD (the curvature: the observed information); a best point at the grid's edge gives none. The
curvature assumes the model right; its misfit (a damping the fit lacks, a tether) is slow and correlated and moves
the estimate further than that SD says, so the window is cut into ``segments`` stretches smoothed apart and the SD
is the larger of the curvature's and the sandwich's (the stretches' slopes at the estimate, their spread over the
total curvature; a batch-means variance). The likelihood of one DOF under several inputs costs one factorization
(:func:`pipeline.estimation.smoother.logliks`: an input moves the mean, not the covariance), and the profile runs on
the trial's middle stretch (``window_s``), so it costs a few banded solves per DOF whatever the trial's length.

The estimate is combined with a prior on the configured offset (the stream's ``offset_s``, already applied to the
stamps at ingest: a zero-mean Gaussian of SD ``differentiate.actuator_offset_sd_s``; precisions add), and the
posterior is applied (tau shifted, the passes run again) where it lies more than two of its own SDs
(``APPLY_SDS``) from the configured offset and at least a quarter of the grid step (``MIN_STEP_FRACTION``) from it.
"""

from __future__ import annotations

import logging
from dataclasses import asdict, dataclass, replace

import numpy as np
import pandas as pd

from pipeline import physics
from pipeline.estimation.dvl_alignment import zero_mean_posterior
from pipeline.estimation.forced import ForceModel, covered, damping_features, input_at
from pipeline.estimation.smoother import Measurements, Smoothed, logliks
from pipeline.sync import valid_column

log = logging.getLogger(__name__)

#: The posterior is applied where it lies this many SDs from the configured offset: applying costs a second set of
#: passes, and a no-delay trial's estimate within 2 SD of 0 changes nothing material (docs/benchmarks.md)
APPLY_SDS = 2.0
#: ... and at least this fraction of the grid step from it: a smaller shift moves tau by less than a quarter of a
#: sample (a few ms on a one-hour gentle trial, where it changed no R^2 by 0.001) for the price of the passes again
MIN_STEP_FRACTION = 0.25

__all__ = ["APPLY_SDS", "MIN_STEP_FRACTION", "ClockOffset", "estimate_actuator_offset", "read_later", "shift_columns",
           "shifted"]


@dataclass(frozen=True)
class ClockOffset:
    """The actuator stream's clock offset (seconds, how late its stamps are after the configured offset): the
    trial's own estimate and SD (the profile likelihood; None where there is none), whether the trial alone pins
    it down (``identifiable``), the estimate combined with the prior (``posterior_s``, ``posterior_sd_s``), and
    whether that was applied (``applied``: further from the configured offset than ``APPLY_SDS`` of its SDs)."""

    estimate_s: float | None
    sd_s: float | None
    identifiable: bool
    reason: str | None = None
    dofs: tuple[str, ...] = ()
    posterior_s: float = 0.0
    posterior_sd_s: float = 0.0
    applied: bool = False

    def as_dict(self) -> dict:
        out = asdict(self)
        out["dofs"] = list(self.dofs)
        return out

    def with_prior(self, prior_sd_s: float, min_s: float = 0.0) -> ClockOffset:
        """Combined with a zero-mean prior of SD ``prior_sd_s`` on the configured offset (Gaussian: precisions
        add), applied beyond ``APPLY_SDS`` of its SDs and ``min_s`` seconds; without a likelihood the posterior is
        the prior; a prior SD of 0 keeps the configured offset."""
        if prior_sd_s <= 0:
            return replace(self, posterior_s=0.0, posterior_sd_s=0.0, applied=False)
        if self.estimate_s is None or self.sd_s is None:
            return replace(self, posterior_s=0.0, posterior_sd_s=prior_sd_s, applied=False)
        mean, sd = zero_mean_posterior(self.estimate_s, self.sd_s, prior_sd_s)
        return replace(self, posterior_s=mean, posterior_sd_s=sd, applied=bool(abs(mean) > max(APPLY_SDS * sd, min_s)))


def read_later(x: np.ndarray, steps: float) -> np.ndarray:
    """``x`` (samples along axis 0 of a uniform grid) read ``steps`` grid steps later: x(t + steps h), linear
    between grid steps, the ends held; exact at whole steps."""
    n = x.shape[0]
    at = np.clip(np.arange(n) + steps, 0.0, n - 1.0)
    k = np.minimum(np.floor(at).astype(np.int64), max(n - 2, 0))
    frac = at - k
    frac = frac.reshape((n,) + (1,) * (x.ndim - 1))
    return x[k] * (1.0 - frac) + x[np.minimum(k + 1, n - 1)] * frac


def shifted(model: ForceModel, offset_s: float, h_s: float) -> ForceModel:
    """``model`` with its actuator forces read ``offset_s`` later: tau(t + offset) (and their noise variance),
    by :func:`read_later`. A stream logged ``offset_s`` late is undone by this."""
    noise = None if model.noise_var is None else read_later(model.noise_var, offset_s / h_s)
    return replace(model, tau=read_later(model.tau, offset_s / h_s), noise_var=noise)


def shift_columns(table: pd.DataFrame, synced: pd.DataFrame, columns: list[str], offset_s: float, h_s: float
                  ) -> np.ndarray:
    """The actuator signals ``columns`` of ``synced`` read ``offset_s`` later into ``table`` (same grid), so that
    what the later stages form from them (derive's tau) has the timing the smoother found. Moved by the nearest
    whole number of grid steps, the ends held: interpolating between steps would smooth a counter's steps, whose
    noise derive estimates from the signal itself for tau's SD. Returns where every one is valid after the move
    (``valid_column`` flags of ``synced``; a column without one counts as valid)."""
    steps = int(np.rint(offset_s / h_s))
    n = len(synced)
    rows = np.clip(np.arange(n) + steps, 0, n - 1)
    ok = np.ones(n, dtype=bool)
    for col in columns:
        table[col] = synced[col].to_numpy()[rows]
        flag = valid_column(col)
        if flag in synced.columns:
            ok &= synced[flag].to_numpy(dtype=bool)[rows]
    return ok


def estimate_actuator_offset(grid_ns: np.ndarray, meas: dict[str, Measurements], results: dict[str, Smoothed],
                             inputs: dict[str, np.ndarray | None], chosen: dict[str, int], model: ForceModel,
                             dofs: tuple[str, ...], *, span_s: float = 0.25, points: int = 11,
                             window_s: float = 300.0, segments: int = 6, max_sd_s: float = 0.05) -> ClockOffset:
    """The profile likelihood of the actuator stream's clock offset (see the module docstring). ``meas``: each
    DOF's measurements as the passes got them; ``results``, ``inputs``, ``chosen``: the passes' chosen results,
    the inputs they used (None: kinematic) and which pass (1: thrust alone; 2 on: with Coriolis and the fitted
    damping, refitted here for each offset: fitted on the late thrust, the damping takes up part of the delay's
    error and would pull the estimate towards 0); ``dofs``: the model's DOF order. Offsets from ``-span_s`` to
    ``span_s`` (``points`` of them), on the middle ``window_s`` seconds of the grid, cut into ``segments``
    stretches smoothed apart for the SD's sandwich (module docstring)."""
    took = [dof for dof in meas if inputs.get(dof) is not None]
    if not took:
        return ClockOffset(None, None, False, "no DOF took the vehicle's model: the actuators' timing does not "
                                              "enter the estimates")
    h_s = (int(grid_ns[1]) - int(grid_ns[0])) / 1e9
    steps = min(grid_ns.size, max(int(window_s / h_s), 3))
    lo = (grid_ns.size - steps) // 2
    cut = slice(lo, lo + steps)
    grid = grid_ns[cut]
    index = {dof: dofs.index(dof) for dof in results}
    nu = np.zeros((steps, len(dofs)))
    nudot = np.zeros_like(nu)
    for dof, res in results.items():
        nu[:, index[dof]], nudot[:, index[dof]] = res.x[cut], res.xdot[cut]
    kept = {}
    for dof in meas:  # the kept measurements within the window, of the DOFs scored or covering the damping's rows
        if dof in took or dof in "uvw":
            m = meas[dof].subset(results[dof].kept)
            kept[dof] = m.subset((m.t_ns >= grid[0]) & (m.t_ns <= grid[-1]))
    rows = covered(grid, {d: kept[d] for d in kept if d in "uvw"} or kept, max_gap_s=0.5)
    g = model.g[cut] if model.g.shape[0] == grid_ns.size else model.g
    base = physics.damping_target(model.M, np.zeros((steps, len(dofs))), nudot, nu, g)  # d = tau + base
    coriolis = physics.coriolis_force(model.M, nu)
    fitted = sorted(index.values())
    # the damping's least squares, fixed but for its target (tau moves with the offset): one pseudo-inverse each
    fits = [(j, X, np.linalg.pinv(X[rows])) for j in fitted
            if rows.sum() > (X := damping_features(nu, j, fitted)).shape[1]]
    bounds = np.linspace(0, steps, segments + 1).astype(np.int64)
    scored: set[str] = set()

    def profile(offsets: np.ndarray) -> np.ndarray:
        """Log-likelihoods (segments, offsets), summed over the DOFs that took the model."""
        per_offset = []
        for d in offsets:
            at = np.clip(np.arange(lo, lo + steps) + d / h_s, 0.0, grid_ns.size - 1.0)
            k0 = np.minimum(np.floor(at).astype(np.int64), max(grid_ns.size - 2, 0))
            frac = (at - k0)[:, None]
            tau = model.tau[k0] * (1.0 - frac) + model.tau[np.minimum(k0 + 1, grid_ns.size - 1)] * frac
            damping = np.zeros_like(tau)
            for j, X, pinv in fits:
                damping[:, j] = X @ (pinv @ (tau[rows, j] + base[rows, j]))
            per_offset.append(((tau - g) @ model.M_inv.T, (tau - g - coriolis - damping) @ model.M_inv.T))
        parts = np.zeros((segments, len(offsets)))
        for dof in took:
            j = index[dof]
            for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
                part = kept[dof].subset((kept[dof].t_ns >= grid[a]) & (kept[dof].t_ns <= grid[b - 1]))
                xs = [(plain if chosen.get(dof, 2) == 1 else damped)[a:b, j] for plain, damped in per_offset]
                try:
                    parts[k] += logliks(grid[a:b], part, [input_at(grid[a:b], x, part.t_ns, part.order)[0]
                                                          for x in xs], q=results[dof].q, s=results[dof].s)
                except ValueError:  # too few measurements in this stretch: it says nothing here
                    continue
                scored.add(dof)
        return parts

    coarse = np.linspace(-span_s, span_s, points)
    coarse_parts = profile(coarse)
    total = coarse_parts.sum(axis=0)
    took = [dof for dof in took if dof in scored]
    if not took:
        return ClockOffset(None, None, False, "too few measurements in the profile's window")
    best = int(np.argmax(total))
    if best in (0, points - 1):
        return ClockOffset(None, None, False, f"the likelihood's maximum lies at ±{span_s} s or beyond", tuple(took))
    # refined: the best coarse offset and its neighbours half a coarse step away
    half = (coarse[1] - coarse[0]) / 2
    offsets = coarse[best] + np.array([-half, 0.0, half])
    fine = profile(offsets[[0, 2]])
    parts = np.stack([fine[:, 0], coarse_parts[:, best], fine[:, 1]], axis=1)
    total = parts.sum(axis=0)
    a2, a1, _ = np.polyfit(offsets, total - total[1], 2)
    if a2 >= 0:
        return ClockOffset(None, None, False, "the likelihood has no maximum in the actuators' offset", tuple(took))
    estimate, sd = float(-a1 / (2 * a2)), float(np.sqrt(-1.0 / (2 * a2)))
    # the sandwich: each stretch's slope at the estimate, their spread against the total curvature
    slopes = [np.polyval(np.polyder(np.polyfit(offsets, part, 2)), estimate) for part in parts]
    robust = float(np.sqrt(segments / (segments - 1) * np.sum(np.square(slopes))) / (-2 * a2))
    sd = max(sd, robust)
    if sd > max_sd_s:
        return ClockOffset(estimate, sd, False, f"SD {sd:.2g} s above {max_sd_s} s: the trial's thrust does not "
                           "pin the actuators' timing down", tuple(took))
    return ClockOffset(estimate, sd, True, None, tuple(took))
