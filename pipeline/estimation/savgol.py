"""The ``savgol`` method's filters: ``scipy.signal.savgol_filter`` (derivative 0 and 1, ``delta=dt_s``) over an odd
window of about ``savgol_window_s`` (at least ``savgol_order + 1`` samples); half a window is dropped at each
segment edge."""

from __future__ import annotations

import numpy as np

from pipeline.config.params import DifferentiateParams

__all__ = ["savgol_filters", "savgol_window"]


def savgol_window(params: DifferentiateParams, dt_s: float, window_s: float | None = None) -> int:
    """The odd window (samples) of about ``window_s`` (default: ``savgol_window_s``), at least ``savgol_order + 1``."""
    width = params.savgol_window_s if window_s is None else window_s
    window = max(int(round(width / dt_s)), params.savgol_order + 1)
    return window if window % 2 == 1 else window + 1


def savgol_filters(x: np.ndarray, window: int, order: int, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(smoothed, derivative)`` of uniformly sampled ``x``: Savitzky-Golay of ``order`` over ``window`` samples."""
    from scipy.signal import savgol_filter  # here: scipy.signal costs ~0.6 CPU-s to import, for this method only

    smooth = savgol_filter(x, window, order, mode="interp")
    return smooth, savgol_filter(x, window, order, deriv=1, delta=dt_s, mode="interp")
