"""The ``gaussian`` method's filters: Gaussian-kernel smoothing and first derivative of a uniformly sampled signal.

- :func:`gaussian_derivative` = ``scipy.ndimage.gaussian_filter1d(order=1)`` divided by ``dt_s`` and by the second
  moment of the truncated, sampled kernel, so it is exact for polynomials up to degree 2 wherever the kernel lies
  inside the segment (scipy's raw kernel is ~3 % low at a 3-sigma truncation).
- ``gaussian_degree=4``: :func:`local_cubic_weights`, a Gaussian-weighted local cubic whose derivative is exact to
  degree 4, cancelling the plain kernel's bias sigma^2/2 x'''. That bias matters: with quadratic damping, x''' holds
  a term in sign(u) u_dot^2, so the plain kernel's damping target steps across u = 0. The corrected kernel is not
  the default: with it, the coupled acceptance ranking changes (``docs/models.md``; figures in
  ``docs/benchmarks.md``).
- Edge rule: the kernel is truncated at ``edge_sigmas`` sigma (4 when ``edge_sigmas`` < 1), and exactly the samples
  whose kernel would reach past a segment edge are dropped (:func:`edge_samples`). Edges are reflected, so the
  kept samples never see the reflection.
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import correlate1d, gaussian_filter1d

from pipeline.config.params import DifferentiateParams

__all__ = ["apply_weights", "edge_samples", "gaussian_derivative", "gaussian_filters", "gaussian_smooth",
           "gaussian_truncate", "local_cubic_weights"]


def gaussian_truncate(edge_sigmas: float) -> float:
    """Kernel truncation in sigmas: ``edge_sigmas`` (so kept samples never see a segment edge), 4 below 1."""
    return edge_sigmas if edge_sigmas >= 1.0 else 4.0


def gaussian_derivative(x: np.ndarray, dt_s: float, sigma_s: float, truncate: float = 4.0) -> np.ndarray:
    """Gaussian-smoothed first derivative of uniformly sampled ``x`` (along axis 0), in units of x per second.

    ``gaussian_filter1d(order=1)`` gives a derivative per sample, with a kernel -k phi(k)/sigma^2 whose
    discrete second moment is slightly below 1 once sampled and truncated; dividing by that moment and by
    ``dt_s`` makes the result exact for polynomials of degree <= 2 where the kernel lies inside the data.
    Edges use reflection (biased: trim them).
    """
    sd = sigma_s / dt_s
    radius = int(truncate * sd + 0.5)
    k = np.arange(-radius, radius + 1, dtype=float)
    phi = np.exp(-0.5 * (k / sd) ** 2)
    phi /= phi.sum()
    moment = float(np.sum(k * k * phi)) / sd**2
    raw = gaussian_filter1d(np.asarray(x, dtype=float), sd, axis=0, order=1, mode="reflect", truncate=truncate)
    return raw / (moment * dt_s)


def gaussian_smooth(x: np.ndarray, dt_s: float, sigma_s: float, truncate: float = 4.0) -> np.ndarray:
    return gaussian_filter1d(np.asarray(x, dtype=float), sigma_s / dt_s, axis=0, mode="reflect", truncate=truncate)


def local_cubic_weights(dt_s: float, sigma_s: float, truncate: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """``(smooth, derivative)`` weights of a Gaussian-weighted least-squares cubic, centred, sampled and truncated.

    ``smooth = (a + b k^2) phi(k)`` with ``sum smooth = 1`` and ``sum smooth k^2 = 0``; ``derivative = (c k + e k^3)
    phi(k) / dt`` with ``sum derivative k = 1/dt`` and ``sum derivative k^3 = 0``. By symmetry the smoothing is exact
    for polynomials of degree <= 3 and the derivative for degree <= 4, so the plain Gaussian's O(sigma^2) bias,
    sigma^2/2 times x'' (smoothing) or x''' (derivative), cancels; the price is more noise at the same sigma.
    """
    sd = sigma_s / dt_s
    radius = int(truncate * sd + 0.5)
    k = np.arange(-radius, radius + 1, dtype=float)
    phi = np.exp(-0.5 * (k / sd) ** 2)
    mom = {j: float(np.sum(k**j * phi)) for j in (0, 2, 4, 6)}
    a, b = np.linalg.solve([[mom[0], mom[2]], [mom[2], mom[4]]], [1.0, 0.0])
    c, e = np.linalg.solve([[mom[2], mom[4]], [mom[4], mom[6]]], [1.0, 0.0])
    return (a + b * k**2) * phi, (c * k + e * k**3) * phi / dt_s


def apply_weights(x: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Centred correlation with ``weights`` along axis 0 (edges reflected, as the Gaussian filters: trim them)."""
    return correlate1d(np.asarray(x, dtype=float), weights, axis=0, mode="reflect")


def gaussian_filters(x: np.ndarray, dt_s: float, sigma_s: float, degree: int = 4, truncate: float = 4.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """``(smoothed, derivative)`` of uniformly sampled ``x`` along axis 0: the plain Gaussian kernels
    (``degree=2``: :func:`gaussian_smooth`, :func:`gaussian_derivative`) or the bias-corrected ones (``degree=4``:
    :func:`local_cubic_weights`). Edges are reflected: trim them."""
    if degree == 2:
        return gaussian_smooth(x, dt_s, sigma_s, truncate), gaussian_derivative(x, dt_s, sigma_s, truncate)
    if degree != 4:
        raise ValueError(f"gaussian_degree {degree}: expected 2 or 4")
    w_smooth, w_deriv = local_cubic_weights(dt_s, sigma_s, truncate)
    return apply_weights(x, w_smooth), apply_weights(x, w_deriv)


def edge_samples(params: DifferentiateParams, dt_s: float, sigma_s: float) -> int:
    """Samples dropped at each end of a segment for a kernel of width ``sigma_s``: ``round(edge_sigmas*sigma/dt)``
    (none when ``edge_sigmas`` is 0)."""
    return int(gaussian_truncate(params.edge_sigmas) * sigma_s / dt_s + 0.5) if params.edge_sigmas else 0
