"""Vehicle dynamics: 6-DOF rigid body with added mass, true damping, restoring forces and lagged thrusters.

    M nu_dot + C(nu) nu + d(nu) + g(eta) = tau + f,  tau = B T(n, nu),  eta_dot = J(eta) nu,  n_dot = (n_cmd - n) / lag

(T(n, nu): the static curve T0(n), less the truth's thrust loss to inflow, :class:`pipeline.sim.truth.SimTruth`;
f: an unknown external force such as a tether's, :mod:`pipeline.sim.disturbance`, zero unless given)

integrated with fixed-step RK4 (commands held over a step). The horizontal thrusters get sums of sines
(several periods, separate per thruster, zero offset, as in the DAGON trials); the vertical thrusters hold
depth and pitch with a PD controller with restoring-force feed-forward. :meth:`Controls.hard` is the hard
preset's excitation: one sinusoid per horizontal thruster, periods 5-18 s, 1800 rpm against 3500 max.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from pipeline import physics
from pipeline.config.vehicle import Vehicle
from pipeline.rk4 import LISTS, rk4_step
from pipeline.sim.truth import SimTruth
from pipeline.vocabulary import DOFS

log = logging.getLogger(__name__)

DOF_INDEX = {d: i for i, d in enumerate(DOFS)}


@dataclass(frozen=True)
class Controls:
    """Command options: sines on the horizontal thrusters, PD on the vertical ones."""

    commands: str = "sines"             # "sines" or "none"
    # "all": independent sines per horizontal thruster; "surge" / "sway" / "yaw": one sum of sines on that
    # generalized force, allocated over the horizontal thrusters so that the other horizontal DOFs get no force
    # (single-DOF excitation, as in the decoupled identification experiments of paper 001)
    excite: str = "all"
    amplitude_rpm: float = 2600.0       # peak command of the horizontal thrusters
    max_rpm: float = 3500.0
    period_range_s: tuple[float, float] = (6.0, 45.0)
    n_sines: int = 3
    depth_control: bool = True
    depth_ref_m: float = 2.0
    kp_depth: float = 150.0             # N/m
    kd_depth: float = 250.0             # N/(m/s)
    kp_pitch: float = 60.0              # N*m/rad
    kd_pitch: float = 40.0              # N*m/(rad/s)

    @classmethod
    def hard(cls) -> Controls:
        """The hard preset: one sinusoid per horizontal thruster (not summed sines), periods drawn uniformly in
        5-18 s, 1800 rpm amplitude against 3500 max (as a basin trial that outruns its DVL)."""
        return cls(amplitude_rpm=1800.0, period_range_s=(5.0, 18.0), n_sines=1)


def euler_rotation(roll: np.ndarray, pitch: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Body-to-NED rotation matrices R(phi, theta, psi), zyx convention; (n,) -> (n, 3, 3)."""
    cf, sf, ct, st, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    r = np.empty(np.shape(roll) + (3, 3))
    r[..., 0, 0] = cp * ct
    r[..., 0, 1] = -sp * cf + cp * st * sf
    r[..., 0, 2] = sp * sf + cp * cf * st
    r[..., 1, 0] = sp * ct
    r[..., 1, 1] = cp * cf + sf * st * sp
    r[..., 1, 2] = -cp * sf + st * sp * cf
    r[..., 2, 0] = -st
    r[..., 2, 1] = ct * sf
    r[..., 2, 2] = ct * cf
    return r


