"""A BlueROV2 with ArduSub's vectored frame in manual mode, logged as mavros records it: a 4-DOF known answer.

The pilot drives forward, lateral, yaw and throttle (RC override, ``mavros_msgs/msg/OverrideRCIn``: ArduSub's RC
channels 1-6, pitch, roll, throttle, yaw, forward, lateral, integer us) at ``RC_SPEC.rate_hz``; the autopilot mixes
them by the vectored frame's factors (:data:`FACTORS`, written out here from ``AP_Motors6DOF.cpp``, independently
of :mod:`pipeline.config.mixing`) into six integer motor PWMs, the servo outputs (``/mavros/rc/out``), which the
ESCs hold until the next command. Each motor's thrust is the T200-like table of :mod:`pipeline.sim.ardusub`; the
true generalized force is tau = B T with B from :data:`POSITIONS` and :data:`DIRECTIONS`, directions chosen so
that each factor pushes its own axis (forward +X, lateral +Y, yaw +N, throttle up). The inputs stay inside
the frame's linear range (no motor clips, |forward| + |throttle| < 1: ArduSub's output scaling and its
forward/vertical coupling limit never act), so the servo outputs are the mixed inputs rounded to 1 us.

The vehicle is held level (roll = pitch = 0; the roll and pitch moments are not simulated); u, v, w, r obey, with
diagonal M (m_ii = mass + added mass; m_rr = I_zz + added inertia) and Fossen's C(nu) for a level body:

    m_uu u' = tau_u + m_vv v r - (X_u u + X_uu u|u|)
    m_vv v' = tau_v - m_uu u r - (Y_v v + Y_vv v|v|)
    m_ww w' = tau_w - (B - W)  - (Z_w w + Z_ww w|w|)        (Fossen's g_z = -(W - B) for a level body)
    m_rr r' = tau_r - (m_vv - m_uu) u v - (N_r r + N_rr r|r|)

integrated by RK4 at ``step_s``. Streams (mavros names): the override (no header: log time at the command), the
servo outputs (header at the command, logged 2 ms later), ``global_position/rel_alt`` (Float64, m up),
``imu/data`` (Imu in ROS axes, body FLU / earth ENU: quaternion, rates, specific force) and
``local_position/velocity_body`` (TwistStamped, body FLU, what ArduSub's EKF gives with a DVL).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from pipeline.rk4 import LISTS, rk4_step
from pipeline.sim.ardusub import FLOAT64_TYPE, RC_OUT_TYPE, _late, thrust_N
from pipeline.sim.sensors import SensorOptions, Stream, StreamSpec, ahrs_quaternion
from pipeline.sim.trial import EPOCH_NS

OVERRIDE_TYPE = "mavros_msgs/msg/OverrideRCIn"
IMU_TYPE = "sensor_msgs/msg/Imu"
TWIST_TYPE = "geometry_msgs/msg/TwistStamped"
SIM_DOFS = ("u", "v", "w", "r")  # the simulated DOFs (the vehicle is held level)
#: ArduSub's RC channels 1-6 (RCMAP defaults): the override's channels[0..5]
CHANNELS = ("pitch", "roll", "throttle", "yaw", "forward", "lateral")
#: the vectored frame (FRAME_CONFIG 1), motors x (roll, pitch, yaw, throttle, forward, lateral)
FACTORS = np.array([[0, 0, 1, 0, -1, 1], [0, 0, -1, 0, -1, -1], [0, 0, -1, 0, 1, 1], [0, 0, 1, 0, 1, -1],
                    [1, 0, 0, -1, 0, 0], [-1, 0, 0, -1, 0, 0]], dtype=float)
_FACTOR_AXES = ("roll", "pitch", "yaw", "throttle", "forward", "lateral")
#: body FRD: motors 1-4 horizontal at 45 degrees (1 front right, 2 front left, 3 rear right, 4 rear left), 5-6
#: vertical (right, left); a positive thrust pushes the vehicle along DIRECTIONS
POSITIONS = np.array([[0.156, 0.111, 0.085], [0.156, -0.111, 0.085], [-0.156, 0.111, 0.085],
                      [-0.156, -0.111, 0.085], [0.0, 0.218, 0.0], [0.0, -0.218, 0.0]])
_S = np.sqrt(0.5)
DIRECTIONS = np.array([[-_S, _S, 0.0], [-_S, -_S, 0.0], [_S, _S, 0.0], [_S, -_S, 0.0], [0, 0, 1.0], [0, 0, 1.0]])

#: the servo outputs and the override at 10 Hz (the outputs logged 2 ms late); rel_alt 10 Hz, 3 mm; IMU 50 Hz,
#: 3 mrad/s of gyro noise and 0.003 in each quaternion component; the EKF's body velocity 10 Hz, 1 cm/s
RC_SPEC = StreamSpec(10.0, 0.002, 0.0, 0.0)
REL_ALT_SPEC = StreamSpec(10.0, 0.005, 0.0, 0.003)
IMU_SPEC = StreamSpec(50.0, 0.003, 0.0, 0.003)
VELOCITY_SPEC = StreamSpec(10.0, 0.004, 0.0, 0.01)


@dataclass(frozen=True)
class VectoredTruth:
    """The BlueROV2's constants (SI; damping positive; Wu 2018's identified values) and the pilot's amplitudes
    (fractions of full stick: forward, lateral, yaw, throttle; throttle around a bias)."""

    mass_kg: float = 11.5
    izz_kgm2: float = 0.16
    added_kg: tuple[float, float, float, float] = (5.5, 12.7, 14.57, 0.12)       # -X_udot -Y_vdot -Z_wdot -N_rdot
    linear: tuple[float, float, float, float] = (4.03, 6.22, 5.18, 0.07)         # X_u Y_v Z_w N_r
    quadratic: tuple[float, float, float, float] = (18.18, 21.66, 36.99, 1.55)   # X_uu Y_vv Z_ww N_rr
    net_buoyancy_N: float = 2.0           # B - W: positive floats up
    gravity_mps2: float = 9.81
    depth0_m: float = 10.0
    amplitude: tuple[float, float, float, float] = (0.4, 0.3, 0.2, 0.35)
    throttle_bias: float = -0.05          # the depth stays within a few metres (the thrust table is asymmetric)

    @property
    def m(self) -> np.ndarray:
        """Diagonal of M over u, v, w, r."""
        return np.array([self.mass_kg] * 3 + [self.izz_kgm2]) + np.array(self.added_kg)


@dataclass
class VectoredTrial:
    """A simulated manual-mode trial: the truth on the integration grid, the mavros streams, what made them."""

    truth: pd.DataFrame   # t_ns, x/y/depth_m, yaw_rad, u..r, their derivatives, tau_*, pwm1..6_us (servo outputs)
    streams: dict[str, Stream]
    vehicle: VectoredTruth
    seed: int
    duration_s: float
    sensors: SensorOptions = field(default_factory=SensorOptions)


def allocation() -> np.ndarray:
    """B (6 x 6): column i is [d_i; r_i x d_i] of motor i."""
    return np.vstack([DIRECTIONS.T, np.cross(POSITIONS, DIRECTIONS).T])


def mixed(channels_us: np.ndarray) -> np.ndarray:
    """Motor outputs in [-1, 1] from the override's channels 1-6 (n, 6), by :data:`FACTORS` (unclipped: the
    trial stays inside the linear range)."""
    x = (np.asarray(channels_us, dtype=float)[:, [CHANNELS.index(a) for a in _FACTOR_AXES]] - 1500.0) / 400.0
    return x @ FACTORS.T


def tau_N(pwm_us: np.ndarray) -> np.ndarray:
    """The true generalized force (n, 6) from the six motors' PWM (n, 6)."""
    return thrust_N(np.asarray(pwm_us, dtype=float)) @ allocation().T


