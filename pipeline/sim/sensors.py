"""Sensor models: each stream samples the truth at its own rate, adds noise, and stamps its messages.

The DVL is as real ones are (defaults: a 3.6 Hz DVL as measured on a basin trial): pings 0.25-0.31 s apart,
each the average velocity over 0.1 s, white noise 0.02 m/s per axis, 0.5 % outliers of 0.15 m/s, a 0.3 %
scale error, its true mount turned 1 deg in yaw from the configured one, and bottom lock lost on about 20 % of
the pings in bursts of 6 pings on average (a two-state Markov chain), velocity zero while lost.

The AHRS's ``linear_acceleration`` is the specific force (acceleration less gravity) at the IMU's position
(``mount["imu_position_m"]``, else ``imu_position_m``), in the AHRS's convention, with white noise 0.02 m/s^2
and a constant bias per axis (a MEMS IMU's); drawn after every other stream, so the other streams are the same
with or without it.

Rate sensors may carry a bias (off by default; :meth:`SensorOptions.hard`): a constant per axis plus the Earth's
rotation at ``earth_rate_latitude_deg`` seen in body axes, ``R(eta)^T Omega (cos L, 0, -sin L)`` (NED), on the
AHRS's gyros and on the FOG; :func:`rate_bias` gives its value per truth row. Thruster speeds may come from a Hall
counter (``thruster_counter_ppr``): the mean speed over each counting window (back to back, ``1 / rate_hz`` long),
quantized to whole pulses per window, stamped at the window's end, so it lags the truth by half a window.

Sample times are the nominal times ``k / rate_hz`` snapped to the integration grid, so a noise-free stream
equals the truth at those rows exactly. Every message has a log time (``t + latency_s``) and a header stamp
(``t + clock_offset_s``, the sensor's own clock); the vehicle config's ``offset_s`` undoes the one its
``clock`` uses. Streams hold the messages' fields as arrays keyed by field path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from pipeline.sim.vehicle import euler_rotation

# NED <- ENU axis swap and FRD <- FLU sign flip (both their own inverses)
_NED_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_FRD_FLU = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class StreamSpec:
    rate_hz: float
    latency_s: float = 0.0          # log time - sample time
    clock_offset_s: float = 0.0     # header stamp - sample time
    noise: float = 0.0              # std of the additive noise, in the message's unit


@dataclass(frozen=True)
class SensorOptions:
    """Rates, stamps, noise and mounting of the simulated sensors (defaults: DAGON's, TABLE I of the paper)."""

    ahrs: StreamSpec = StreamSpec(120.0, 0.003, 0.010, math.radians(0.1))   # noise: angles (rad)
    ahrs_rate_noise_radps: float = 0.002
    ahrs_convention: str = "frd_ned"                                        # or "flu_enu"
    accel_noise_mps2: float = 0.02                                          # IMU accelerometers: white, per axis
    accel_bias_mps2: tuple[float, float, float] = (0.02, -0.015, 0.025)     # constant, in the IMU's axes
    imu_position_m: tuple[float, float, float] = (0.2, 0.1, -0.1)           # unless the mount gives it
    fog: StreamSpec = StreamSpec(100.0, 0.002, 0.0, 2e-4)
    depth: StreamSpec = StreamSpec(10.0, 0.005, 0.0, 0.01)
    dvl: StreamSpec = StreamSpec(3.6, 0.020, -0.05, 0.02)                 # noise: white, m/s per axis
    dvl_ping_interval_s: tuple[float, float] | None = (0.25, 0.31)          # None: regular pings at dvl.rate_hz
    dvl_outlier_rate: float = 0.005                                         # fraction of pings with an outlier
    dvl_outlier_mps: float = 0.15                                           # its SD per axis
    dvl_scale_error: float = 0.003                                          # measured = (1 + e) x true
    dvl_misalignment_rpy_deg: tuple[float, float, float] = (0.0, 0.0, 1.0)  # true mount - configured mount
    dvl_averaging_s: float = 0.1                                            # each ping averages this window
    dvl_lock_loss_fraction: float = 0.2                                     # pings without bottom lock ...
    dvl_lock_loss_mean_pings: float = 6.0                                   # ... in bursts of this mean length
    thrusters: StreamSpec = StreamSpec(20.0, 0.001, 0.0, 5.0)               # noise in rpm
    thruster_unit: str = "rad/s"                                            # or "rpm"
    bottom_depth_m: float = 10.0
    dropout_bursts_per_min: float = 0.0                                     # long outages (turns, steep slopes)
    dropout_duration_s: tuple[float, float] = (2.0, 8.0)
    gyro_bias_radps: tuple[float, float, float] = (0.0, 0.0, 0.0)            # AHRS gyros, constant, body FRD
    fog_bias_radps: float = 0.0                                             # the FOG (yaw rate), constant
    earth_rate_latitude_deg: float | None = None                            # None: no Earth rate on the rates
    thruster_counter_ppr: int | None = None   # Hall pulses per revolution; None: speeds sampled, plus noise
    noise: bool = True      # False: every sensor ideal (no noise, outliers, scale, misalignment, averaging, bias,
    #                         counter quantization)
    dropouts: bool = True   # False: the DVL never loses bottom lock

    @classmethod
    def hard(cls) -> SensorOptions:
        """The hard preset's sensors: the default ones, plus rate-sensor biases and Hall-counter thruster speeds.

        Gyros (MEMS): (3, -2, 3) x 1e-4 rad/s; FOG: 2e-4 rad/s; both plus the Earth's rate at 45 deg N
        (7.29e-5 rad/s, -5.2e-5 on r when level): about 2.5e-4 (gyro) and 1.5e-4 (FOG) rad/s in all on r.
        Thruster speeds: one Hall sensor's rising edges on a 14-pole motor (7 pulses per revolution) counted over
        0.1-s windows (10 Hz): 85.7 rpm per count, 50 ms late, no other noise.
        """
        return cls(gyro_bias_radps=(3e-4, -2e-4, 3e-4), fog_bias_radps=2e-4, earth_rate_latitude_deg=45.0,
                   thruster_counter_ppr=7, thrusters=StreamSpec(10.0, 0.001, 0.0, 0.0))


@dataclass
class Stream:
    """One topic's messages: log and header times (int64 ns) and field arrays keyed by field path."""

    name: str
    topic: str
    msgtype: str
    log_ns: np.ndarray
    header_ns: np.ndarray
    fields: dict[str, np.ndarray]
    frame_id: str = ""
    joint_names: tuple[str, ...] = field(default_factory=tuple)
    index: np.ndarray | None = None  # truth rows sampled

    def __len__(self) -> int:
        return int(self.log_ns.size)


def sample_rows(n_rows: int, grid_hz: float, rate_hz: float) -> np.ndarray:
    """Truth rows nearest to the nominal sample times k / rate_hz."""
    count = int(math.floor((n_rows - 1) / grid_hz * rate_hz + 1e-9)) + 1
    return np.minimum(np.rint(np.arange(count) * (grid_hz / rate_hz)).astype(np.int64), n_rows - 1)


EARTH_RATE_RADPS = 7.2921159e-5


def rate_bias(eta: np.ndarray, opts: SensorOptions) -> tuple[np.ndarray, np.ndarray]:
    """The rate sensors' total bias per row of ``eta`` (m, 6): (gyro (m, 3) in body FRD, FOG (m,) on r), zero
    without noise. Constant biases plus the Earth's rate in body axes at the vehicle's attitude."""
    gyro = np.zeros((eta.shape[0], 3))
    fog = np.zeros(eta.shape[0])
    if not opts.noise:
        return gyro, fog
    gyro += np.asarray(opts.gyro_bias_radps, dtype=float)
    fog += opts.fog_bias_radps
    if opts.earth_rate_latitude_deg is not None:
        lat = math.radians(opts.earth_rate_latitude_deg)
        w_ned = EARTH_RATE_RADPS * np.array([math.cos(lat), 0.0, -math.sin(lat)])
        w_body = np.einsum("mji,j->mi", euler_rotation(eta[:, 3], eta[:, 4], eta[:, 5]), w_ned)  # R^T w
        gyro += w_body
        fog += w_body[:, 2]
    return gyro, fog


def hall_counter(n_rpm: np.ndarray, grid_hz: float, ends: np.ndarray, ppr: int, rng: np.random.Generator
                 ) -> np.ndarray:
    """Speeds (rpm) a Hall counter reports at the window ends ``ends`` (truth rows; a window runs from the previous
    end): whole pulses counted in the window (``ppr`` per revolution, from a random initial shaft angle) over the
    window's length. The count carries the fraction of a pulse over to the next window, as a counter does."""
    if int(ppr) != ppr or ppr < 1:
        raise ValueError(f"thruster_counter_ppr must be a whole number of pulses per revolution >= 1, not {ppr!r}")
    revs = np.concatenate([np.zeros((1, n_rpm.shape[1])),
                           np.cumsum(0.5 * (n_rpm[1:] + n_rpm[:-1]), axis=0) / (60.0 * grid_hz)])
    pulses = np.floor((revs + rng.uniform(size=n_rpm.shape[1])) * ppr)
    counts = np.diff(pulses[ends], axis=0)
    window_s = np.diff(ends)[:, None] / grid_hz
    return counts * 60.0 / (ppr * window_s)


def _stamps(t_ns: np.ndarray, spec: StreamSpec) -> tuple[np.ndarray, np.ndarray]:
    return t_ns + int(round(spec.latency_s * 1e9)), t_ns + int(round(spec.clock_offset_s * 1e9))


def ahrs_quaternion(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray, convention: str) -> np.ndarray:
    """Attitude quaternions (x, y, z, w), w >= 0: body FRD -> NED, or ROS body FLU -> ENU."""
    R = euler_rotation(roll, pitch, yaw)
    if convention == "flu_enu":
        R = _NED_ENU @ R @ _FRD_FLU
    elif convention != "frd_ned":
        raise ValueError(f"AHRS convention must be 'frd_ned' or 'flu_enu', not {convention!r}")
    q = Rotation.from_matrix(R).as_quat()
    return np.where(q[:, 3:4] < 0, -q, q)


def dvl_rotation(rpy_deg: tuple[float, float, float]) -> np.ndarray:
    """DVL frame -> body frame rotation from the mount's roll-pitch-yaw (degrees)."""
    r, p, y = np.radians(rpy_deg)
    return euler_rotation(np.array(r), np.array(p), np.array(y))


def dvl_measurement(nu: np.ndarray, position_m: np.ndarray, rot_dvl_to_body: np.ndarray) -> np.ndarray:
    """Noise-free DVL velocity in its own frame: R^T (v + omega x r_dvl); nu (n, 6) -> (n, 3)."""
    v_body = nu[:, :3] + np.cross(nu[:, 3:], np.asarray(position_m, dtype=float))
    return v_body @ rot_dvl_to_body  # rows: (R^T v)^T = v^T R


def specific_force(nu: np.ndarray, nu_dot: np.ndarray, roll: np.ndarray, pitch: np.ndarray,
                   position_m: np.ndarray, g_mps2: float) -> np.ndarray:
    """True specific force (n, 3) in body FRD axes at ``position_m``: a - g_b, with the point's acceleration
    a = v_dot + omega x v + omega_dot x r + omega x (omega x r) and gravity g_b = R^T (0, 0, g)."""
    v, w, v_dot, w_dot = nu[:, :3], nu[:, 3:], nu_dot[:, :3], nu_dot[:, 3:]
    r = np.broadcast_to(np.asarray(position_m, dtype=float), v.shape)
    a = v_dot + np.cross(w, v) + np.cross(w_dot, r) + np.cross(w, np.cross(w, r))
    g_b = g_mps2 * np.stack([-np.sin(pitch), np.cos(pitch) * np.sin(roll), np.cos(pitch) * np.cos(roll)], axis=1)
    return a - g_b


def ping_rows(n_rows: int, grid_hz: float, interval_s: tuple[float, float], rng: np.random.Generator) -> np.ndarray:
    """Truth rows of irregular pings: intervals uniform in ``interval_s``, snapped to the truth grid."""
    lo, hi = interval_s
    duration_s = (n_rows - 1) / grid_hz
    count = int(duration_s / lo) + 2
    t = np.concatenate([[0.0], np.cumsum(rng.uniform(lo, hi, size=count))])
    t = t[t <= duration_s]
    return np.unique(np.minimum(np.rint(t * grid_hz).astype(np.int64), n_rows - 1))


def lock_chain(n_pings: int, fraction: float, mean_pings: float, rng: np.random.Generator) -> np.ndarray:
    """True where a ping has bottom lock: a two-state Markov chain losing lock on ``fraction`` of the pings in
    bursts of ``mean_pings`` on average (exit probability 1/mean, entry fraction/(1-fraction)/mean)."""
    lock = np.ones(n_pings, dtype=bool)
    if fraction <= 0 or n_pings == 0:
        return lock
    p_exit = 1.0 / max(mean_pings, 1.0)
    p_enter = min(fraction / (1.0 - fraction) * p_exit, 1.0)
    draws = rng.uniform(size=n_pings)
    lost = draws[0] < fraction
    for k in range(n_pings):
        if k:
            lost = draws[k] >= p_exit if lost else draws[k] < p_enter
        lock[k] = not lost
    return lock


def dropout_mask(t_s: np.ndarray, duration_s: float, opts: SensorOptions, rng: np.random.Generator) -> np.ndarray:
    """True where the DVL has bottom lock: per-ping bursts (:func:`lock_chain`) and long outages at random times."""
    if not opts.dropouts:
        return np.ones(t_s.size, dtype=bool)
    lock = lock_chain(t_s.size, opts.dvl_lock_loss_fraction, opts.dvl_lock_loss_mean_pings, rng)
    if opts.dropout_bursts_per_min <= 0:
        return lock
    n_bursts = rng.poisson(opts.dropout_bursts_per_min * duration_s / 60.0)
    starts = np.sort(rng.uniform(0.0, duration_s, size=n_bursts))
    lengths = rng.uniform(*opts.dropout_duration_s, size=n_bursts)
    for start, length in zip(starts, lengths, strict=True):
        lock[(t_s >= start) & (t_s < start + length)] = False
    return lock


def make_streams(truth: dict[str, np.ndarray], vehicle_mount: dict, opts: SensorOptions,
                 rng: np.random.Generator) -> dict[str, Stream]:
    """All sensor streams from the truth arrays (t_ns, t_s, eta, nu, n; grid_hz) and the DVL mount."""
    t_ns, eta, nu, n_rpm = truth["t_ns"], truth["eta"], truth["nu"], truth["n"]
    grid_hz, rows = float(truth["grid_hz"]), t_ns.size
    duration_s = float(truth["t_s"][-1])
    scale = 1.0 if opts.noise else 0.0
    out: dict[str, Stream] = {}

    i = sample_rows(rows, grid_hz, opts.ahrs.rate_hz)
    ang = eta[i, 3:] + scale * opts.ahrs.noise * rng.standard_normal((i.size, 3))
    q = ahrs_quaternion(ang[:, 0], ang[:, 1], ang[:, 2], opts.ahrs_convention)
    gyro_bias, fog_bias = rate_bias(eta, opts)
    w = nu[i, 3:] + scale * opts.ahrs_rate_noise_radps * rng.standard_normal((i.size, 3))
    if opts.noise and np.any(gyro_bias):
        w = w + gyro_bias[i]
    if opts.ahrs_convention == "flu_enu":
        w = w @ _FRD_FLU
    fields = {f"orientation.{a}": q[:, j] for j, a in enumerate("xyzw")}
    fields.update({f"angular_velocity.{a}": w[:, j] for j, a in enumerate("xyz")})
    fields.update({f"linear_acceleration.{a}": np.zeros(i.size) for a in "xyz"})  # filled last (below)
    log_ns, hdr_ns = _stamps(t_ns[i], opts.ahrs)
    frame = "ahrs_link_frd" if opts.ahrs_convention == "frd_ned" else "ahrs_link"
    out["ahrs"] = Stream("ahrs", "/ahrs/imu", "sensor_msgs/msg/Imu", log_ns, hdr_ns, fields, frame, index=i)

    i = sample_rows(rows, grid_hz, opts.fog.rate_hz)
    rate = nu[i, 5] + scale * opts.fog.noise * rng.standard_normal(i.size)
    if opts.noise and np.any(fog_bias):
        rate = rate + fog_bias[i]
    log_ns, hdr_ns = _stamps(t_ns[i], opts.fog)
    out["fog"] = Stream("fog", "/fog/rate", "geometry_msgs/msg/Vector3Stamped", log_ns, hdr_ns,
                        {"vector.x": np.zeros(i.size), "vector.y": np.zeros(i.size), "vector.z": rate}, "fog",
                        index=i)

    i = sample_rows(rows, grid_hz, opts.depth.rate_hz)
    depth = eta[i, 2] + scale * opts.depth.noise * rng.standard_normal(i.size)
    log_ns, hdr_ns = _stamps(t_ns[i], opts.depth)
    out["depth"] = Stream("depth", "/pressure/depth", "geometry_msgs/msg/PointStamped", log_ns, hdr_ns,
                          {"point.x": np.zeros(i.size), "point.y": np.zeros(i.size), "point.z": depth},
                          "pressure", index=i)

    if opts.dvl_ping_interval_s is None:
        i = sample_rows(rows, grid_hz, opts.dvl.rate_hz)
    else:
        i = ping_rows(rows, grid_hz, opts.dvl_ping_interval_s, rng)
    rot = vehicle_mount["rotation"]
    if opts.noise and any(opts.dvl_misalignment_rpy_deg):
        rot = rot @ dvl_rotation(opts.dvl_misalignment_rpy_deg)
    half = int(round(0.5 * opts.dvl_averaging_s * grid_hz)) if opts.noise else 0
    if half > 0:  # the ping's velocity is the mean over a window centred on its stamp
        csum = np.concatenate([np.zeros((1, 6)), np.cumsum(nu, axis=0)])
        lo, hi = np.maximum(i - half, 0), np.minimum(i + half, rows - 1)
        nu_ping = (csum[hi + 1] - csum[lo]) / (hi - lo + 1)[:, None]
    else:
        nu_ping = nu[i]
    vel = dvl_measurement(nu_ping, vehicle_mount["position_m"], rot) * (1.0 + scale * opts.dvl_scale_error)
    vel = vel + scale * opts.dvl.noise * rng.standard_normal(vel.shape)
    outlier = rng.uniform(size=i.size) < scale * opts.dvl_outlier_rate
    vel[outlier] += opts.dvl_outlier_mps * rng.standard_normal((int(outlier.sum()), 3))
    lock = dropout_mask(truth["t_s"][i], duration_s, opts, rng)
    vel[~lock] = 0.0
    altitude = np.where(lock, opts.bottom_depth_m - eta[i, 2], 0.0)
    log_ns, hdr_ns = _stamps(t_ns[i], opts.dvl)
    out["dvl"] = Stream("dvl", "/dvl/data", "auv_msgs/msg/DVL", log_ns, hdr_ns,
                        {"velocity.x": vel[:, 0], "velocity.y": vel[:, 1], "velocity.z": vel[:, 2],
                         "bottom_lock": lock, "altitude": altitude.astype(np.float32)}, "dvl", index=i)

    i = sample_rows(rows, grid_hz, opts.thrusters.rate_hz)
    if opts.thruster_counter_ppr is not None and opts.noise:  # stamped at each window's end; the first has none
        speed = hall_counter(n_rpm, grid_hz, i, opts.thruster_counter_ppr, rng)
        i = i[1:]
    else:
        speed = n_rpm[i] + scale * opts.thrusters.noise * rng.standard_normal(n_rpm[i].shape)
    if opts.thruster_unit == "rad/s":
        speed = speed * (2 * np.pi / 60.0)
    elif opts.thruster_unit != "rpm":
        raise ValueError(f"thruster_unit must be 'rad/s' or 'rpm', not {opts.thruster_unit!r}")
    log_ns, hdr_ns = _stamps(t_ns[i], opts.thrusters)
    names = tuple(vehicle_mount["joint_names"])
    out["thrusters"] = Stream("thrusters", "/thrusters/joint_states", "sensor_msgs/msg/JointState", log_ns, hdr_ns,
                              {"velocity": speed}, "", names, index=i)

    if "nu_dot" in truth:  # the accelerometers, drawn last so that every other stream is as without them
        i = out["ahrs"].index
        imu_r = np.asarray(vehicle_mount.get("imu_position_m", opts.imu_position_m), dtype=float)
        f = specific_force(nu[i], truth["nu_dot"][i], eta[i, 3], eta[i, 4], imu_r,
                           float(vehicle_mount.get("gravity_mps2", 9.81)))
        if opts.ahrs_convention == "flu_enu":
            f = f @ _FRD_FLU
        f = f + scale * (np.asarray(opts.accel_bias_mps2) + opts.accel_noise_mps2 * rng.standard_normal(f.shape))
        out["ahrs"].fields.update({f"linear_acceleration.{a}": f[:, j] for j, a in enumerate("xyz")})
    return out