class Dynamics:
    """The right-hand side, vectorized over rows: states eta (m, 6), nu (m, 6), n (m, n_thr)."""

    def __init__(self, vehicle: Vehicle, truth: SimTruth) -> None:
        self.vehicle = vehicle
        self.truth = truth
        self.M = physics.mass_matrix(vehicle)
        self.M_inv = np.linalg.inv(self.M)
        self.B = physics.allocation_matrix(vehicle)
        self.lag_s = np.array([t.lag_s for t in vehicle.thrusters])
        self._base = vehicle.resolve("")
        curves = [t.thrust for t in vehicle.thrusters]
        self._k = None
        if all(c.table is None for c in curves):
            k_fwd = np.array([c.k_fwd_N_per_rpm2 for c in curves], dtype=float)
            k_bwd = np.array([c.k_bwd_N_per_rpm2 if c.k_bwd_N_per_rpm2 is not None else c.k_fwd_N_per_rpm2
                              for c in curves], dtype=float)
            self._k = (k_fwd, k_bwd)
        rb = vehicle.rigid_body
        self.W, self.Bf = physics.weight_buoyancy_N(rb)
        self.cg, self.cb = np.asarray(rb.cg_m), np.asarray(rb.cb_m)
        self._cg, self._cb = tuple(map(float, rb.cg_m)), tuple(map(float, rb.cb_m))

    def thrust(self, n: np.ndarray, nu: np.ndarray | None = None) -> np.ndarray:
        """Per-thruster thrust in N, (m, n_thr): the static curve T0(n); with ``nu`` (m, 6) the thrust actually
        applied, less the truth's loss to axial inflow ``u_a = B^T nu`` (none when the truth has it off)."""
        if self._k is not None:
            static = np.where(n >= 0, self._k[0], self._k[1]) * n * np.abs(n)
        else:
            static = np.stack([physics.thrust_N(t, n[:, i], self._base)
                               for i, t in enumerate(self.vehicle.thrusters)], axis=1)
        if nu is None:
            return static
        return self.truth.applied_thrust(static, n, np.atleast_2d(nu) @ self.B)

    def restoring(self, roll: np.ndarray | float, pitch: np.ndarray | float) -> Any:
        """g(eta) (Fossen 4.6): (m, 6) for arrays, a list of 6 floats for one state."""
        w, b = self.W, self.Bf
        (xg, yg, zg), (xb, yb, zb) = self._cg, self._cb
        if isinstance(roll, float):  # one state (the controller): plain floats cost far less than small arrays
            sf, cf, st, ct = math.sin(roll), math.cos(roll), math.sin(pitch), math.cos(pitch)
            return [(w - b) * st, -(w - b) * ct * sf, -(w - b) * ct * cf,
                    -(yg * w - yb * b) * ct * cf + (zg * w - zb * b) * ct * sf,
                    (zg * w - zb * b) * st + (xg * w - xb * b) * ct * cf,
                    -(xg * w - xb * b) * ct * sf - (yg * w - yb * b) * st]
        sf, cf, st, ct = np.sin(roll), np.cos(roll), np.sin(pitch), np.cos(pitch)
        return np.stack([
            (w - b) * st,
            -(w - b) * ct * sf,
            -(w - b) * ct * cf,
            -(yg * w - yb * b) * ct * cf + (zg * w - zb * b) * ct * sf,
            (zg * w - zb * b) * st + (xg * w - xb * b) * ct * cf,
            -(xg * w - xb * b) * ct * sf - (yg * w - yb * b) * st,
        ], axis=-1)

    def nu_dot(self, eta: np.ndarray, nu: np.ndarray, n: np.ndarray, force: np.ndarray | None = None) -> np.ndarray:
        """M^-1 (tau - C(nu) nu - d(nu) - g(eta) + f), ``force``: the external force f (m, 6), default none."""
        tau = self.thrust(n, nu) @ self.B.T
        rhs = tau - physics.coriolis_force(self.M, nu) - self.truth.damping(nu) - self.restoring(eta[:, 3], eta[:, 4])
        if force is not None:
            rhs = rhs + force
        return rhs @ self.M_inv.T

    def eta_dot(self, eta: np.ndarray, nu: np.ndarray) -> np.ndarray:
        roll, pitch = eta[:, 3], eta[:, 4]
        R = euler_rotation(roll, pitch, eta[:, 5])
        lin = np.einsum("mij,mj->mi", R, nu[:, :3])
        p, q, r = nu[:, 3], nu[:, 4], nu[:, 5]
        sf, cf, ct, tt = np.sin(roll), np.cos(roll), np.cos(pitch), np.tan(pitch)
        ang = np.stack([p + sf * tt * q + cf * tt * r, cf * q - sf * r, (sf * q + cf * r) / ct], axis=-1)
        return np.hstack([lin, ang])

    def n_dot(self, n: np.ndarray, n_cmd: np.ndarray) -> np.ndarray:
        lag = np.where(self.lag_s > 0, self.lag_s, 1.0)
        return np.where(self.lag_s > 0, (n_cmd - n) / lag, 0.0)


