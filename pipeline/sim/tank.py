"""A 1:25 ship model's zig-zags in a towing tank, written as the carriage's raw text tables (docs/user-guide.md §9).

A hand-built 3-DOF model (``M``: diagonal mass with added mass; rudder and skeg lift at the stern; quadratic and
linear damping; propeller thrust ``K n|n|``) is integrated by RK4 at 100 Hz and sampled at 20 Hz into a whitespace
table with a cp1252 preamble, no header and time rounded to 3 significant digits; the velocities are given in earth
axes (rotated by the heading), heading and yaw rate in degrees. ``ring_mps`` adds a narrow-band disturbance to the
*measured* surge (a carriage or shaft vibration: the vehicle does not move with it), rotated into the earth-frame
rates like the surge itself.
"""

from __future__ import annotations

import numpy as np

from pipeline.rk4 import rk4_step

__all__ = ["M", "nudot", "simulate_zigzag", "steady_u"]

#: The ship's mass matrix (rigid body plus added mass, diagonal), as the guide's ship.yaml gives it
M = np.diag([110.0, 180.0, 180.0, 11.0, 45.0, 60.0])
#: The propeller's thrust coefficient (N per rpm^2): the guide's k_fwd_N_per_rpm2
K_THRUST = 1e-4


def nudot(nu: np.ndarray, n_rpm: np.ndarray | float, delta: np.ndarray | float) -> np.ndarray:
    """M^-1 (tau - C(nu) nu - D(nu) nu) of the 3-DOF ship for the diagonal M (30x faster than the general form;
    tests/cli/test_ship_e2e.py checks that both agree): [u̇ v̇ 0 0 0 ṙ] per row of ``nu`` (6 columns, or one row)."""
    u, v, r = nu[..., 0], nu[..., 1], nu[..., 5]
    m11, m22, m66 = M[0, 0], M[1, 1], M[5, 5]
    # rudder lift and the skeg's lift against the drift, both at the stern (1 m aft): without the skeg the hull's
    # Munk moment makes the ship course-unstable (eigenvalue +0.39/s at 0.8 m/s) and no 20 deg rudder checks a turn
    stern_Y = 40.0 * delta * u * np.abs(u) - 80.0 * u * v
    surge = K_THRUST * n_rpm * np.abs(n_rpm) + m22 * v * r - (20 * u + 30 * u * np.abs(u))
    sway = stern_Y - m11 * u * r - (60 * v + 80 * v * np.abs(v))
    yaw = -1.0 * stern_Y - (m22 - m11) * u * v - (15 * r + 20 * r * np.abs(r))
    zero = np.zeros_like(surge)
    return np.stack([surge / m11, sway / m22, zero, zero, zero, yaw / m66], axis=-1)


def _rhs(nu: np.ndarray, inputs: tuple[float, float]) -> np.ndarray:
    return nudot(nu, *inputs)


def steady_u(n_rpm: float) -> float:
    """Surge speed where the propeller's thrust meets the surge damping, straight ahead."""
    return float(np.roots([30.0, 20.0, -K_THRUST * n_rpm**2]).max())


def _narrow_band(rng: np.random.Generator, t_s: np.ndarray, f_hz: float, amp_mps: float) -> np.ndarray:
    """A sine at ``f_hz`` whose amplitude (±30 %) and phase (SD 0.5 rad) wander with a correlation time of 10 s:
    a line about 0.03 Hz wide, as a vibration's, not a pure tone a notch of any width would remove exactly."""
    h = float(t_s[1] - t_s[0])
    a = np.exp(-h / 10.0)
    drive = rng.normal(0.0, np.sqrt(1 - a * a), (t_s.size, 2))
    wander = np.zeros((t_s.size, 2))
    for k in range(1, t_s.size):  # two unit-variance Ornstein-Uhlenbeck processes
        wander[k] = a * wander[k - 1] + drive[k]
    return amp_mps * (1 + 0.3 * np.tanh(wander[:, 0])) * np.sin(2 * np.pi * f_hz * t_s + 0.5 * wander[:, 1])


def simulate_zigzag(seed: int, duration_s: float = 150.0, rudder_rate_degps: float = 15.0, ring_mps: float = 0.0,
                    ring_hz: float = 2.0) -> tuple[str, np.ndarray]:
    """(the table's text, true [udot vdot rdot] at each 20 Hz row): a 20/20 zig-zag, started straight at the
    propeller's steady speed, the rudder moved at ``rudder_rate_degps``; the propeller speed varies as a sine of a
    period and phase drawn from ``seed``, so every seed covers the same envelope (about 16 rudder switches in
    150 s). ``ring_mps``: the amplitude of a narrow-band disturbance at ``ring_hz`` on the measured surge (drawn
    from its own stream of ``seed``: the motion and the noise stay those of ``ring_mps=0``)."""
    rng = np.random.default_rng(seed)
    h, sub = 0.01, 5
    period_s, phase = rng.uniform(40.0, 60.0), rng.uniform(0.0, 2 * np.pi)
    n0 = 600 + 200 * np.sin(phase)
    nu, psi, pos = np.array([steady_u(n0), 0, 0, 0, 0, 0.0]), 0.0, np.zeros(2)
    delta, command, step = 0.0, np.deg2rad(20.0), np.deg2rad(rudder_rate_degps) * h
    steps = int(duration_s / h)
    ring = (_narrow_band(np.random.default_rng([seed, 1]), np.arange(0, steps, sub) * h, ring_hz, ring_mps)
            if ring_mps > 0 else np.zeros(len(range(0, steps, sub))))
    rows, truth = [], []
    for k in range(steps):
        t = k * h
        n_rpm = 600 + 200 * np.sin(2 * np.pi * t / period_s + phase)
        if psi < -np.deg2rad(20):  # a positive rudder turns the bow to port (psi falls): counter-rudder
            command = -np.deg2rad(20.0)
        elif psi > np.deg2rad(20):
            command = np.deg2rad(20.0)
        delta += np.clip(command - delta, -step, step)
        if k % sub == 0:
            u, v, r = nu[0] + ring[k // sub], nu[1], nu[5]  # the vibration is in the measurement only
            xdot, ydot = u * np.cos(psi) - v * np.sin(psi), u * np.sin(psi) + v * np.cos(psi)
            noise = rng.normal(0, [0.005, 0.005, 0.02, 0.05])
            rows.append([t, pos[0], pos[1], xdot + noise[0], ydot + noise[1], np.rad2deg(psi) + noise[2],
                         np.rad2deg(r) + noise[3], np.rad2deg(delta), n_rpm / 60])
            acc = nudot(nu, n_rpm, delta)
            truth.append([acc[0], acc[1], acc[5]])
        nu_next = rk4_step(_rhs, nu, (n_rpm, delta), h)  # heading and position from the step's start
        psi += h * nu[5]
        pos += h * np.array([nu[0] * np.cos(psi) - nu[1] * np.sin(psi), nu[0] * np.sin(psi) + nu[1] * np.cos(psi)])
        nu = nu_next
    preamble = "Towing tank run, zig-zag 20°/20°\nship model 1:25\nrudder in °, heading in °\nunits: s m m/s °\n"
    body = "\n".join("  ".join([f"{row[0]:.3g}"] + [f"{x:.6f}" for x in row[1:]]) for row in rows)
    return preamble + body + "\n", np.array(truth)
