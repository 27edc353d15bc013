"""The vehicle's own model as the smoother's process equation: what the logged actuators say about the
acceleration, so that the smoother need not guess it from the velocity sensors alone.

The white-jerk smoother (:mod:`pipeline.estimation.smoother`) models each DOF's acceleration as a smooth unknown
function; fast thrust changes (a thruster reversed in a fraction of a second) then look like noise, and the
3.6 Hz DVL cannot resolve them. But the logged thruster speeds give the thrust exactly, so the acceleration is

    nu_dot = a(t) + b(t),        a(t) = M^-1 (tau(t) - g(eta) - C(nu) nu - d_hat(nu)),

with ``a`` known on the grid and ``b`` what the model does not know (damping errors, currents, a tether),
modelled per DOF by the same white-jerk process as before. With ``U(t) = int a dt``, the state
``w = nu - U`` follows the white-jerk model exactly, measured by ``y - U(t)`` (a velocity sample) or
``y - a(t)`` (a measured acceleration). So the smoother, its exact likelihood and its variances are reused
unchanged (a known input shifts the mean, not the covariance: Särkkä, *Bayesian Filtering and Smoothing*, 2013,
eqs. 4.20-4.21 p. 57 with a control input, and 8.6 p. 136 for the RTS smoother), and the likelihood of the
measurements under each model is directly comparable (the change of variables has unit Jacobian).

Passes (the scheme of Alexandersson, Mao & Ringsberg, Ocean Eng. 266 (2022) 112940, §3: a filter and smoother
with the vehicle model, then inverse dynamics): pass 1 uses a = M^-1 (tau - g); each later pass fits the damping
``d_hat`` by least squares on the previous estimates (linear and quadratic terms, :func:`fit_damping`) and adds
C(nu) nu and d_hat(nu) from them. Per DOF the smoother keeps whichever pass, the kinematic one included, has the
highest likelihood; the passes stop when none improves.

Piecewise-linear ``a`` between grid samples: U at t_k + delta h is U_k + h (a_k delta + (a_{k+1} - a_k)
delta^2 / 2), exact for that interpolation.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
import pandas as pd

from pipeline import physics
from pipeline.config.vehicle import Vehicle
from pipeline.estimation.noise import estimate_noise
from pipeline.estimation.smoother import Measurements, Smoothed, smooth, smoothed_variances

log = logging.getLogger(__name__)

__all__ = ["ForceModel", "covered", "fit_damping", "force_model", "input_at", "smooth_with_input"]


@dataclass(frozen=True)
class ForceModel:
    """What the vehicle config and the logged actuators give on the grid: M, M^-1, tau (N, 6) and g(eta) (N, 6)."""

    M: np.ndarray
    M_inv: np.ndarray
    tau: np.ndarray
    g: np.ndarray
    # the variance of M^-1 tau per sample from the actuator signals' own noise (estimated from the data)
    noise_var: np.ndarray | None = None

    def acceleration(self, nu: np.ndarray | None = None, damping: np.ndarray | None = None) -> np.ndarray:
        """a = M^-1 (tau - g - C(nu) nu - d_hat) on the grid (N, 6); without ``nu``, a = M^-1 (tau - g)."""
        force = self.tau - self.g
        if nu is not None:
            force = force - physics.coriolis_force(self.M, nu)
        if damping is not None:
            force = force - damping
        return force @ self.M_inv.T


def force_model(synced: pd.DataFrame, body: pd.DataFrame, vehicle: Vehicle) -> ForceModel | None:
    """The force model on the synced grid, or None when the vehicle has no thrusters (nothing to model). Each
    thruster input is smoothed by the white-jerk smoother with its own noise estimated from the data (bridging
    invalid samples, which are unusable anyway), and what the smoother leaves of that noise is counted in
    ``noise_var``."""
    if not vehicle.thrusters:
        return None
    grid = synced["t_ns"].to_numpy(dtype=np.int64)
    speeds = np.zeros((grid.size, len(vehicle.thrusters)))
    sd = np.zeros_like(speeds)
    runs = []
    for i, thr in enumerate(vehicle.thrusters):  # each input smoothed with its own noise (a counter's steps too)
        x = synced[thr.input_signal].to_numpy(dtype=float)
        ok = np.isfinite(x)
        if ok.sum() < 3:
            continue
        noise = estimate_noise(grid[ok] / 1e9, x[ok]).sd
        if not np.isfinite(noise) or noise <= 0:
            speeds[:, i] = np.interp(grid, grid[ok], x[ok])
            continue
        runs.append((i, smooth(grid, Measurements(grid[ok], x[ok], noise**2), gate=0)))
    smoothed_variances([res for _, res in runs])
    for i, res in runs:
        speeds[:, i], sd[:, i] = res.x, res.x_sd
    B = physics.allocation_matrix(vehicle)
    tau = physics.thrusts(vehicle, speeds) @ B.T
    M = physics.mass_matrix(vehicle)
    M_inv = np.linalg.inv(M)
    g = physics.restoring_force(vehicle, body["roll_rad"].to_numpy(dtype=float),
                                body["pitch_rad"].to_numpy(dtype=float))
    # what is left of each input's noise, through the thrust map's slope (numerical) and M^-1 B
    step = np.maximum(sd, 1e-6 * np.maximum(np.abs(speeds).max(axis=0), 1.0))
    slope = (physics.thrusts(vehicle, speeds + step) - physics.thrusts(vehicle, speeds - step)) / (2 * step)
    noise_var = ((slope * sd) ** 2) @ ((M_inv @ B) ** 2).T
    return ForceModel(M=M, M_inv=M_inv, tau=tau, g=np.atleast_2d(g), noise_var=noise_var)


#: A vehicle symmetric port-starboard: its damping couples the longitudinal DOFs (u, w, q) among themselves and
#: the lateral ones (v, p, r) among themselves, not across (Fossen 2011, §7.5.2, p. 172, the decoupled
#: longitudinal and lateral models). Across the groups a coupling would also absorb a DVL misalignment (v
#: measured with a share of u) into the model.
_GROUPS = ((0, 2, 4), (1, 3, 5))


def damping_features(nu: np.ndarray, dof: int, dofs: list[int]) -> np.ndarray:
    """Regressors of d_hat for DOF ``dof``: a constant, the measured DOFs of its group (linear), its own nu |nu|."""
    group = next(g for g in _GROUPS if dof in g)
    cols = [np.ones(nu.shape[0])] + [nu[:, j] for j in dofs if j in group] + [nu[:, dof] * np.abs(nu[:, dof])]
    return np.stack(cols, axis=1)


def fit_damping(model: ForceModel, nu: np.ndarray, nudot: np.ndarray, rows: np.ndarray, dofs: list[int]
                ) -> np.ndarray:
    """d_hat(nu) on the grid (N, 6): per measured DOF, least squares of the damping target
    d = tau - M nu_dot - C(nu) nu - g on :func:`damping_features`, over ``rows``; zero for the other DOFs."""
    target = physics.damping_target(model.M, model.tau, nudot, nu, model.g)
    out = np.zeros_like(nu)
    for j in dofs:
        X = damping_features(nu, j, dofs)
        if rows.sum() <= X.shape[1]:
            continue
        coef, *_ = np.linalg.lstsq(X[rows], target[rows, j], rcond=None)
        out[:, j] = X @ coef
    return out


def _cumulative(a: np.ndarray, h_s: float) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(0.5 * h_s * (a[1:] + a[:-1]))])


def input_at(grid_ns: np.ndarray, a: np.ndarray, t_ns: np.ndarray, order: np.ndarray | int = 0
             ) -> tuple[np.ndarray, np.ndarray]:
    """The known input at measurement stamps: U(t) for value measurements (order 0), a(t) for derivative ones
    (order 1); and U on the grid. Stamps outside the grid get the end values (the smoother drops them)."""
    h_ns = int(grid_ns[1] - grid_ns[0])
    h_s = h_ns / 1e9
    U = _cumulative(a, h_s)
    rel = np.clip(np.asarray(t_ns, dtype=np.int64) - int(grid_ns[0]), 0, (grid_ns.size - 1) * h_ns)
    k = np.minimum(rel // h_ns, grid_ns.size - 2)
    delta = (rel - k * h_ns) / h_ns
    slope = a[k + 1] - a[k]
    value = U[k] + h_s * (a[k] * delta + slope * delta**2 / 2)
    rate = a[k] + slope * delta
    return np.where(np.asarray(order) == 1, rate, value), U


def smooth_with_input(grid_ns: np.ndarray, meas: Measurements, a: np.ndarray | None, **kwargs) -> Smoothed:
    """:func:`pipeline.estimation.smoother.smooth` of nu_dot = a + b (see the module docstring); ``a`` None: the
    kinematic smoother itself. SDs are filled later by ``smoothed_variances`` (unchanged by a known input)."""
    if a is None:
        return smooth(grid_ns, meas, **kwargs)
    shift, U = input_at(grid_ns, a, meas.t_ns, meas.order)
    res = smooth(grid_ns, Measurements(meas.t_ns, meas.y - shift, meas.var, meas.order), **kwargs)
    if res.s > 0:
        # with the input's error e in the model, w = nu - U moves by b + e: x' is the smooth part b alone, while
        # w's increments also hold what the measurements say about e (inner samples; the ends keep x')
        res.xdot = res.xdot.copy()
        res.xdot[1:-1] = (res.x[2:] - res.x[:-2]) / (2 * res.h_s)
    res.x = res.x + U
    res.xdot = res.xdot + a
    res.xddot = res.xddot + np.gradient(a, res.h_s)
    return res


_MODELS = ("kinematic", "thrust", "thrust, Coriolis and fitted damping")


def covered(grid_ns: np.ndarray, meas: dict[str, Measurements], max_gap_s: float) -> np.ndarray:
    """Grid samples within ``max_gap_s`` of a measurement of every DOF: where the first pass's estimates are
    measured, not bridged, and the damping fit may use them."""
    ok = np.ones(grid_ns.size, dtype=bool)
    for m in meas.values():
        t = np.sort(m.t_ns)
        if t.size == 0:
            return np.zeros(grid_ns.size, dtype=bool)
        i = np.clip(np.searchsorted(t, grid_ns), 1, max(t.size - 1, 1))
        near = np.minimum(np.abs(grid_ns - t[i - 1]), np.abs(t[np.minimum(i, t.size - 1)] - grid_ns))
        ok &= near <= max_gap_s * 1e9
    return ok


def smooth_passes(grid_ns: np.ndarray, meas: dict[str, Measurements], model: ForceModel | None, *, passes: int,
                  process_noise: dict[str, float], gate: float, dofs: tuple[str, ...],
                  fixed: dict[str, Smoothed] | None = None
                  ) -> tuple[dict[str, Smoothed], dict[str, np.ndarray | None], dict]:
    """Per measured DOF, the smoothed result (SDs filled) of the model chosen, the known input it used (None: the
    kinematic smoother) and a report of the passes.

    Pass 0 is the kinematic smoother, whose residual gate fixes the measurements every later pass is scored on
    (so their likelihoods compare). Pass 1 adds a = M^-1 (tau - g); pass k > 1 also C(nu) nu and the damping
    fitted on the best estimates so far. A DOF takes a pass's result when it raises the DOF's log-likelihood
    (so the passes never lower it) and the model's own error leaves nu_dot no less known (median SD) than the
    kinematic pass: an input noisier than what it explains (the AHRS's angle noise times a restoring moment,
    say) is absorbed by the input-error term, which raises the likelihood but not the derivative's quality. The
    passes stop after ``passes`` or when no DOF gains (from pass 2 on: pass 1, without the damping, may lose
    where pass 2 wins); from pass 3 on, only the DOFs the previous pass improved are smoothed again.
    ``fixed``: other DOFs' results, not smoothed again, whose nu and nu_dot enter the model as they are (the
    velocity sensor's DOFs smoothed again after its misalignment is undone).
    """
    best: dict[str, Smoothed] = {}
    for dof, m in meas.items():
        try:
            best[dof] = smooth(grid_ns, m, q=process_noise.get(dof), gate=gate)
        except ValueError as err:
            raise ValueError(f"{dof}: {err}") from err
    chosen = {dof: 0 for dof in best}
    inputs: dict[str, np.ndarray | None] = {dof: None for dof in best}
    noise_var = {dof: None for dof in best}
    kinematic_sd = _median_sds(best, {}, {})
    history = [_record(0, best, kinematic_sd)]
    if model is not None and passes > 0:
        pass0_kept = {dof: best[dof].kept for dof in best}
        kept = {dof: m.subset(best[dof].kept) for dof, m in meas.items()}
        context = dict(fixed or {})
        index = {dof: dofs.index(dof) for dof in [*best, *context]}
        if model.noise_var is not None:
            noise_var = {dof: model.noise_var[:, index[dof]] for dof in best}
        rows = covered(grid_ns, {d: kept[d] for d in best if d in "uvw"} or kept, max_gap_s=0.5)
        active = list(best)
        for k in range(1, passes + 1):
            if k == 1:
                a = model.acceleration()
            else:
                nu = np.zeros((grid_ns.size, len(dofs)))
                nudot = np.zeros_like(nu)
                for dof, res in {**context, **best}.items():
                    nu[:, index[dof]], nudot[:, index[dof]] = res.x, res.xdot
                a = model.acceleration(nu, fit_damping(model, nu, nudot, rows, sorted(index.values())))
            step = {dof: smooth_with_input(grid_ns, kept[dof], a[:, index[dof]], q=process_noise.get(dof),
                                           gate=0, input_error=True)
                    for dof in active}
            candidates = {dof: res for dof, res in step.items() if res.loglik > best[dof].loglik}
            sds = _median_sds(candidates, {dof: a[:, index[dof]] for dof in candidates}, noise_var)
            gained = [dof for dof in candidates if sds[dof] <= kinematic_sd[dof]]
            for dof in gained:
                best[dof], chosen[dof], inputs[dof] = step[dof], k, a[:, index[dof]]
                full = np.zeros(meas[dof].t_ns.size, dtype=bool)  # kept: of the given measurements, as pass 0's
                full[np.flatnonzero(pass0_kept[dof])[step[dof].kept]] = True
                best[dof].kept = full
            history.append(_record(k, step, sds))
            if k >= 2:  # from pass 3 on, only the DOFs the last pass improved (the others' input hardly moved)
                active = gained
            log.info("smoother pass %d (%s): higher likelihood for %s", k, _MODELS[min(k, 2)],
                     ", ".join(gained) or "none")
            if not gained and k >= 2:  # pass 1 lacks the damping, which pass 2 adds: always try both
                break
    smoothed_variances(list(best.values()))
    for dof, res in best.items():
        if inputs[dof] is not None:
            _input_error_sd(res, inputs[dof], noise_var[dof])
    return best, inputs, {"passes": history, "chosen": chosen, "force_model": model is not None}


#: The passes compare median SDs of nu_dot over the trial's middle stretch of this many grid steps (the full SDs
#: are computed once, for the results kept)
GUARD_STEPS = 6000


def _median_sds(results: dict[str, Smoothed], inputs: dict[str, np.ndarray],
                noise_var: dict[str, np.ndarray | None]) -> dict[str, float]:
    """Each result's median SD of nu_dot (with the input's error where it has an input) over the middle stretch."""
    windows = {}
    for dof, res in results.items():
        lo = max((res.x.size - GUARD_STEPS) // 2, 0)
        cut = slice(lo, lo + GUARD_STEPS)
        windows[dof] = (Smoothed(x=res.x[cut], xdot=res.xdot[cut], q=res.q, loglik=res.loglik, used=res.used,
                                 gated=res.gated, info=res.info[cut], h_s=res.h_s, s=res.s), cut)
    smoothed_variances([w for w, _ in windows.values()])
    out = {}
    for dof, (window, cut) in windows.items():
        if dof in inputs:
            extra = noise_var.get(dof)
            _input_error_sd(window, inputs[dof], None if extra is None else extra[cut])
        out[dof] = float(np.median(window.xdot_sd))
    return out


def _input_error_sd(res: Smoothed, a: np.ndarray, noise_var: np.ndarray | None) -> None:
    """Add the input's error to nu_dot's SD (the smooth part's posterior so far).

    The smoother models the input's error e white, but its pointwise size cannot come from that model
    (measurements at a few Hz do not see e's fast content, and a white e has no pointwise variance). Two parts:
    the actuator signals' own noise left after smoothing them (``noise_var``), and the model's error, which
    follows the thrust (a gain, a lag): the level s the data resolve over the input's own bandwidth B (Rice's
    mean frequency, sqrt(var a' / var a) / 2 pi), var = 2 s B.
    """
    spread = float(np.var(a))
    bandwidth = np.sqrt(float(np.var(np.diff(a) / res.h_s)) / spread) / (2 * np.pi) if spread > 0 else 0.0
    extra = 0.0 if noise_var is None else noise_var
    res.xdot_sd = np.sqrt(res.xdot_sd**2 + 2 * res.s * bandwidth + extra)


def _record(k: int, results: dict[str, Smoothed], median_sd: dict[str, float]) -> dict:
    return {"pass": k, "model": _MODELS[min(k, 2)],
            "loglik": {d: float(r.loglik) for d, r in results.items()},
            "process_noise": {d: float(r.q) for d, r in results.items()},
            "input_error": {d: float(r.s) for d, r in results.items()},
            "median_acceleration_sd": median_sd}


def excitation_report(grid_ns: np.ndarray, model: ForceModel | None, meas: dict[str, Measurements],
                      history: list[dict]) -> dict[str, dict[str, float]]:
    """Per linear-velocity DOF, the band its velocity sensor resolves and the share of the thrust-driven
    acceleration's power above it: a trial whose excitation outruns its sensors says so.

    The band: where the kinematic smoother's process (white jerk: the velocity's spectrum q / omega^6) meets the
    sensor's white noise (r T: variance r every T seconds), f_c = (q / (r T))^(1/6) / 2 pi. The acceleration:
    a = M^-1 (tau - g) from the logged actuators (pass 1's input), its periodogram over the trial.
    """
    if model is None:
        return {}
    a = model.acceleration()
    h_s = (grid_ns[1] - grid_ns[0]) / 1e9
    out = {}
    for j, dof in enumerate("uvw"):
        if dof not in meas or meas[dof].t_ns.size < 3:
            continue
        q = history[0]["process_noise"][dof]
        r = float(np.median(meas[dof].var))
        interval = float(np.median(np.diff(np.sort(meas[dof].t_ns)))) / 1e9
        f_c = (q / (r * interval)) ** (1 / 6) / (2 * np.pi)
        power = np.abs(np.fft.rfft(a[:, j] - a[:, j].mean())) ** 2
        freq = np.fft.rfftfreq(a.shape[0], h_s)
        total = float(power[1:].sum())
        out[dof] = {"resolved_band_hz": float(f_c),
                    "power_above_band": float(power[freq > f_c].sum() / total) if total > 0 else 0.0}
    return out