class Commander:
    """Thruster speed commands: sums of sines (horizontal) and the depth/pitch PD (vertical)."""

    def __init__(self, dyn: Dynamics, controls: Controls, rng: np.random.Generator) -> None:
        self.dyn, self.c = dyn, controls
        dirs = dyn.B[:3].T  # normalized directions, (n_thr, 3)
        self.vertical = np.abs(dirs[:, 2]) > 0.9
        n_thr = dirs.shape[0]
        lo, hi = controls.period_range_s
        self.periods = rng.uniform(lo, hi, size=(n_thr, controls.n_sines))
        self.phases = rng.uniform(0.0, 2 * np.pi, size=(n_thr, controls.n_sines))
        self.weights = rng.uniform(0.5, 1.0, size=(n_thr, controls.n_sines))
        self.weights /= self.weights.sum(axis=1, keepdims=True)
        grid = np.linspace(-controls.max_rpm, controls.max_rpm, 4001)
        self._grid, self._thrust_grid = grid, dyn.thrust(np.repeat(grid[:, None], n_thr, axis=1))
        vert = np.flatnonzero(self.vertical)
        self._vert = vert
        self._alloc_pinv = np.linalg.pinv(dyn.B[np.ix_([2, 4], vert)]) if vert.size else None
        self._single = self._single_dof_allocation() if controls.excite != "all" else None

    def _single_dof_allocation(self) -> tuple[np.ndarray, np.ndarray]:
        """(horizontal thruster indices, thrust per thruster at full excitation) for ``controls.excite``."""
        dofs = {"surge": 0, "sway": 1, "yaw": 5}
        if self.c.excite not in dofs:
            raise ValueError(f"excite must be 'all' or one of {sorted(dofs)}, not {self.c.excite!r}")
        horiz = np.flatnonzero(~self.vertical)
        rows = [0, 1, 5]
        unit = np.linalg.pinv(self.dyn.B[np.ix_(rows, horiz)])[:, rows.index(dofs[self.c.excite])]
        amp = np.full((1, self.vertical.size), self.c.amplitude_rpm)
        t_max = np.minimum(self.dyn.thrust(amp)[0], -self.dyn.thrust(-amp)[0])[horiz]  # symmetric thrust limit
        used = np.abs(unit) > 1e-12 * np.abs(unit).max()
        scale = float(np.min(t_max[used] / np.abs(unit[used])))
        return horiz, unit * scale

    def _inverse(self, thrust: np.ndarray, thrusters: np.ndarray) -> np.ndarray:
        return np.array([np.interp(thrust[j], self._thrust_grid[:, i], self._grid) for j, i in enumerate(thrusters)])

    def inverse_thrust(self, thrust: np.ndarray) -> np.ndarray:
        """Propeller speed (rpm) giving ``thrust`` (N) per vertical thruster, clamped to max_rpm."""
        return self._inverse(thrust, self._vert)

    def __call__(self, t_s: float, eta: np.ndarray, nu: np.ndarray) -> np.ndarray:
        n_cmd = np.zeros(self.vertical.size)
        if self.c.commands == "sines":
            s = (self.weights * np.sin(2 * np.pi * t_s / self.periods + self.phases)).sum(axis=1)
            if self._single is None:
                n_cmd = np.where(self.vertical, 0.0, self.c.amplitude_rpm * s)
            else:  # one force signal (the first thruster's sines), allocated
                horiz, full = self._single
                n_cmd[horiz] = self._inverse(full * s[0], horiz)
        elif self.c.commands != "none":
            raise ValueError(f"commands must be 'sines' or 'none', not {self.c.commands!r}")
        if self.c.depth_control and self._alloc_pinv is not None:
            g = self.dyn.restoring(float(eta[3]), float(eta[4]))
            f_w = g[2] + self.c.kp_depth * (self.c.depth_ref_m - eta[2]) - self.c.kd_depth * nu[2]
            m_q = g[4] - self.c.kp_pitch * eta[4] - self.c.kd_pitch * nu[4]
            thrust = self._alloc_pinv @ np.array([f_w, m_q])
            n_cmd[self._vert] = self.inverse_thrust(thrust)
        return np.clip(n_cmd, -self.c.max_rpm, self.c.max_rpm)


