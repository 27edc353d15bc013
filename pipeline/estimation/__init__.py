"""The differentiate stage: from noisy multi-rate sensors to body velocities, accelerations and how sure we are.

The stage's pure function is :func:`pipeline.estimation.differentiate.differentiate`; it runs one of three methods
behind one signature, (synced, vehicle, params, streams) -> (kinematics table, report):

- :mod:`~pipeline.estimation.kalman`: ``kalman``, a Kalman/RTS smoother over every velocity and rate sensor at its
  own stamps (:mod:`~pipeline.estimation.smoother`: white-jerk model per DOF, process noise by maximum likelihood,
  outlier gating, solved as one banded system), with positions (:mod:`~pipeline.estimation.position`) and IMU
  accelerometers (:mod:`~pipeline.estimation.accelerometer`);
- :mod:`~pipeline.estimation.grid`: ``gaussian`` and ``savgol``, filters of the synced grid
  (:mod:`~pipeline.estimation.gaussian`, :mod:`~pipeline.estimation.savgol`), segment edges, grid step and ``auto``
  widths (:mod:`~pipeline.estimation.widths`);
- shared by all: :mod:`~pipeline.estimation.measurements` (sensor samples at their own stamps, their noise) and
  :mod:`~pipeline.estimation.noise` (each signal's noise SD and outlier rate, estimated from the data).

Frames and mounting (attitude, rotations, body velocities on the grid) are :mod:`pipeline.kinematics`; column
names are :mod:`pipeline.vocabulary`.
"""
