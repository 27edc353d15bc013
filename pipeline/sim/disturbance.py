"""A slowly varying unknown force on the vehicle, such as a tether's: what no vehicle model knows.

Per DOF an Ornstein-Uhlenbeck process with stationary SD ``sd`` and time constant ``time_constant_s``,

    df = -f / T dt + sd sqrt(2 / T) dW,

sampled exactly on the integration grid (``f_{k+1} = a f_k + sd sqrt(1 - a^2) e_k``, ``a = exp(-dt / T)``, the
first value drawn from the stationary law) and held over each RK4 step. It enters the dynamics on the thrust's
side, ``M nu_dot + C(nu) nu + d(nu) + g(eta) = tau + f`` (:mod:`pipeline.sim.vehicle`), so the damping target
``tau - M nu_dot - C(nu) nu - g(eta)`` computed from exact nu, nu_dot and tau equals ``d(nu) - f``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from pipeline.errors import ConfigError


@dataclass(frozen=True)
class Disturbance:
    """Stationary SDs of the force per DOF (u v w in N, p q r in N*m) and its time constant (s)."""

    sd: tuple[float, float, float, float, float, float] = (0.0,) * 6
    time_constant_s: float = 30.0

    def __post_init__(self) -> None:
        if len(self.sd) != 6 or any(not np.isfinite(s) or s < 0 for s in self.sd):
            raise ConfigError(f"disturbance sd needs 6 finite values >= 0 (u v w p q r), not {self.sd}", field="sd")
        if not (np.isfinite(self.time_constant_s) and self.time_constant_s > 0):
            raise ConfigError(f"disturbance time_constant_s must be > 0, not {self.time_constant_s}",
                              field="time_constant_s")

    @classmethod
    def hard(cls) -> Disturbance:
        """The hard preset's tether: 3 N in surge, 3 N in sway, 1 N*m in yaw (SDs), time constant 30 s."""
        return cls(sd=(3.0, 3.0, 0.0, 0.0, 0.0, 1.0), time_constant_s=30.0)

    def sample(self, n_steps: int, dt_s: float, rng: np.random.Generator) -> np.ndarray:
        """The force at ``n_steps`` grid points ``dt_s`` apart, (n_steps, 6)."""
        sd = np.asarray(self.sd, dtype=float)
        a = float(np.exp(-dt_s / self.time_constant_s))
        draws = rng.standard_normal((n_steps, 6))
        innovations = sd * np.sqrt(1.0 - a * a) * draws
        innovations[:1] = sd * draws[:1]
        return lfilter([1.0], [1.0, -a], innovations, axis=0)  # f_k = a f_{k-1} + innovation_k