def pilot_us(t_s: np.ndarray, v: VectoredTruth, seed: int) -> np.ndarray:
    """The pilot's channels 1-6 (n, 6), integer us: two sines per axis, periods and phases drawn from ``seed``."""
    rng = np.random.default_rng(seed)
    out = np.full((t_s.size, 6), 1500.0)
    for axis, amp, bias in zip(("forward", "lateral", "yaw", "throttle"), v.amplitude, (0, 0, 0, v.throttle_bias),
                               strict=True):
        periods = rng.uniform(4.0, 9.0), rng.uniform(10.0, 22.0)
        phases = rng.uniform(0, 2 * np.pi, 2)
        s = 0.55 * np.sin(2 * np.pi * t_s / periods[0] + phases[0]) + 0.45 * np.sin(2 * np.pi * t_s / periods[1]
                                                                                    + phases[1])
        out[:, CHANNELS.index(axis)] = 1500.0 + 400.0 * (bias + amp * s)
    return np.rint(out)


def vectored_trial(duration_s: float = 60.0, seed: int = 0, vehicle: VectoredTruth | None = None, *,
                   step_s: float = 0.002, phase_s: float = 0.025) -> VectoredTrial:
    """Simulate a manual-mode trial of ``duration_s``: pilot commands every 0.1 s from ``phase_s``. Deterministic
    for a seed."""
    v = vehicle or VectoredTruth()
    rng = np.random.default_rng(seed + 1)
    m = v.m.tolist()
    lin, quad = list(v.linear), list(v.quadratic)
    n = int(round(duration_s / step_s))
    t = np.arange(n + 1) * step_s
    per_rc = int(round(1.0 / (RC_SPEC.rate_hz * step_s)))
    first = int(round(phase_s / step_s))
    rc_rows = np.arange(first, n + 1, per_rc)
    pilot = pilot_us(t[rc_rows], v, seed)
    pilot[0] = [1500, 1500, 1500 + 400 * v.throttle_bias, 1500, 1500, 1500]
    pilot = np.rint(pilot)
    motors = mixed(pilot)
    if np.abs(motors).max() >= 1.0:
        raise ValueError("the pilot's inputs leave the frame's linear range: lower VectoredTruth.amplitude")
    servo = np.rint(1500.0 + 400.0 * motors)
    held = np.clip(np.searchsorted(rc_rows, np.arange(n + 1), side="right") - 1, 0, None)
    pwm = servo[held]
    pwm[: first] = 1500.0                                           # nothing commanded before the first message
    tau = tau_N(pwm)[:, [0, 1, 2, 5]]
    g_w = v.net_buoyancy_N                                           # g(eta)_z = B - W when level

    def f(x: list[float], tq: list[float]) -> list[float]:
        _, _, _, psi, u, vv, w, r = x
        c, s = np.cos(psi), np.sin(psi)
        return [u * c - vv * s, u * s + vv * c, w, r,
                (tq[0] + m[1] * vv * r - lin[0] * u - quad[0] * u * abs(u)) / m[0],
                (tq[1] - m[0] * u * r - lin[1] * vv - quad[1] * vv * abs(vv)) / m[1],
                (tq[2] - g_w - lin[2] * w - quad[2] * w * abs(w)) / m[2],
                (tq[3] - (m[1] - m[0]) * u * vv - lin[3] * r - quad[3] * r * abs(r)) / m[3]]

    x = np.zeros((n + 1, 8))
    state = [0.0, 0.0, v.depth0_m, 0.0, 0.0, 0.0, 0.0, 0.0]
    x[0] = state
    tau_list = tau.tolist()
    for k in range(n):
        state = rk4_step(f, state, tau_list[k], step_s, LISTS)
        x[k + 1] = state
    xdot = np.array([f(row, tq) for row, tq in zip(x.tolist(), tau_list, strict=True)])
    t_ns = EPOCH_NS + np.rint(t * 1e9).astype(np.int64)
    truth = pd.DataFrame({"t_ns": t_ns, "x_m": x[:, 0], "y_m": x[:, 1], "depth_m": x[:, 2], "yaw_rad": x[:, 3],
                          **{f"{d}_mps" if d != "r" else "r_radps": x[:, 4 + i] for i, d in enumerate(SIM_DOFS)},
                          **{f"{d}dot": xdot[:, 4 + i] for i, d in enumerate(SIM_DOFS)},
                          **{f"tau_{d}": tau[:, i] for i, d in enumerate(SIM_DOFS)},
                          **{f"pwm{i + 1}_us": pwm[:, i] for i in range(6)}})
    streams = _streams(truth, x, xdot, t_ns, rc_rows, pilot, servo, v, step_s, rng)
    return VectoredTrial(truth, streams, v, seed, duration_s)


