"""``sigma_s: auto``: a Gaussian derivative's width per signal, from the signal's noise and spectrum.

The Gaussian derivative of width s applied to a signal x with white noise of SD sigma sampled every dt has

- noise variance  sigma^2 dt / (4 sqrt(pi) s^3)   (the integral of the squared derivative kernel), and
- bias            s^2 / 2 x'''                      (its leading term),

so the mean-square error sigma^2 dt / (4 sqrt(pi) s^3) + s^4 E[x'''^2] / 4 is least at

    s* = (3 sigma^2 dt / (4 sqrt(pi) E[x'''^2]))^(1/7).

E[x'''^2] is estimated from the data with a pilot Gaussian third derivative of width p, less what the noise
adds to it (sigma^2 dt 15 / (16 sqrt(pi) p^7)); the pilot is refined from s* (three rounds, starting at 1 s,
widened where the noise would dominate it), the classic plug-in rule. ``sigma`` and ``dt`` are the sensor's own
(noise estimated at its native stamps, :mod:`pipeline.estimation.noise`), not the synced grid's, since a grid
interpolated from a slower sensor carries correlated noise.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

__all__ = ["optimal_sigma"]

_SQRT_PI = float(np.sqrt(np.pi))


def optimal_sigma(segments: list[np.ndarray], grid_dt_s: float, noise_sd: float, native_dt_s: float, *,
                  bounds_s: tuple[float, float] = (0.05, 3.0), rounds: int = 3) -> float:
    """The plug-in width (s) for the derivative of a signal given as its valid grid ``segments``."""
    lo, hi = bounds_s
    if noise_sd <= 0:
        return lo
    s = 1.0
    m3 = 0.0
    for _ in range(rounds):
        pilot = s
        for _grow in range(20):
            m3, count = 0.0, 0
            for x in segments:
                edge = int(np.ceil(4 * pilot / grid_dt_s))
                if x.size <= 2 * edge + 1:
                    continue
                d3 = gaussian_filter1d(np.asarray(x, dtype=float), pilot / grid_dt_s, order=3, mode="reflect")
                d3 = d3[edge: x.size - edge] / grid_dt_s**3
                m3 += float(np.sum(d3 * d3))
                count += d3.size
            if count == 0:
                return hi
            noise_part = noise_sd**2 * native_dt_s * 15.0 / (16.0 * _SQRT_PI * pilot**7)
            m3 = m3 / count - noise_part
            if m3 > noise_part:  # the signal's part dominates: a usable pilot
                break
            pilot *= 1.25
        if m3 <= 0:
            return hi
        s = float(np.clip((3.0 * noise_sd**2 * native_dt_s / (4.0 * _SQRT_PI * m3)) ** (1.0 / 7.0), lo, hi))
    return s
