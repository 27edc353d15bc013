"""Rate-sensor bias from the AHRS attitude: a constant bias per rate signal (FOG, gyro), with its SD.

A gyro or FOG reads omega_m = omega + b + noise, with b a constant (its bias plus the Earth's rotation, 7.3e-5
rad/s at most, seen in body axes). The attitude the trial logs is not integrated from those rates (an AHRS
takes roll and pitch from gravity, yaw from a magnetometer or its own filter), so it tells b apart: the Euler
angles Theta = (phi, theta, psi) move with the body rates as

    Theta_dot = T(Theta) omega,   T = [[1, sin(phi) tan(theta), cos(phi) tan(theta)],
                                       [0, cos(phi),            -sin(phi)           ],
                                       [0, sin(phi) / cos(theta), cos(phi) / cos(theta)]]

(Fossen, *Handbook of Marine Craft Hydrodynamics and Motion Control*, Wiley 2011, §2.2.1, eq. 2.29, p. 25;
e.g. psi_dot = (q sin(phi) + r cos(phi)) / cos(theta)). Integrating the measured rates through it, each at its
own stamps with T at the attitude interpolated there,

    D_i(t) = sum_j int_0^t T_ij omega_m,j ds - Theta_i(t) = c_i + sum_j B_ij(t) b_j + e_i(t),
    B_ij(t) = int_0^t T_ij(Theta(s)) ds,

a regression of the attitude discrepancy D on B (near level, B = t I: an angle offset plus the bias times the
time) over every logged angle at once. D is differenced from sample to sample within each stretch between the
rate sensors' gaps, so each angle's offset (and its reset at a gap) drops out. Rates not configured enter
through the attitude's own derivative (omega = T^-1 Theta_dot, without a bias). Robust: D is unwrapped (yaw
wraps at +-pi, and a gap may hide a full turn), and an attitude outlier (a step out and back beyond 8 robust
SDs) is dropped.

**SD, with autocorrelated errors.** The errors are far from white: the rate noise integrates to a random walk,
and the AHRS's angle errors may be correlated over its filter's time constant or slower. Two steps:
(1) generalized least squares under a local-level error model, D's error = a random walk (diffusion q) plus the
attitude's error (variance s2), its covariance after differencing tridiagonal (banded Cholesky); q and s2 per
angle from the residuals' variogram at lags of 1 sample to an eighth of the trial (the random walk hides at one
sample and dominates over minutes); (2) the **effective sample size** of what that model misses: the whitened
residuals' integrated autocorrelation time tau = 1 + 2 sum_k rho(k), summed over Sokal's automatic window (the
smallest lag M with M >= 5 tau(M); Sokal, *Monte Carlo Methods in Statistical Mechanics*, 1997, §3, p. 12),
scales each angle's contribution: Cov(b) = (sum_i X_i' Sigma_i^-1 X_i / tau_i)^-1.

**Identifiable** when the attitude the rate drives is configured, the usable stretch lasts at least
``MIN_SPAN_S``, and the SD is within ``PLAUSIBLE_BIAS_RADPS`` (a bias no larger than a MEMS gyro's cannot be
told from zero otherwise); an unidentifiable bias is not subtracted.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from scipy.linalg import cho_solve_banded, cholesky_banded, solve_banded
from scipy.optimize import nnls

from pipeline.config.vehicle import Vehicle
from pipeline.estimation.smoother import Measurements
from pipeline.sync import valid_column

log = logging.getLogger(__name__)

__all__ = ["MIN_SPAN_S", "PLAUSIBLE_BIAS_RADPS", "RateBias", "debias", "estimate_rate_biases", "euler_rate_matrix",
           "rate_biases"]

#: A usable stretch of attitude shorter than this gives no bias (the slope is not told from the offset).
MIN_SPAN_S = 60.0
#: A bias whose SD is larger than this is not identifiable: a tactical MEMS gyro's bias is a few 1e-4 rad/s
#: (about 100 deg/h), a FOG's 1e-6..1e-4, the Earth's rate 7.3e-5 at most.
PLAUSIBLE_BIAS_RADPS = 1e-3
#: Attitude samples with |pitch| above this are skipped (T is singular at +-90 deg).
MAX_PITCH_RAD = np.radians(80.0)
_SOKAL_C = 5.0


@dataclass(frozen=True)
class RateBias:
    """One rate signal's bias estimate: value and SD (rad/s), whether it was identifiable (and so subtracted),
    why not, and the effective-sample-size factors used for its SD."""

    signal: str
    bias_radps: float
    sd_radps: float
    identifiable: bool
    reason: str | None = None

    def as_dict(self) -> dict[str, Any]:
        """The JSON record; a bias that was not estimated is null (NaN is not JSON), with its ``reason``."""
        def number(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None

        return {"signal": self.signal, "bias_radps": number(self.bias_radps), "sd_radps": number(self.sd_radps),
                "identifiable": self.identifiable, "subtracted": self.identifiable, "reason": self.reason}


def euler_rate_matrix(roll: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """T(Theta) (n, 3, 3) with Theta_dot = T omega (ZYX Euler angles; Fossen 2011, eq. 2.29, p. 25)."""
    sr, cr = np.sin(roll), np.cos(roll)
    tp, cp = np.tan(pitch), np.cos(pitch)
    T = np.zeros(np.shape(sr) + (3, 3))  # filled in place: nested np.stack copies the (n, 3, 3) array twice
    T[..., 0, 0] = 1.0
    T[..., 0, 1], T[..., 0, 2] = sr * tp, cr * tp
    T[..., 1, 1], T[..., 1, 2] = cr, -sr
    T[..., 2, 1], T[..., 2, 2] = sr / cp, cr / cp
    return T


def _body_rates_from_attitude(t_s: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """omega = T^-1 Theta_dot (n, 3) from the attitude's central differences (for rates not configured)."""
    rate = np.gradient(angles, t_s, axis=0)
    roll, pitch = angles[:, 0], angles[:, 1]
    sr, cr, sp, cp = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
    return np.stack([rate[:, 0] - sp * rate[:, 2],
                     cr * rate[:, 1] + cp * sr * rate[:, 2],
                     -sr * rate[:, 1] + cp * cr * rate[:, 2]], axis=1)


