"""Noise models estimated from the data: each signal's white-noise standard deviation and outlier rate.

A signal sampled faster than it changes is, locally, a low-order polynomial plus noise. For every sample whose
two neighbours on each side are close in time, :func:`local_residuals` predicts it from a least-squares
quadratic through those four neighbours, at the sample's own time (so irregular stamps, as a DVL's pings, are
handled exactly), and divides the prediction error by its standard deviation in units of sigma,
``sqrt(1 + |w|^2)`` with ``w`` the prediction's weights. For white noise these normalized residuals have
standard deviation sigma; a quadratic trend cancels exactly, so only the third derivative (motion faster than
the sensor's rate) leaks in. The median absolute deviation (x 1.4826) makes the estimate robust to outliers.

An outlier contaminates the residuals of its neighbours too; it is counted once, where the normalized residual
exceeds ``gate`` sigma and is the largest of the five around it.

An estimate never goes below :func:`noise_floor` (source ``floor``): a noise-free signal (simulated data, a
constant channel) leaves residuals that are float rounding (~1e-18) or exactly zero, and a measurement variance
of 1e-36 makes the smoother's banded system singular in double precision ("not positive definite") or its
derivatives noise, while zero cannot be used at all.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["NOISE_FLOOR", "NOISE_FLOOR_RELATIVE", "NoiseEstimate", "estimate_noise", "local_residuals", "noise_floor"]

MAD_TO_SD = 1.482602218505602
#: The floor of an estimated noise SD, in the signal's (SI) unit: 1 nm/s, 1 nrad/s. Far below any real sensor's
#: noise (a DVL's ~1e-3 m/s, a navigation-grade FOG's ~1e-6 rad/s per sample) and far above float64 rounding
#: of values up to 1000 (~1e-13).
NOISE_FLOOR = 1e-9
#: ... and at least this fraction of the signal's largest |value|, so that it stays above rounding for large
#: values (UTM positions, 5e6 m: 5e-6 m, below an RTK fix's 1e-2 m).
NOISE_FLOOR_RELATIVE = 1e-12


def noise_floor(x: np.ndarray) -> float:
    """The smallest noise SD an estimate of ``x``'s noise may give (see :data:`NOISE_FLOOR`)."""
    x = np.asarray(x, dtype=float)
    finite = np.abs(x[np.isfinite(x)])
    return max(NOISE_FLOOR, NOISE_FLOOR_RELATIVE * float(finite.max()) if finite.size else 0.0)


@dataclass(frozen=True)
class NoiseEstimate:
    """A signal's noise: ``sd`` (its unit), ``outlier_rate`` (fraction of samples), from ``samples`` residuals;
    ``source``: ``estimated``, ``floor`` (the estimate was below :func:`noise_floor`: a noise-free signal) or
    ``config`` (an override in params)."""

    sd: float
    outlier_rate: float
    samples: int
    source: str = "estimated"

    def as_dict(self) -> dict[str, float | int | str | None]:
        """As JSON: NaN (not estimated) becomes None."""
        return {k: (None if isinstance(v, float) and not np.isfinite(v) else v) for k, v in asdict(self).items()}


def local_residuals(t_s: np.ndarray, x: np.ndarray, max_step_s: float | None = None) -> np.ndarray:
    """Normalized leave-one-out residuals of a local quadratic through the two neighbours on each side.

    ``t_s`` increasing (seconds), ``x`` the samples (NaN = missing). Samples without four finite neighbours
    within ``max_step_s`` of each other (default: 3 x the median step) get NaN.
    """
    t = np.asarray(t_s, dtype=float)
    x = np.asarray(x, dtype=float)
    out = np.full(x.shape, np.nan)
    if x.size < 5:
        return out
    steps = np.diff(t)
    limit = 3.0 * float(np.median(steps)) if max_step_s is None else max_step_s
    k = np.arange(2, x.size - 2)
    offsets = (-2, -1, 1, 2)
    nb_t = np.stack([t[k + o] - t[k] for o in offsets], axis=1)
    nb_x = np.stack([x[k + o] for o in offsets], axis=1)
    span = np.stack([steps[k + o] for o in (-2, -1, 0, 1)], axis=1)
    ok = np.all(np.isfinite(nb_x), axis=1) & np.isfinite(x[k]) & np.all(span <= limit, axis=1)
    ok &= np.all(span > 0, axis=1)
    if not ok.any():
        return out
    k, nb_t, nb_x = k[ok], nb_t[ok], nb_x[ok]
    scale = np.max(np.abs(nb_t), axis=1, keepdims=True)
    s = nb_t / scale
    V = np.stack([np.ones_like(s), s, s * s], axis=2)            # (n, 4, 3)
    VtV = np.einsum("nij,nik->njk", V, V)
    # prediction at s = 0 is the intercept: w = e0^T (V^T V)^-1 V^T
    coef = np.linalg.solve(VtV, np.broadcast_to(np.array([1.0, 0.0, 0.0]), (len(k), 3))[..., None])[..., 0]
    w = np.einsum("nj,nij->ni", coef, V)                          # (n, 4)
    pred = np.sum(w * nb_x, axis=1)
    out[k] = (x[k] - pred) / np.sqrt(1.0 + np.sum(w * w, axis=1))
    return out


def estimate_noise(t_s: np.ndarray, x: np.ndarray, *, gate: float = 5.0, max_step_s: float | None = None,
                   max_samples: int = 20_000) -> NoiseEstimate:
    """Robust white-noise SD and outlier rate of one signal (see the module docstring). A longer signal is
    read in 40 evenly spaced contiguous blocks of ``max_samples`` in all (a few % precision)."""
    t_s, x = np.asarray(t_s, dtype=float), np.asarray(x, dtype=float)
    if x.size > max_samples:
        blocks, size = 40, max_samples // 40
        starts = np.linspace(0, x.size - size, blocks).astype(np.int64)
        z = np.concatenate([local_residuals(t_s[a: a + size], x[a: a + size], max_step_s) for a in starts])
        return _summarize(z, gate, noise_floor(x))
    return _summarize(local_residuals(t_s, x, max_step_s), gate, noise_floor(x))


def _summarize(z: np.ndarray, gate: float, floor: float) -> NoiseEstimate:
    finite = np.isfinite(z)
    n = int(finite.sum())
    if n < 10:
        return NoiseEstimate(float("nan"), float("nan"), n)
    zf = z[finite]
    sd = MAD_TO_SD * float(np.median(np.abs(zf - np.median(zf))))
    if sd == 0.0:  # quantized or noise-free: the smallest non-zero residual bounds it
        nonzero = np.abs(zf[zf != 0])
        sd = float(nonzero.min()) / 10.0 if nonzero.size else 0.0
        if sd < floor:
            return NoiseEstimate(floor, 0.0, n, "floor")
        return NoiseEstimate(sd, 0.0, n)
    source = "estimated"
    if sd < floor:
        sd, source = floor, "floor"
    a = np.abs(np.nan_to_num(z, nan=0.0))
    padded = np.pad(a, 2)
    local_max = np.ones(a.size, dtype=bool)
    for o in (-2, -1, 1, 2):
        local_max &= a >= padded[2 + o: 2 + o + a.size]
    outliers = int(np.sum((a > gate * sd) & local_max & finite))
    return NoiseEstimate(sd, outliers / n, n, source)