def scalar_rhs(dyn: Dynamics, external: bool = False):
    """A pure-Python right-hand side for one state (list in, list out): for a 17-element state the vectorized
    numpy version's cost is array overhead (figures: docs/benchmarks.md). Same equations as
    :meth:`Dynamics.nu_dot` / :meth:`Dynamics.eta_dot` (the tests compare them). ``external``: the input is the
    thruster commands followed by an external force f (6 values), held over the step like the commands."""
    ms = 0.5 * (dyn.M + dyn.M.T)

    def sparse_rows(matrix: np.ndarray) -> list[list[tuple[int, float]]]:
        return [[(j, float(val)) for j, val in enumerate(row) if val != 0.0] for row in matrix]

    m_top, m_bot = sparse_rows(ms[:3]), sparse_rows(ms[3:])  # a = [M11 M12] nu, c = [M21 M22] nu
    minv = sparse_rows(dyn.M_inv)
    bmat = sparse_rows(dyn.B)
    n_thr = dyn.B.shape[1]
    lin, quad, cub = list(dyn.truth.linear), list(dyn.truth.quadratic), list(dyn.truth.cubic)
    coupled = [(DOF_INDEX[t.dof], t.coef, [(DOF_INDEX[f.strip("|")], f.startswith("|")) for f in t.factors])
               for t in dyn.truth.coupled]
    w, b = dyn.W, dyn.Bf
    (xg, yg, zg), (xb, yb, zb) = dyn.cg.tolist(), dyn.cb.tolist()
    wb, xw, yw, zw = w - b, xg * w - xb * b, yg * w - yb * b, zg * w - zb * b
    lags = dyn.lag_s.tolist()
    k = None if dyn._k is None else (dyn._k[0].tolist(), dyn._k[1].tolist())
    r3 = range(3)
    c_inflow = dyn.truth.inflow_rpm_per_mps
    bcols = [[(j, float(dyn.B[j, i])) for j in range(6) if dyn.B[j, i] != 0.0] for i in range(n_thr)]

    def rhs(y: list[float], cmd: list[float]) -> list[float]:
        x, yy, z, phi, th, psi, u, v, ww, p, q, r = y[:12]
        n = y[12:]
        nu = (u, v, ww, p, q, r)
        if k is not None:
            kk = [k[0][i] if n[i] >= 0 else k[1][i] for i in range(n_thr)]
            thrust = [kk[i] * n[i] * abs(n[i]) for i in range(n_thr)]
            if c_inflow:  # T0(n) - K c |n| u_a, u_a = B[:, i] . nu
                for i in range(n_thr):
                    u_a = 0.0
                    for j, val in bcols[i]:
                        u_a += val * nu[j]
                    thrust[i] -= kk[i] * c_inflow * abs(n[i]) * u_a
        else:
            thrust = dyn.thrust(np.array([n]), np.array([nu]))[0].tolist()
        v1, v2 = nu[:3], nu[3:]
        a = [0.0, 0.0, 0.0]
        c = [0.0, 0.0, 0.0]
        for i in r3:
            for j, val in m_top[i]:
                a[i] += val * nu[j]
            for j, val in m_bot[i]:
                c[i] += val * nu[j]
        cor = [
            v2[1] * a[2] - v2[2] * a[1], v2[2] * a[0] - v2[0] * a[2], v2[0] * a[1] - v2[1] * a[0],
            v1[1] * a[2] - v1[2] * a[1] + v2[1] * c[2] - v2[2] * c[1],
            v1[2] * a[0] - v1[0] * a[2] + v2[2] * c[0] - v2[0] * c[2],
            v1[0] * a[1] - v1[1] * a[0] + v2[0] * c[1] - v2[1] * c[0],
        ]
        damp = [lin[i] * nu[i] + quad[i] * nu[i] * abs(nu[i]) + cub[i] * nu[i] ** 3 for i in range(6)]
        for out, coef, factors in coupled:
            prod = coef
            for idx, use_abs in factors:
                prod *= abs(nu[idx]) if use_abs else nu[idx]
            damp[out] += prod
        sf, cf, st, ct = math.sin(phi), math.cos(phi), math.sin(th), math.cos(th)
        sp, cp = math.sin(psi), math.cos(psi)
        g = [wb * st, -wb * ct * sf, -wb * ct * cf, -yw * ct * cf + zw * ct * sf, zw * st + xw * ct * cf,
             -xw * ct * sf - yw * st]
        rhs6 = [-cor[i] - damp[i] - g[i] for i in range(6)]
        if external:
            for i in range(6):
                rhs6[i] += cmd[n_thr + i]
        for i in range(6):
            for j, val in bmat[i]:
                rhs6[i] += val * thrust[j]
        nudot = [0.0] * 6
        for i in range(6):
            for j, val in minv[i]:
                nudot[i] += val * rhs6[j]
        tt = st / ct
        deta = [
            cp * ct * u + (-sp * cf + cp * st * sf) * v + (sp * sf + cp * cf * st) * ww,
            sp * ct * u + (cp * cf + sf * st * sp) * v + (-cp * sf + st * sp * cf) * ww,
            -st * u + ct * sf * v + ct * cf * ww,
            p + sf * tt * q + cf * tt * r,
            cf * q - sf * r,
            (sf * q + cf * r) / ct,
        ]
        ndot = [(cmd[i] - n[i]) / lags[i] if lags[i] > 0 else 0.0 for i in range(n_thr)]
        return deta + nudot + ndot

    return rhs