def _cumtrapz(t_s: np.ndarray, f: np.ndarray, gap: np.ndarray | None = None) -> np.ndarray:
    """Cumulative trapezoid of f (n, ...) over t_s, nothing added across the steps flagged in ``gap`` (n - 1)."""
    steps = 0.5 * (f[1:] + f[:-1]) * np.diff(t_s).reshape((-1,) + (1,) * (f.ndim - 1))
    if gap is not None:
        steps[gap] = 0.0
    return np.concatenate([np.zeros((1,) + f.shape[1:]), np.cumsum(steps, axis=0)])


def _integrated_autocorrelation_time(x: np.ndarray) -> float:
    """tau = 1 + 2 sum_k rho(k) over Sokal's window (smallest M with M >= 5 tau(M)); at least 1."""
    n = x.size
    if n < 8:
        return 1.0
    x = x - x.mean()
    size = 1 << int(np.ceil(np.log2(2 * n)))
    spec = np.fft.rfft(x, size)
    acf = np.fft.irfft(spec * np.conj(spec), size)[:n]
    if acf[0] <= 0:
        return 1.0
    tau = 1.0 + 2.0 * np.cumsum(acf[1:] / acf[0])
    window = np.nonzero(np.arange(1, n) >= _SOKAL_C * tau)[0]
    m = window[0] if window.size else n - 2
    return float(max(tau[m], 1.0))


