"""A model's force error as a free run's band members carry it: a stationary AR(1) in time per DOF.

The decoupled study's blocked CV predicts every train_test row with a model fitted without its block; the signed
out-of-fold residuals ``target - prediction`` (N or N*m) are the force the model misses, as far as the damping
target sees it. :func:`fit_ar1` keeps two numbers of them: their RMS (``sd``, the SD of a zero-mean error) and their
lag-1 correlation at the rows' time step, as a time constant (``rho = exp(-step / T)``), so that
:meth:`ForceError.sample` draws the same process at any rollout step ``dt``: ``e_0 ~ N(0, sd^2)``, ``e_{i+1} = a e_i
+ sd sqrt(1 - a^2) w_i``, ``a = exp(-dt / T)`` (the exact discretization of an Ornstein-Uhlenbeck process, held over
each step as the thrust is). docs/models.md, "Free-run bands".
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

__all__ = ["ForceError", "fit_ar1"]

#: a lag-1 correlation at or above this is clipped (a time constant of ~1000 steps): a random walk has no SD
MAX_LAG1 = 0.999


@dataclass(frozen=True)
class ForceError:
    """A stationary AR(1) force error: RMS ``sd`` (force units), time constant ``time_constant_s`` (0: white at any
    step), and what it was fitted from (``lag1`` at ``step_s``, ``rows``, ``pairs``)."""

    sd: float
    time_constant_s: float
    lag1: float | None = None
    step_s: float | None = None
    rows: int = 0
    pairs: int = 0

    def coefficient(self, dt_s: float) -> float:
        """The AR(1) coefficient at step ``dt_s``: ``exp(-dt_s / T)``."""
        return math.exp(-dt_s / self.time_constant_s) if self.time_constant_s > 0 else 0.0

    def sample(self, n_members: int, n_steps: int, dt_s: float, rng: np.random.Generator) -> np.ndarray:
        """``(n_members, n_steps)`` draws of the process at step ``dt_s``, each member from the stationary law."""
        a = self.coefficient(dt_s)
        w = rng.standard_normal((n_members, n_steps))
        out = np.empty_like(w)
        out[:, 0] = w[:, 0]
        scale = math.sqrt(1.0 - a * a)
        for i in range(1, n_steps):
            out[:, i] = a * out[:, i - 1] + scale * w[:, i]
        return self.sd * out

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ForceError:
        return cls(**{k: data[k] for k in ("sd", "time_constant_s", "lag1", "step_s", "rows", "pairs") if k in data})


def fit_ar1(residuals: np.ndarray, t_ns: np.ndarray) -> ForceError:
    """The AR(1) of signed residuals at times ``t_ns`` (int64 ns, table order; several trials or segments allowed):
    RMS and the lag-1 correlation of consecutive rows one time step apart (the median step; a pair further apart,
    or back in time at a trial's boundary, is left out). A correlation <= 0 is white (``time_constant_s`` 0)."""
    e = np.asarray(residuals, dtype=float)
    t = np.asarray(t_ns, dtype=np.int64)
    ok = np.isfinite(e)
    e, t = e[ok], t[ok]
    sd = float(np.sqrt(np.mean(e**2))) if e.size else 0.0
    gap = np.diff(t)
    positive = gap[gap > 0]
    if positive.size == 0 or sd == 0.0:
        return ForceError(sd, 0.0, rows=int(e.size))
    step_ns = float(np.median(positive))
    pair = (gap > 0) & (gap <= 1.5 * step_ns)
    if not pair.any():
        return ForceError(sd, 0.0, step_s=step_ns * 1e-9, rows=int(e.size))
    a, b = e[:-1][pair], e[1:][pair]
    lag1 = float(np.sum(a * b) / np.sqrt(np.sum(a * a) * np.sum(b * b)))
    rho = min(lag1, MAX_LAG1)
    tc = -step_ns * 1e-9 / math.log(rho) if rho > 0 else 0.0
    return ForceError(sd, tc, lag1=lag1, step_s=step_ns * 1e-9, rows=int(e.size), pairs=int(pair.sum()))

