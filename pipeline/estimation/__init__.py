"""State estimation: from noisy multi-rate sensors to body velocities, accelerations and how sure we are.

- :mod:`pipeline.estimation.noise`: each signal's noise SD and outlier rate, estimated from the data;
- :mod:`pipeline.estimation.smoother`: a Kalman/RTS smoother (white-jerk model per DOF, measurements at their
  own stamps, process noise by maximum likelihood, outlier gating) solved as one banded system;
- :mod:`pipeline.estimation.motion`: the differentiate stage's ``kalman`` method over a vehicle's sensors;
- :mod:`pipeline.estimation.widths`: ``sigma_s: auto`` for the Gaussian and Savitzky-Golay filters.

Frames and mounting stay in :mod:`pipeline.kinematics`.
"""

from pipeline.estimation.motion import estimate_motion, sensor_noise
from pipeline.estimation.noise import NoiseEstimate, estimate_noise
from pipeline.estimation.smoother import Measurements, Smoothed, smooth, smoothed_variances

__all__ = ["Measurements", "NoiseEstimate", "Smoothed", "estimate_motion", "estimate_noise", "sensor_noise",
           "smooth", "smoothed_variances"]