def estimate_rate_biases(grid_ns: np.ndarray, angles: np.ndarray, angle_ok: np.ndarray, used_angles: tuple[bool, ...],
                         rates: dict[str, Measurements], signals: dict[str, str]) -> dict[str, RateBias]:
    """Per configured rate (``rates``: dof 'p' 'q' 'r' -> its measurements at their own stamps, sign applied;
    ``signals``: dof -> signal name), the constant bias and its SD from the attitude (module docstring).

    ``angles`` (n, 3): roll, pitch, yaw (rad) on the grid ``grid_ns``; ``angle_ok`` (n,): where the attitude is
    valid; ``used_angles``: which of roll, pitch, yaw the trial logs (an angle not logged is no evidence)."""
    t0 = int(grid_ns[0])
    t_s = (grid_ns - t0) / 1e9
    ok = angle_ok & np.all(np.isfinite(angles), axis=1) & (np.abs(angles[:, 1]) < MAX_PITCH_RAD)
    angles = np.where(np.isfinite(angles), angles, 0.0)
    if ok.any() and not ok.all():  # the attitude between valid samples, for T at the rate sensors' stamps
        angles = np.stack([np.interp(t_s, t_s[ok], angles[ok, i]) for i in range(3)], axis=1)
    dofs = [d for d in "pqr" if d in rates]
    # the discrepancy's integrals on the grid: I[:, i] = sum_j int T_ij omega_j, B[:, i, j] = int T_ij
    integral = np.zeros((t_s.size, 3))
    B = np.zeros((t_s.size, 3, len(dofs)))
    gap_ends: list[float] = []
    missing = [j for j, d in enumerate("pqr") if d not in rates]
    if missing:
        omega_att = _body_rates_from_attitude(t_s, angles)
        T = euler_rate_matrix(angles[:, 0], angles[:, 1])
        integral += _cumtrapz(t_s, np.einsum("nij,nj->ni", T[:, :, missing], omega_att[:, missing]))
    for k, dof in enumerate(dofs):
        m = rates[dof]
        ts = (m.t_ns - t0) / 1e9
        inside = (ts >= t_s[0]) & (ts <= t_s[-1])
        ts, y = ts[inside], m.y[inside]
        if ts.size < 2:
            ok[:] = False
            continue
        T_j = euler_rate_matrix(np.interp(ts, t_s, angles[:, 0]),
                                np.interp(ts, t_s, angles[:, 1]))[:, :, "pqr".index(dof)]
        dt = np.diff(ts)
        gap = dt > max(10.0 * float(np.median(dt)), 0.5)
        F = _cumtrapz(ts, T_j * y[:, None], gap)
        G = _cumtrapz(ts, T_j, gap)
        for i in range(3):
            integral[:, i] += np.interp(t_s, ts, F[:, i])
            B[:, i, k] = np.interp(t_s, ts, G[:, i])
        ok &= (t_s >= ts[0]) & (t_s <= ts[-1])
        for lo, hi in zip(ts[:-1][gap], ts[1:][gap], strict=True):  # inside a gap the integral is unknown
            ok &= (t_s <= lo) | (t_s >= hi)
            gap_ends.append(hi)
    segment = np.searchsorted(np.sort(gap_ends), t_s, side="right")

    def unidentifiable(reason: str) -> dict[str, RateBias]:
        log.warning("rate-sensor bias not estimated (%s): %s kept as measured", reason,
                    ", ".join(signals[d] for d in dofs))
        return {d: RateBias(signals[d], float("nan"), float("nan"), False, reason) for d in dofs}

    rows = np.nonzero(ok)[0]
    span = float(t_s[rows[-1]] - t_s[rows[0]]) if rows.size else 0.0
    if not dofs:
        return {}
    if span < MIN_SPAN_S:
        return unidentifiable(f"{span:.0f} s of valid attitude and rates, under the {MIN_SPAN_S:.0f} s needed")

    # per used angle and stretch between gaps: the discrepancy (unwrapped) and the bias regressors, differenced
    # from sample to sample (the offsets drop out), with the time between the samples
    parts = {"dD": [], "dX": [], "dt": [], "angle": [], "first": []}
    seg = segment[rows]
    for a, i in enumerate(i for i in range(3) if used_angles[i]):
        for s in np.unique(seg):
            idx = rows[seg == s]
            if idx.size < 3:
                continue
            idx = idx[_not_spikes(np.diff(np.unwrap(integral[idx, i] - angles[idx, i])))]
            D = np.unwrap(integral[idx, i] - angles[idx, i])
            dD, dX, dt = np.diff(D), np.diff(B[idx, i, :], axis=0), np.diff(t_s[idx])
            keep = np.ones(dD.size, dtype=bool)
            parts["dD"].append(dD[keep])
            parts["dX"].append(dX[keep])
            parts["dt"].append(dt[keep])
            parts["angle"].append(np.full(int(keep.sum()), a))
            first = np.zeros(int(keep.sum()), dtype=bool)
            first[:1] = True
            parts["first"].append(first)
    if not parts["dD"]:
        return unidentifiable("no attitude angle is logged")
    dD, dX, dt = (np.concatenate(parts[k]) for k in ("dD", "dX", "dt"))
    angle_of, first = np.concatenate(parts["angle"]), np.concatenate(parts["first"])
    col_scale = np.sqrt(np.sum(dX**2, axis=0))
    driven = col_scale > 1e-6 * np.sqrt(np.sum(dt**2))  # some logged angle moves with this rate
    est = {d: RateBias(signals[d], float("nan"), float("nan"), False,
                       "no logged attitude angle that this rate moves") for d, on in zip(dofs, driven, strict=True)
           if not on}
    cols = np.nonzero(driven)[0]
    if cols.size == 0:
        return est
    b, cov, tau = _local_level_gls(dD, dX[:, cols], dt, angle_of, first)
    for c, k in enumerate(cols):
        sd = float(np.sqrt(cov[c, c]))
        reason = None if sd <= PLAUSIBLE_BIAS_RADPS else (
            f"SD {sd:.2g} rad/s above a plausible bias ({PLAUSIBLE_BIAS_RADPS:g} rad/s)")
        est[dofs[k]] = RateBias(signals[dofs[k]], float(b[c]), sd, reason is None, reason)
    log.info("rate-sensor biases from the attitude (autocorrelation times of the whitened residuals %s): %s",
             ", ".join(f"{x:.1f}" for x in tau),
             "; ".join(f"{e.signal} {e.bias_radps:.3g} +- {e.sd_radps:.2g} rad/s" for e in est.values()))
    return {d: est[d] for d in dofs}


