"""One simulated trial: the 6-DOF vehicle integrated under its commands (:mod:`pipeline.sim.vehicle`), the truth
table at the integration rate and the sensor streams (:mod:`pipeline.sim.sensors`), and the packaged DAGON vehicle.

Three presets of excitation, disturbance and sensors (``generate_trial(..., preset=...)``):

- ``"gentle"`` (the default, what the demo and every existing output use): three summed sines per horizontal
  thruster, periods 6-45 s, 2600 rpm; no disturbance; :class:`SensorOptions` defaults.
- ``"hard"``, a trial that outruns its sensors: :meth:`Controls.hard` (one sinusoid per thruster, periods 5-18 s,
  1800 rpm), :meth:`Disturbance.hard` (a tether-like Ornstein-Uhlenbeck force in surge, sway and yaw) and
  :meth:`SensorOptions.hard` (Hall-counter thruster speeds, gyro and FOG biases with the Earth's rate).
- ``"family"``: each trial draws its own regime from its seed (:func:`pipeline.sim.regime.draw_regime`: 1-3
  sines per thruster, periods 5-45 s, half or full thrust, the tether on or off, Hall-counter speeds on or off,
  the hard preset's rate biases), recorded as ``SimTrial.regime``.

Benchmarks draw each preset's trials from its own seeds, :data:`PRESET_SEED_OFFSET` (hard: seed k -> 3200 + k).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import pandas as pd

from pipeline import physics
from pipeline.config import load_vehicle
from pipeline.config.vehicle import Vehicle
from pipeline.sim.disturbance import Disturbance
from pipeline.sim.regime import Regime, draw_regime
from pipeline.sim.sensors import SensorOptions, Stream, dvl_rotation, make_streams, rate_bias
from pipeline.sim.truth import SimTruth, load_truth
from pipeline.sim.vehicle import Commander, Controls, Dynamics, integrate
from pipeline.vocabulary import DOFS, acceleration_column, force_columns, velocity_column

PRESETS = ("gentle", "hard", "family")
#: Benchmark seed k of a preset is simulator seed ``PRESET_SEED_OFFSET[preset] + k``: the presets' trials never
#: share a seed (and so never share command phases or sensor noise).
PRESET_SEED_OFFSET = {"gentle": 0, "hard": 3200, "family": 6400}

log = logging.getLogger(__name__)

EPOCH_NS = 1_700_000_000_000_000_000  # 2023-11-14T22:13:20Z: trials start here (+ start_offset_s)


@dataclass
class SimTrial:
    """A simulated trial: the truth table, the sensor streams, and what made them."""

    truth: pd.DataFrame
    streams: dict[str, Stream]
    vehicle: Vehicle
    sim_truth: SimTruth
    seed: int
    duration_s: float
    sensors: SensorOptions = field(default_factory=SensorOptions)
    preset: str = "gentle"
    disturbance: Disturbance | None = None
    regime: Regime | None = None  # the "family" preset's draw; None for the others


def example_vehicle_path(fmt: str = "mcap") -> Path:
    """Path of the packaged DAGON vehicle config (ROS topics). For ``fmt="csv"`` use
    :func:`load_example_vehicle` or :func:`pipeline.sim.writers.csv_vehicle_yaml`, which write the CSV layout."""
    if fmt == "csv":
        raise ValueError("the CSV layout is generated: use load_example_vehicle('csv') or example(out_dir, 'csv')")
    return Path(str(resources.files("pipeline.sim").joinpath("dagon.yaml")))


def load_example_vehicle(fmt: str = "mcap") -> Vehicle:
    """The packaged DAGON vehicle config; ``fmt="csv"``: its CSV-layout variant (one file per stream)."""
    vehicle = load_vehicle(example_vehicle_path())
    if fmt == "csv":
        from pipeline.sim.writers import csv_vehicle

        return csv_vehicle(vehicle)
    return vehicle


def truth_table(vehicle: Vehicle, dyn: Dynamics, states: dict[str, np.ndarray], t_ns: np.ndarray,
                sensors: SensorOptions | None = None) -> pd.DataFrame:
    """The truth DataFrame: velocities, accelerations, pose, speeds, thrusts, forces and true damping.

    After the columns every trial has always had (unchanged): ``dist_*``, the external force f (zero without a
    disturbance); ``d_true_*`` = ``d_* - dist_*``, what the damping target tau - M nu_dot - C(nu) nu - g(eta)
    equals with exact nu, nu_dot and applied tau (``tau_*``, the force the thrusters actually apply); and the rate
    sensors' total biases ``gyro_bias_{p,q,r}_radps``, ``fog_bias_r_radps`` (:func:`pipeline.sim.sensors.rate_bias`).
    """
    eta, nu, n = states["eta"], states["nu"], states["n"]
    force = states.get("force")
    nudot = dyn.nu_dot(eta, nu, n, force)
    thrust = dyn.thrust(n, nu)  # applied (after the truth's inflow loss, if any); tau_* = B T: the true forces
    tau = thrust @ dyn.B.T
    cols: dict[str, np.ndarray] = {"t_ns": t_ns.astype(np.int64)}
    for j, dof in enumerate(DOFS):
        cols[velocity_column(dof)] = nu[:, j]
    for j, dof in enumerate(DOFS):
        cols[acceleration_column(dof)] = nudot[:, j]
    for j, name in enumerate(("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")):
        cols[name] = eta[:, j]
    cols["depth_m"] = eta[:, 2]
    for j, thr in enumerate(vehicle.thrusters):
        cols[thr.speed_signal] = n[:, j]
    for j, thr in enumerate(vehicle.thrusters):
        cols[f"{thr.speed_signal.removesuffix('_rpm')}_cmd_rpm"] = states["n_cmd"][:, j]
    for j, thr in enumerate(vehicle.thrusters):
        cols[f"T_{thr.name}_N"] = thrust[:, j]
    terms = {
        "tau": tau,
        "Mnudot": nudot @ dyn.M.T,
        "Cnu": physics.coriolis_force(dyn.M, nu),
        "g": dyn.restoring(eta[:, 3], eta[:, 4]),
        "d": dyn.truth.damping(nu),
    }
    dist = np.zeros_like(nu) if force is None else force
    terms["dist"] = dist
    terms["d_true"] = terms["d"] - dist
    for prefix, values in terms.items():
        for j, name in enumerate(force_columns(prefix)):
            cols[name] = values[:, j]
    gyro, fog = rate_bias(eta, sensors or SensorOptions())
    for j, dof in enumerate(("p", "q", "r")):
        cols[f"gyro_bias_{velocity_column(dof)}"] = gyro[:, j]
    cols[f"fog_bias_{velocity_column('r')}"] = fog
    return pd.DataFrame(cols)


def generate_trial(
    vehicle: Vehicle | None = None,
    duration_s: float = 60.0,
    seed: int = 0,
    *,
    truth: SimTruth | None = None,
    rate_hz: float = 200.0,
    controls: Controls | None = None,
    sensors: SensorOptions | None = None,
    disturbance: Disturbance | None = None,
    preset: str = "gentle",
    nu0: np.ndarray | None = None,
    eta0: np.ndarray | None = None,
    start_offset_s: float = 0.0,
    warmup_s: float = 0.0,
) -> SimTrial:
    """Simulate one trial, deterministic given ``seed``.

    ``vehicle``: default the packaged DAGON; ``truth``: the true damping (default DAGON's); ``rate_hz``: RK4
    step and truth rate (1e9 / rate_hz must be an integer number of ns); ``controls``: thruster commands and
    depth/pitch hold; ``sensors``: rates, noise, stamps, dropouts; ``start_offset_s``: trial start after
    :data:`EPOCH_NS`; ``warmup_s``: seconds simulated (same commands) before the trial starts and dropped, so
    that a trial begins already in motion rather than from rest (as a logged run cut out of a longer mission).
    ``preset``: ``"gentle"``, ``"hard"`` or ``"family"`` (module docstring); it fills ``controls``, ``sensors``
    and ``disturbance`` where they are not given (``"gentle"``: no disturbance; ``"family"``: the seed's regime,
    ``SimTrial.regime``). The disturbance is drawn from its own child of the seed, so the commands and sensor
    noise of a trial do not depend on it (nor on the regime, drawn from another child).
    """
    if preset not in PRESETS:
        raise ValueError(f"preset must be one of {PRESETS}, not {preset!r}")
    hard = preset == "hard"
    vehicle = vehicle if vehicle is not None else load_example_vehicle()
    truth = truth if truth is not None else load_truth()
    regime = draw_regime(seed) if preset == "family" else None
    if regime is not None:
        controls = controls or regime.controls()
        sensors = sensors or regime.sensors()
        disturbance = disturbance if disturbance is not None else regime.disturbance_model()
    controls = controls or (Controls.hard() if hard else Controls())
    sensors = sensors or (SensorOptions.hard() if hard else SensorOptions())
    if disturbance is None and hard:
        disturbance = Disturbance.hard()
    dt_ns = 1e9 / rate_hz
    if abs(dt_ns - round(dt_ns)) > 1e-6:
        raise ValueError(f"rate_hz {rate_hz} does not give an integer step in ns")
    rng_cmd, rng_sensor = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    dyn = Dynamics(vehicle, truth)
    commander = Commander(dyn, controls, rng_cmd)
    eta_start = np.zeros(6) if eta0 is None else np.asarray(eta0, dtype=float)
    if eta0 is None and controls.depth_control:
        eta_start[2] = controls.depth_ref_m
    nu_start = np.zeros(6) if nu0 is None else np.asarray(nu0, dtype=float)
    force = None
    if disturbance is not None:
        n_steps = int(round((duration_s + warmup_s) * rate_hz)) + 1
        rng_force = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])
        force = disturbance.sample(n_steps, 1.0 / rate_hz, rng_force)
    states = integrate(dyn, commander, duration_s + warmup_s, rate_hz, eta_start, nu_start,
                       np.zeros(len(vehicle.thrusters)), force)
    if force is not None:
        states["force"] = force
    skip = int(round(warmup_s * rate_hz))
    if skip:
        states = {key: val[skip:] for key, val in states.items()}
        states["t_s"] = states["t_s"] - states["t_s"][0]
    start_ns = EPOCH_NS + int(round(start_offset_s * 1e9))
    t_ns = start_ns + np.arange(states["t_s"].size, dtype=np.int64) * int(round(dt_ns))
    table = truth_table(vehicle, dyn, states, t_ns, sensors)
    mount = {
        "position_m": np.asarray(vehicle.sensors.dvl.position_m, dtype=float),
        "rotation": dvl_rotation(vehicle.sensors.dvl.rotation_rpy_deg),
        "joint_names": [t.name for t in vehicle.thrusters],
        "gravity_mps2": vehicle.rigid_body.gravity_mps2,
    }
    if vehicle.sensors.accelerometer is not None:
        mount["imu_position_m"] = np.asarray(vehicle.sensors.accelerometer.position_m, dtype=float)
    nu_dot = table[[acceleration_column(dof) for dof in DOFS]].to_numpy()
    streams = make_streams({**states, "t_ns": t_ns, "grid_hz": rate_hz, "nu_dot": nu_dot}, mount, sensors,
                           rng_sensor)
    log.info("simulated %s for %.1f s (seed %d%s): %d truth rows, %s", vehicle.name, duration_s, seed,
             f", {regime.describe()}" if regime else "", len(table), {k: len(s) for k, s in streams.items()})
    return SimTrial(table, streams, vehicle, truth, seed, duration_s, sensors, preset, disturbance, regime)