def _rows(n: int, step_s: float, spec: StreamSpec, start_s: float) -> np.ndarray:
    return np.arange(int(round(start_s / step_s)), n, int(round(1.0 / (spec.rate_hz * step_s))))


def _streams(truth: pd.DataFrame, x: np.ndarray, xdot: np.ndarray, t_ns: np.ndarray, rc_rows: np.ndarray,
             pilot: np.ndarray, servo: np.ndarray, v: VectoredTruth, step_s: float, rng: np.random.Generator
             ) -> dict[str, Stream]:
    n = len(truth)
    channels = np.full((rc_rows.size, 18), 65535, dtype=np.uint16)   # CHAN_NOCHANGE beyond the six axes
    channels[:, :6] = pilot
    outputs = np.zeros((rc_rows.size, 16), dtype=np.uint16)          # outputs 7-16 not assigned
    outputs[:, :6] = servo
    streams = {
        "override": Stream("override", "/mavros/rc/override", OVERRIDE_TYPE, t_ns[rc_rows], t_ns[rc_rows],
                           {"channels": channels}),
        "rc": Stream("rc", "/mavros/rc/out", RC_OUT_TYPE, _late(t_ns[rc_rows], RC_SPEC.latency_s), t_ns[rc_rows],
                     {"channels": outputs}),
    }
    alt = _rows(n, step_s, REL_ALT_SPEC, 0.05)
    streams["rel_alt"] = Stream("rel_alt", "/mavros/global_position/rel_alt", FLOAT64_TYPE,
                                _late(t_ns[alt], REL_ALT_SPEC.latency_s), t_ns[alt],
                                {"data": -x[alt, 2] + rng.normal(0.0, REL_ALT_SPEC.noise, alt.size)})
    imu = _rows(n, step_s, IMU_SPEC, 0.01)
    zero = np.zeros(imu.size)
    q = ahrs_quaternion(zero, zero, x[imu, 3], "flu_enu") + rng.normal(0.0, IMU_SPEC.noise, (imu.size, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    u, vv, r = x[imu, 4], x[imu, 5], x[imu, 7]
    accel_frd = np.stack([xdot[imu, 4] - r * vv, xdot[imu, 5] + r * u, xdot[imu, 6] - v.gravity_mps2], axis=1)
    gyro = rng.normal(0.0, 0.003, (imu.size, 3))
    fields = {**{f"orientation.{a}": q[:, j] for j, a in enumerate("xyzw")},
              "angular_velocity.x": gyro[:, 0], "angular_velocity.y": gyro[:, 1], "angular_velocity.z": -r + gyro[:, 2],
              "linear_acceleration.x": accel_frd[:, 0], "linear_acceleration.y": -accel_frd[:, 1],
              "linear_acceleration.z": -accel_frd[:, 2]}
    streams["imu"] = Stream("imu", "/mavros/imu/data", IMU_TYPE, _late(t_ns[imu], IMU_SPEC.latency_s), t_ns[imu],
                            fields, frame_id="base_link")
    vel = _rows(n, step_s, VELOCITY_SPEC, 0.07)
    noise = rng.normal(0.0, VELOCITY_SPEC.noise, (vel.size, 3))
    streams["velocity_body"] = Stream(
        "velocity_body", "/mavros/local_position/velocity_body", TWIST_TYPE,
        _late(t_ns[vel], VELOCITY_SPEC.latency_s), t_ns[vel],
        {"twist.linear.x": x[vel, 4] + noise[:, 0], "twist.linear.y": -x[vel, 5] + noise[:, 1],
         "twist.linear.z": -x[vel, 6] + noise[:, 2], "twist.angular.x": np.zeros(vel.size),
         "twist.angular.y": np.zeros(vel.size), "twist.angular.z": -x[vel, 7]}, frame_id="base_link")
    return streams
