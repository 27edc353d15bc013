"""Synthetic plants with known answers, for tests and benchmarks (the demo's trials come from :mod:`pipeline.sim`'s
6-DOF vehicle): both integrate with the one RK4 of :mod:`pipeline.rk4`.

- :class:`SyntheticPlant` and :func:`synthetic_trial`: a 3-DOF (u, v, r) vehicle with diagonal M and *decoupled*
  damping ``d = l x + q x|x| + c x^3`` per DOF, in the feature-store columns with the true damping beside the
  noisy one (the decoupled study and the rollouts are checked against it).
- :func:`synthetic_frame`: a 3-DOF vehicle with a full M and *coupled* damping terms beyond the Gertler-Hagen /
  McFarland-Whitcomb structures, thrust lost to inflow (absent from the static tau the store carries) and
  lagged thruster commands, as feature-store rows (the coupled study's data).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from pipeline import physics
from pipeline.rk4 import rk4_step
from pipeline.rollout.dynamics import DecoupledDynamics
from pipeline.vocabulary import DAMPING_COLUMNS, DOFS, TAU_COLUMNS, VELOCITY_COLUMNS

# -- decoupled damping: the rollouts' and the decoupled study's plant ----------------------------------------------


@dataclass
class SyntheticPlant:
    """3 DOF (u, v, r) with diagonal M, damping ``d = l x + q x|x| + c x^3`` (+ a deadband of width ``dead``),
    three thrusters (two surge at +-0.25 m, one lateral at +0.4 m), ``T = k n|n|``."""

    m: tuple[float, float, float] = (80.0, 120.0, 20.0)
    lin: tuple[float, float, float] = (10.0, 20.0, 5.0)
    quad: tuple[float, float, float] = (40.0, 80.0, 10.0)
    cub: tuple[float, float, float] = (60.0, 150.0, 20.0)
    dead: tuple[float, float, float] = (0.0, 0.0, 0.0)
    k_thrust: float = 2e-5

    dofs = ("u", "v", "r")

    def mass_matrix(self) -> np.ndarray:
        return np.diag([self.m[0], self.m[1], 1.0, 1.0, 1.0, self.m[2]])

    def damping(self, dof: str, x: np.ndarray) -> np.ndarray:
        j = self.dofs.index(dof)
        y = self.lin[j] * x + self.quad[j] * x * np.abs(x) + self.cub[j] * x**3
        if self.dead[j] > 0:
            y = y + self.lin[j] * 3 * np.clip(x, -self.dead[j], self.dead[j])
        return y

    def tau(self, rpm: np.ndarray) -> np.ndarray:
        thrust = self.k_thrust * rpm * np.abs(rpm)
        return np.column_stack([thrust[:, 0] + thrust[:, 1], thrust[:, 2],
                                0.25 * (thrust[:, 1] - thrust[:, 0]) + 0.4 * thrust[:, 2]])

    def dynamics(self, nu: np.ndarray, tau: np.ndarray) -> np.ndarray:
        """The true ``nudot(nu, tau)`` over (u, v, r), a :data:`Dynamics`."""
        return self.as_dynamics()(nu, tau)

    def as_dynamics(self) -> DecoupledDynamics:
        return DecoupledDynamics(self.mass_matrix(), self.dofs,
                                 {d: functools.partial(self.damping, d) for d in self.dofs}, physics.coriolis_force)


def synthetic_trial(plant: SyntheticPlant, duration_s: float = 300.0, rate_hz: float = 20.0, seed: int = 0,
                    nu_noise: tuple[float, float, float] = (0.005, 0.005, 0.002), d_noise: float = 2.0,
                    substeps: int = 2, gap_s: tuple[float, float] | None = None) -> Any:
    """A trial table in the feature-store columns, integrated at ``rate_hz * substeps`` with thrust held per
    sample: ``t_ns segment u_mps v_mps r_radps (w p q zero) n1_rpm n2_rpm n3_rpm tau_* d_* (measured: truth +
    noise) dtrue_* yaw_rad x_m y_m``. ``gap_s = (start, stop)`` marks an invalid stretch (segment -1)."""
    rng = np.random.default_rng(seed)
    n = int(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    rpm = np.zeros((n, 3))
    for j, amp in enumerate((2200.0, 2200.0, 2000.0)):
        periods = rng.uniform(15.0, 60.0, 3)
        phases = rng.uniform(0, 2 * np.pi, 3)
        sig = sum(np.sin(2 * np.pi * t / p + ph) for p, ph in zip(periods, phases, strict=True)) / 2.0
        steps = np.repeat(rng.uniform(-0.4, 0.4, n // 200 + 1), 200)[:n]
        rpm[:, j] = amp * np.clip(sig + steps, -1, 1)
    tau = plant.tau(rpm)
    f = plant.as_dynamics()
    dt = 1.0 / rate_hz
    h = dt / substeps
    nu = np.zeros((n, 3))
    yaw = np.zeros(n)
    pos = np.zeros((n, 2))
    state = np.zeros((1, 3))
    psi, p = 0.0, np.zeros(2)
    for i in range(n):
        nu[i], yaw[i], pos[i] = state[0], psi, p
        for _ in range(substeps):
            u, v, r = state[0]
            p = p + h * np.array([u * np.cos(psi) - v * np.sin(psi), u * np.sin(psi) + v * np.cos(psi)])
            psi += h * r
            state = rk4_step(f, state, tau[i][None], h)
    meas = nu + rng.standard_normal(nu.shape) * np.asarray(nu_noise)
    cols: dict[str, Any] = {"t_ns": (t * 1e9).round().astype(np.int64), "segment": np.zeros(n, dtype=np.int32)}
    for j, d in enumerate(plant.dofs):
        cols[VELOCITY_COLUMNS[d]] = meas[:, j]
    for d in ("w", "p", "q"):
        cols[VELOCITY_COLUMNS[d]] = np.zeros(n)
    for j in range(3):
        cols[f"n{j + 1}_rpm"] = rpm[:, j]
    for d in DOFS:
        j = plant.dofs.index(d) if d in plant.dofs else None
        cols[TAU_COLUMNS[d]] = tau[:, j] if j is not None else np.zeros(n)
        true = plant.damping(d, nu[:, j]) if j is not None else np.zeros(n)
        cols[DAMPING_COLUMNS[d]] = true + (d_noise * rng.standard_normal(n) if j is not None else 0.0)
        cols["dtrue_" + DAMPING_COLUMNS[d][2:]] = true
    cols.update(yaw_rad=yaw, x_m=pos[:, 0], y_m=pos[:, 1], roll_rad=np.zeros(n), pitch_rad=np.zeros(n))
    df = pd.DataFrame(cols)
    if gap_s is not None:
        df.loc[(t >= gap_s[0]) & (t < gap_s[1]), "segment"] = -1
        df.loc[t >= gap_s[1], "segment"] = 1
    return df


# -- coupled damping: the coupled study's plant ---------------------------------------------------------------------

_M = np.array([[110.0, 0.0, 0.0], [0.0, 160.0, 8.0], [0.0, 8.0, 25.0]])
_K_THRUST = 2.0e-5  # N / rpm^2
_K_ADVANCE = 0.01  # N / (rpm m/s): thrust lost to inflow, NOT in the static tau the feature store carries
_B = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, 1.0], [-0.3, 0.3, 0.5]])


def _coriolis(nu: np.ndarray) -> np.ndarray:
    u, v, r = nu.T
    a_x = _M[0, 0] * u + _M[0, 1] * v + _M[0, 2] * r
    a_y = _M[1, 0] * u + _M[1, 1] * v + _M[1, 2] * r
    return np.column_stack([-r * a_y, r * a_x, u * a_y - v * a_x])


def _damping(nu: np.ndarray) -> np.ndarray:
    u, v, r = nu.T
    return np.column_stack([
        8 * u + 30 * u * np.abs(u) + 40 * u * r**2 + 15 * v * r,
        15 * v + 80 * v * np.abs(v) + 30 * u * r + 60 * v * u**2,
        3 * r + 10 * r * np.abs(r) + 6 * u * v + 4 * np.tanh(8 * v) * np.abs(u) + 5 * r * u**2])


def _accel(nu: np.ndarray, n_rpm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    thrust_static = _K_THRUST * n_rpm * np.abs(n_rpm)
    inflow = np.column_stack([nu[:, 0], nu[:, 0], nu[:, 1] + 0.5 * nu[:, 2]])
    thrust = thrust_static - _K_ADVANCE * np.abs(n_rpm) * inflow
    tau_eff = thrust @ _B.T
    rhs = tau_eff - _coriolis(nu) - _damping(nu)
    return np.linalg.solve(_M, rhs.T).T, thrust_static @ _B.T


def _nudot(nu: np.ndarray, n_rpm: np.ndarray) -> np.ndarray:
    return _accel(nu, n_rpm)[0]


def synthetic_frame(n_samples: int = 1500, *, rate_hz: float = 2.0, seed: int = 0, trial: str = "syn01",
                    split: str | None = None, tuning_fraction: float = 0.2, noise: float = 0.02,
                    vehicle: str = "synthetic") -> pd.DataFrame:
    """A feature-store-like table of one simulated trial (RK4, step + sine thruster commands, noisy signals).

    ``split=None``: first ``tuning_fraction`` of the rows are ``tuning``, the rest ``train_test``; otherwise every
    row gets ``split``. ``noise`` is the measurement noise SD as a fraction of each signal's SD.
    """
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    t = np.arange(n_samples) * dt
    amp = np.array([1400.0, 1400.0, 1200.0])
    n_rpm = np.zeros((n_samples, 3))
    for i in range(3):  # random steps held 2-10 s, through a first-order thruster lag (1 s), plus a sine
        level, hold, state = 0.0, 0.0, 0.0
        phase, freq = rng.uniform(0, 2 * np.pi), rng.uniform(0.02, 0.1)
        for k in range(n_samples):
            if hold <= 0:
                level, hold = rng.uniform(-1.0, 1.0), rng.uniform(2.0, 10.0)
            hold -= dt
            state += (level - state) * min(dt / 1.0, 1.0)
            n_rpm[k, i] = amp[i] * np.clip(0.8 * state + 0.2 * np.sin(2 * np.pi * freq * t[k] + phase), -1, 1)
    nu = np.zeros((n_samples, 3))
    x = np.zeros((1, 3))
    for k in range(n_samples):
        nu[k] = x[0]
        x = rk4_step(_nudot, x, n_rpm[k:k + 1], dt)
    nudot, tau = _accel(nu, n_rpm)
    thrust_static = _K_THRUST * n_rpm * np.abs(n_rpm)  # the derive stage's T_<thruster>_N
    noisy = [a + noise * a.std(axis=0) * rng.normal(size=a.shape) for a in (nu, nudot)]
    frame = pd.DataFrame({
        "vehicle": vehicle, "trial": trial,
        "t_ns": (np.round(t * 1e9)).astype(np.int64) + 1_700_000_000 * 10**9,
        "segment": np.zeros(n_samples, dtype=np.int32),
        "u_mps": noisy[0][:, 0], "v_mps": noisy[0][:, 1], "r_radps": noisy[0][:, 2],
        "n1_rpm": n_rpm[:, 0], "n2_rpm": n_rpm[:, 1], "n3_rpm": n_rpm[:, 2],
        **{f"T_th{i + 1}_N": thrust_static[:, i] for i in range(3)},
        "tau_u_N": tau[:, 0], "tau_v_N": tau[:, 1], "tau_r_Nm": tau[:, 2],
        "udot_mps2": noisy[1][:, 0], "vdot_mps2": noisy[1][:, 1], "rdot_radps2": noisy[1][:, 2],
    })
    if split is None:
        n_tune = int(round(tuning_fraction * n_samples))
        frame["split"] = np.where(np.arange(n_samples) < n_tune, "tuning", "train_test")
    else:
        frame["split"] = split
    return frame


# -- a ship with a rudder: the manoeuvring family's plant ---------------------------------------------------------

#: The simulated ship's true accelerations, Abkowitz-type terms solved for nudot (names as
#: pipeline.models.manoeuvring's: ``d`` the rudder angle in rad, ``T`` the thrust in N; SI units). Every other term
#: of that family is absent (0): a constant, u, v², r² in surge; the constants, |r|r / |v|v, v²r, vr², r δ² / v δ²
#: and δ³ where not listed. Port-starboard symmetric: surge even in (v, r, δ), sway and yaw odd.
SHIP_TRUTH: dict[str, float] = {
    "X_|u|u": -0.17, "X_vr": 0.8, "X_dd": -0.3, "X_T": 0.0083,
    "Y_v": -2.0, "Y_r": -0.3, "Y_|v|v": -2.0, "Y_d": 0.15, "Y_ddd": -0.3, "Y_Td": 0.008, "Y_vdd": 1.5,
    "N_v": -0.8, "N_r": -0.5, "N_|r|r": -1.5, "N_d": -0.12, "N_Td": -0.008, "N_rdd": 0.6,
}


def _ship_nudot(nu: np.ndarray, thrust: np.ndarray, delta: np.ndarray) -> np.ndarray:
    u, v, r = nu.T
    c = SHIP_TRUTH
    T, d = thrust, delta
    udot = c["X_|u|u"] * np.abs(u) * u + c["X_vr"] * v * r + c["X_dd"] * d * d + c["X_T"] * T
    vdot = (c["Y_v"] * v + c["Y_r"] * r + c["Y_|v|v"] * np.abs(v) * v + c["Y_d"] * d + c["Y_ddd"] * d ** 3
            + c["Y_Td"] * T * d + c["Y_vdd"] * v * d * d)
    rdot = (c["N_v"] * v + c["N_r"] * r + c["N_|r|r"] * np.abs(r) * r + c["N_d"] * d + c["N_Td"] * T * d
            + c["N_rdd"] * r * d * d)
    return np.column_stack([udot, vdot, rdot])


def _ship_step(nu: np.ndarray, inputs: np.ndarray) -> np.ndarray:
    return _ship_nudot(nu, inputs[:, 0], inputs[:, 1])


def ship_zigzag(duration_s: float = 300.0, *, rate_hz: float = 20.0, seed: int = 0,
                amplitudes_deg: tuple[float, ...] = (10.0, 20.0, 30.0), thrusts_N: tuple[float, float] = (12.0, 35.0),
                leg_s: float = 60.0, rudder_rate_degps: float = 30.0, manoeuvres: tuple[str, ...] = ("zigzag",),
                hold_s: tuple[float, float] = (0.5, 3.0), noise: float = 0.1, trial: str = "ship01",
                split: str = "train_test", vehicle: str = "ship") -> pd.DataFrame:
    """Zig-zag manoeuvres of the ship of :data:`SHIP_TRUTH` as feature-store rows (RK4 at ``rate_hz``, thrust and
    rudder held per step).

    Each leg of ``leg_s`` draws a manoeuvre from ``manoeuvres``, an amplitude a from ``amplitudes_deg`` and a
    propeller thrust in ``thrusts_N``: ``zigzag`` (rudder to +-a, switched when the heading passes +-a from the
    leg's start) or ``steps`` (rudder to a uniform angle in [-a, a], held for a uniform time in ``hold_s``: the
    transients that tell sway from yaw, which a zig-zag's near-steady turns keep proportional). The rudder moves at
    ``rudder_rate_degps``. Columns: ``t_ns segment
    u_mps v_mps r_radps T_prop_N rudder_rad tau_u_N tau_v_N tau_r_Nm udot_mps2 vdot_mps2 rdot_radps2
    yaw_rad split``; velocities and accelerations carry white noise of ``noise`` times their SD (u, v, r: a tenth
    of that), thrust and rudder are exact; ``tau_u_N`` is the thrust, ``tau_v_N`` = ``tau_r_Nm`` = 0 (the rudder
    adds nothing to tau, as the derive stage has it). ``true_*dot`` columns hold the noise-free accelerations."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / rate_hz
    n = int(round(duration_s * rate_hz))
    leg = max(1, int(round(leg_s * rate_hz)))
    x = np.array([[1.0, 0.0, 0.0]])
    psi, delta, sign = 0.0, 0.0, 1.0
    nu, thrust, rudder, yaw = np.zeros((n, 3)), np.zeros(n), np.zeros(n), np.zeros(n)
    amp = T = psi0 = target = hold = 0.0
    kind = manoeuvres[0]
    for k in range(n):
        if k % leg == 0:
            kind = manoeuvres[int(rng.integers(len(manoeuvres)))]
            amp = np.deg2rad(rng.choice(amplitudes_deg))
            T = rng.uniform(*thrusts_N)
            psi0 = psi  # each leg zig-zags about the heading it starts on
        if kind == "zigzag":
            if sign * (psi - psi0) <= -amp:  # heading passed the switch: rudder to the other side
                sign = -sign
            target = sign * amp
        else:
            hold -= dt
            if hold <= 0:
                target, hold = rng.uniform(-amp, amp), rng.uniform(*hold_s)
        step = np.deg2rad(rudder_rate_degps) * dt
        delta += np.clip(target - delta, -step, step)
        nu[k], thrust[k], rudder[k], yaw[k] = x[0], T, delta, psi
        x_next = rk4_step(_ship_step, x, np.array([[T, delta]]), dt)
        psi += 0.5 * dt * (x[0, 2] + x_next[0, 2])
        x = x_next
    nudot = _ship_nudot(nu, thrust, rudder)
    sd_nu, sd_acc = nu.std(axis=0), nudot.std(axis=0)
    nu_meas = nu + 0.1 * noise * sd_nu * rng.normal(size=nu.shape)
    acc_meas = nudot + noise * sd_acc * rng.normal(size=nudot.shape)
    return pd.DataFrame({
        "vehicle": vehicle, "trial": trial,
        "t_ns": (np.round(np.arange(n) * dt * 1e9)).astype(np.int64) + 1_700_000_000 * 10**9,
        "segment": np.zeros(n, dtype=np.int32),
        "u_mps": nu_meas[:, 0], "v_mps": nu_meas[:, 1], "r_radps": nu_meas[:, 2],
        "T_prop_N": thrust, "rudder_rad": rudder,
        "tau_u_N": thrust, "tau_v_N": np.zeros(n), "tau_r_Nm": np.zeros(n),
        "udot_mps2": acc_meas[:, 0], "vdot_mps2": acc_meas[:, 1], "rdot_radps2": acc_meas[:, 2],
        "true_udot_mps2": nudot[:, 0], "true_vdot_mps2": nudot[:, 1], "true_rdot_radps2": nudot[:, 2],
        "yaw_rad": yaw, "split": split,
    })