def integrate(dyn: Dynamics, commander: Commander | None, duration_s: float, rate_hz: float,
              eta0: np.ndarray, nu0: np.ndarray, n0: np.ndarray, force: np.ndarray | None = None
              ) -> dict[str, np.ndarray]:
    """Fixed-step RK4 (:mod:`pipeline.rk4` on lists); returns states at every step: t_s (N,), eta (N, 6), nu (N, 6),
    n (N, n_thr), n_cmd. ``force``: an external force (N, 6) per step, held over the step (N = steps + 1)."""
    dt = 1.0 / rate_hz
    steps = int(round(duration_s * rate_hz))
    n_thr = n0.size
    out = np.empty((steps + 1, 12 + n_thr))
    cmd_all = np.zeros((steps + 1, n_thr))
    y = np.concatenate([eta0, nu0, n0]).astype(float).tolist()
    if force is not None and force.shape != (steps + 1, 6):
        raise ValueError(f"force must have shape {(steps + 1, 6)}, not {force.shape}")
    f = scalar_rhs(dyn, external=force is not None)
    ext = force.tolist() if force is not None else None
    instant = [i for i, lag in enumerate(dyn.lag_s.tolist()) if lag <= 0]
    zeros = [0.0] * n_thr
    for step in range(steps + 1):
        if commander is not None:
            arr = np.array(y)
            cmd = commander(step * dt, arr[:6], arr[6:12]).tolist()
        else:
            cmd = zeros
        for i in instant:
            y[12 + i] = cmd[i]
        out[step] = y
        cmd_all[step] = cmd
        if step == steps:
            break
        y = rk4_step(f, y, cmd if ext is None else cmd + ext[step], dt, LISTS)
        if not all(math.isfinite(val) for val in y):
            raise FloatingPointError(f"simulation diverged at t = {step * dt:.3f} s")
    return {"t_s": np.arange(steps + 1) * dt, "eta": out[:, :6], "nu": out[:, 6:12], "n": out[:, 12:],
            "n_cmd": cmd_all}
