"""A BlueROV2-like ROV in ArduSub's depth hold, logged as mavros records it: a heave-only trial with a known answer.

The truth is the heave equation in NED (z and w down, the vertical motors' thrust down):

    (m + Z_wdot) w' = T_5 + T_6 + W - B - Z_w w - Z_ww w|w|

integrated by RK4 at ``step_s``. The autopilot's depth controller (a PD on depth plus the hover feed-forward) sets
the two vertical motors' PWM at the servo-output rate from the true state, tracking a depth set point that the
pilot moves up and down; the ESCs hold each PWM until the next message. Each motor's thrust is the thrust table
(:func:`thrust_table_csv`, a T200-like curve in kgf by PWM, with a dead band) interpolated linearly, as derive reads
such a sheet, so a vehicle config that names the same table gives back the true thrust exactly. The horizontal
motors stay at 1500 us.

Streams (mavros topic names and types; ``pipeline.sim.writers`` writes them): ``/mavros/rc/out``
(``mavros_msgs/msg/RCOut``: the 16 servo outputs in us, motors 1-6 first; header stamp at the command, log time
``rc.latency_s`` later) and ``/mavros/global_position/rel_alt`` (``std_msgs/msg/Float64``: metres, positive up, so
minus the depth, plus white noise; no header). No attitude is logged: the vehicle is level.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from pipeline.rk4 import rk4_step
from pipeline.sim.sensors import SensorOptions, Stream, StreamSpec
from pipeline.sim.trial import EPOCH_NS

KGF_N = 9.80665
RC_OUT_TYPE = "mavros_msgs/msg/RCOut"
FLOAT64_TYPE = "std_msgs/msg/Float64"
#: the table's columns, named as in Blue Robotics' T200 sheet
TABLE_PWM_COLUMN, TABLE_FORCE_COLUMN = "PWM (µs)", "Force (Kg f)"

#: the servo outputs at 10 Hz, logged 2 ms after the command; rel_alt at 10 Hz, logged 5 ms late, 3 mm of noise
RC_SPEC = StreamSpec(10.0, 0.002, 0.0, 0.0)
REL_ALT_SPEC = StreamSpec(10.0, 0.005, 0.0, 0.003)


@dataclass(frozen=True)
class HeaveTruth:
    """The vehicle's heave constants (SI; Z_w, Z_ww as positive damping) and the depth controller's."""

    mass_kg: float = 11.5
    added_mass_kg: float = 14.57          # -Z_wdot
    z_w: float = 6.0                      # N per m/s
    z_ww: float = 25.0                    # N per (m/s)^2
    net_buoyancy_N: float = 2.0           # B - W: positive floats up
    gravity_mps2: float = 9.81
    depth0_m: float = 5.0
    kp_us_per_m: float = 120.0            # the depth controller: PWM offset per metre of depth error ...
    kd_us_per_mps: float = 60.0           # ... and per m/s of heave rate

    @property
    def weight_N(self) -> float:
        return self.mass_kg * self.gravity_mps2

    @property
    def buoyancy_N(self) -> float:
        return self.weight_N + self.net_buoyancy_N


@dataclass
class HeaveTrial:
    """A simulated depth-hold trial: the truth on the integration grid, the mavros streams, what made them."""

    truth: pd.DataFrame                   # t_ns, depth_m, w_mps, wdot_mps2, pwm_us, thrust_N (per vertical motor)
    streams: dict[str, Stream]
    heave: HeaveTruth
    seed: int
    duration_s: float
    sensors: SensorOptions = field(default_factory=SensorOptions)


def thrust_table() -> tuple[np.ndarray, np.ndarray]:
    """(PWM us, force kgf) every 4 us over 1100-1900 us: 0 within 25 us of 1500, then 5.0 kgf forward and 4.0 kgf
    backward at full stroke along a 1.5 power, rounded to 0.01 kgf as a data sheet is."""
    pwm = np.arange(1100, 1901, 4)
    x = np.clip((np.abs(pwm - 1500.0) - 25.0) / 375.0, 0.0, None)
    force = np.where(pwm >= 1500, 5.0, -4.0) * x**1.5
    return pwm, np.round(force, 2)


def thrust_table_csv() -> str:
    """The thrust table as a CSV text (the T200 sheet's column names, one voltage)."""
    pwm, force = thrust_table()
    rows = "".join(f"{p},{f:.2f}\n" for p, f in zip(pwm, force, strict=True))
    return f"{TABLE_PWM_COLUMN},{TABLE_FORCE_COLUMN}\n{rows}"


def thrust_N(pwm_us: np.ndarray | float) -> np.ndarray:
    """One motor's thrust (N) at ``pwm_us``: the table interpolated linearly."""
    pwm, force = thrust_table()
    return np.interp(pwm_us, pwm, force) * KGF_N


def _hover_pwm(net_buoyancy_N: float) -> float:
    """The PWM at which the two vertical motors hold the net buoyancy (the controller's feed-forward)."""
    grid = np.arange(1100.0, 1900.5, 0.5)
    return float(grid[np.argmin(np.abs(2 * thrust_N(grid) - net_buoyancy_N))])


def set_point_m(t_s: np.ndarray | float, depth0_m: float) -> np.ndarray:
    """The pilot's depth set point: slow and fast swings around the start depth, so the vehicle heaves both ways."""
    t = np.asarray(t_s, dtype=float)
    return depth0_m + 1.2 * np.sin(2 * np.pi * t / 24.0) + 0.5 * np.sin(2 * np.pi * t / 7.7) \
        + 0.25 * np.sin(2 * np.pi * t / 3.3)


def heave_trial(duration_s: float = 60.0, seed: int = 0, heave: HeaveTruth | None = None, *,
                step_s: float = 0.001, rc: StreamSpec = RC_SPEC, rel_alt: StreamSpec = REL_ALT_SPEC) -> HeaveTrial:
    """Simulate a depth-hold trial of ``duration_s``; ``rc`` and ``rel_alt``: the two streams' rates, log
    latencies and (rel_alt) noise SD in metres. Deterministic for a seed."""
    h = heave or HeaveTruth()
    rng = np.random.default_rng(seed)
    m33 = h.mass_kg + h.added_mass_kg
    n = int(round(duration_s / step_s))
    t = np.arange(n + 1) * step_s
    per_rc = int(round(1.0 / (rc.rate_hz * step_s)))
    hover = _hover_pwm(h.net_buoyancy_N)
    x = np.zeros((n + 1, 2))                       # depth (m, down), w (m/s, down)
    x[0] = (h.depth0_m, 0.0)
    pwm = np.empty(n + 1)

    def f(state: np.ndarray, thrust: float) -> np.ndarray:
        w = state[1]
        return np.array([w, (thrust - h.net_buoyancy_N - h.z_w * w - h.z_ww * w * abs(w)) / m33])

    thrust = 0.0
    for k in range(n + 1):
        if k % per_rc == 0:  # a new servo output: the controller's command, held by the ESCs
            err = set_point_m(t[k], h.depth0_m) - x[k, 0]
            command = float(np.clip(np.rint(hover + h.kp_us_per_m * err - h.kd_us_per_mps * x[k, 1]), 1100, 1900))
            thrust = 2.0 * float(thrust_N(command))
        pwm[k] = command
        if k < n:
            x[k + 1] = rk4_step(f, x[k], thrust, step_s)
    depth, w = x[:, 0], x[:, 1]
    t_ns = EPOCH_NS + np.rint(t * 1e9).astype(np.int64)
    thrust_each = thrust_N(pwm)
    wdot = (2 * thrust_each - h.net_buoyancy_N - h.z_w * w - h.z_ww * w * np.abs(w)) / m33
    truth = pd.DataFrame({"t_ns": t_ns, "depth_m": depth, "w_mps": w, "wdot_mps2": wdot, "pwm_us": pwm,
                          "thrust_N": thrust_each})

    rc_rows = np.arange(0, n + 1, per_rc)
    channels = np.full((rc_rows.size, 16), 1500, dtype=np.uint16)
    channels[:, 8:] = 0                            # outputs not assigned to a motor
    channels[:, 4] = channels[:, 5] = pwm[rc_rows].astype(np.uint16)
    streams = {"rc": Stream("rc", "/mavros/rc/out", RC_OUT_TYPE, _late(t_ns[rc_rows], rc.latency_s),
                            t_ns[rc_rows], {"channels": channels}, frame_id="")}
    alt_rows = np.arange(int(round(0.05 / step_s)), n + 1, int(round(1.0 / (rel_alt.rate_hz * step_s))))
    up = -depth[alt_rows] + rng.normal(0.0, rel_alt.noise, alt_rows.size)
    streams["rel_alt"] = Stream("rel_alt", "/mavros/global_position/rel_alt", FLOAT64_TYPE,
                                _late(t_ns[alt_rows], rel_alt.latency_s), t_ns[alt_rows], {"data": up})
    return HeaveTrial(truth, streams, h, seed, duration_s)


def _late(t_ns: np.ndarray, latency_s: float) -> np.ndarray:
    return t_ns + int(math.floor(latency_s * 1e9 + 0.5))