def _not_spikes(dD: np.ndarray, limit: float = 8.0) -> np.ndarray:
    """The samples to keep (dD: their increments): an attitude outlier is a step out and a step back beyond
    ``limit`` robust SDs; the sample goes and its neighbours' increment spans it (so this drops no trend)."""
    dev = dD - np.median(dD)
    mad = 1.4826 * np.median(np.abs(dev))
    big = np.abs(dev) > limit * max(mad, 1e-15)
    spike = big[:-1] & big[1:] & (np.sign(dev[:-1]) != np.sign(dev[1:]))
    keep = np.ones(dD.size + 1, dtype=bool)
    keep[1:-1] = ~spike
    return keep


def _variogram_fit(u: np.ndarray, h: np.ndarray, start: np.ndarray) -> tuple[float, float]:
    """(q, s2) of the residual increments ``u`` (time steps ``h``; ``start``: a stretch's first increment): the
    variogram of the level E[(R(t + L) - R(t))^2] = q L + 2 s2, fitted by least squares (non-negative, each lag
    weighted by 1 / its value squared) at lags of 1, 2, 4 ... samples up to an eighth of the series. The random
    walk's share at one sample is tiny (its drift shows over minutes), so the lag-1 moments alone cannot find q."""
    stretch = np.cumsum(start)
    level, t = np.cumsum(u), np.cumsum(h)
    rows = []
    lag = 1
    while lag <= max(u.size // 8, 1):
        same = stretch[lag:] == stretch[:-lag]
        if same.sum() >= 10:
            rows.append((float(np.mean((t[lag:] - t[:-lag])[same])),
                         float(np.mean((level[lag:] - level[:-lag])[same] ** 2))))
        lag *= 2
    if not rows:
        return 1e-30, float(np.mean(u**2)) / 2
    L, g = np.array(rows).T
    w = 1.0 / np.maximum(g, 1e-300)
    design = np.stack([L, 2 * np.ones_like(L)], axis=1) * w[:, None]
    q, s2 = nnls(design, g * w)[0]
    return max(float(q), 1e-6 * 2 * float(s2) / float(np.mean(h)), 1e-30), float(s2)


def _local_level_gls(dD: np.ndarray, dX: np.ndarray, dt: np.ndarray, angle_of: np.ndarray, first: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Bias (k,), its covariance (k, k) and each angle's autocorrelation time, by generalized least squares of
    the differenced discrepancy dD = dX b + dW + dv: a random walk W (the integrated rate noise, diffusion q per
    second) plus the attitude's error v (variance s2), so per angle Cov(dD) is tridiagonal: q dt + 2 s2 on the
    diagonal, -s2 beside it (none across a stretch's first increment). q and s2 by moments of the residuals
    (:func:`_variogram_fit`), twice; then the whitened residuals' integrated autocorrelation time tau
    (Sokal) scales each angle's covariance by what the model misses (errors correlated beyond the white v)."""
    angles = np.unique(angle_of)
    b = np.linalg.lstsq(dX, dD, rcond=None)[0]
    tau = np.ones(angles.size)
    for step in range(3):
        A = np.zeros((dX.shape[1], dX.shape[1]))
        rhs = np.zeros(dX.shape[1])
        factors = []
        for a in angles:
            on = angle_of == a
            u, h, start = dD[on] - dX[on] @ b, dt[on], first[on]
            q, s2 = _variogram_fit(u, h, start)
            band = np.zeros((2, u.size))
            band[0] = q * h + 2 * s2
            band[1, :-1] = np.where(start[1:], 0.0, -s2)
            chol = cholesky_banded(band, lower=True)
            factors.append((on, chol))
            Xw = cho_solve_banded((chol, True), dX[on])
            A += dX[on].T @ Xw / tau[a]
            rhs += Xw.T @ dD[on] / tau[a]
        b = np.linalg.solve(A, rhs)
        if step == 1:  # the model fitted: what its whitened residuals still share sets tau
            tau = np.array([_integrated_autocorrelation_time(solve_banded((1, 0), chol, dD[on] - dX[on] @ b))
                            for on, chol in factors])
    return b, np.linalg.inv(A), tau


def rate_biases(synced: pd.DataFrame, body: pd.DataFrame, vehicle: Vehicle, rates: dict[str, Measurements]
                ) -> dict[str, RateBias]:
    """:func:`estimate_rate_biases` for a trial: the attitude from ``body`` (roll, pitch, yaw on the synced grid,
    :func:`pipeline.kinematics.body_kinematics`), valid where sync says the attitude signals are."""
    att = vehicle.sensors.attitude
    names = [att.quaternion] if att.quaternion is not None else [s for s in (att.roll, att.pitch, att.yaw) if s]
    ok = np.ones(len(synced), dtype=bool)
    for name in names:
        col = valid_column(name)
        if col in synced.columns:
            ok &= synced[col].to_numpy(dtype=bool)
    used = (True, True, True) if att.quaternion is not None else tuple(s is not None for s in
                                                                        (att.roll, att.pitch, att.yaw))
    angles = np.stack([body[c].to_numpy(dtype=float) for c in ("roll_rad", "pitch_rad", "yaw_rad")], axis=1)
    r = vehicle.sensors.rates
    signals = {d: s for d, s in zip("pqr", (r.p, r.q, r.r), strict=True) if s is not None and d in rates}
    return estimate_rate_biases(body["t_ns"].to_numpy(dtype=np.int64), angles, ok, used,
                                {d: rates[d] for d in signals}, signals)


def debias(rates: dict[str, Measurements], biases: dict[str, RateBias]) -> dict[str, Measurements]:
    """The rate measurements less each identifiable bias (the others as they are)."""
    out = dict(rates)
    for dof, est in biases.items():
        if est.identifiable:
            m = rates[dof]
            out[dof] = Measurements(m.t_ns, m.y - est.bias_radps, m.var, m.order)
    return out
