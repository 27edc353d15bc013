"""The simulator's true hydrodynamic damping: what no user knows, what every test can check against.

``d(nu) = D_l nu + D_q nu|nu| + D_c nu^3 + sum_k c_k prod(factors_k)`` per DOF, with coupled terms such as
``|v| r`` or ``u v`` (``dagon_truth.yaml``). Sign convention as in :mod:`pipeline.physics`: d is on the left
of ``M nu_dot + C(nu) nu + d(nu) + g(eta) = tau``, so it opposes motion.

Thrust lost to inflow (advance speed), optional: a propeller's thrust coefficient falls with the advance ratio,
``K_T(J) ~ K_T0 (1 - J / J0)``, ``J = u_a / (n D)``, so with the static curve ``T0(n) = K n|n|``

    T = T0(n) (1 - c u_a / n) = K n|n| - K c |n| u_a,    u_a = d . (v + omega x r) = (B^T nu)_i

(``u_a``: the water's inflow speed along the thruster axis d at its position r, positive when the vehicle moves
the way the thruster pushes; ``c = inflow_loss * inflow_ref_rpm`` in rpm per m/s). ``inflow_loss`` is the fraction
of static thrust lost per m/s of axial inflow at ``inflow_ref_rpm``; 0 (the default) switches the effect off.
A user's vehicle config only knows ``T0(n)``, so with the effect on the derive stage's tau is the *static* thrust
and its d(nu) absorbs the loss; the simulator's truth table keeps ``T_*``/``tau_*`` as the forces actually applied
and ``d_*`` as the true hydrodynamic damping (``tau_static - tau`` is the unmodelled thrust loss).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from pipeline.errors import ConfigError
from pipeline.vocabulary import DOFS

#: DAGON's thrust loss to inflow (fraction per m/s at 2500 rpm: 15 % at 0.5 m/s; J0 ~ 0.8 for a 0.1 m propeller).
#: Off in the packaged ``dagon_truth.yaml``; ``dataclasses.replace(load_truth(), inflow_loss=DAGON_INFLOW_LOSS)``.
DAGON_INFLOW_LOSS = 0.3


@dataclass(frozen=True)
class CoupledTerm:
    """``coef * prod(factors)`` added to ``dof``; a factor is a DOF name or ``|dof|``."""

    dof: str
    coef: float
    factors: tuple[str, ...]


@dataclass(frozen=True)
class SimTruth:
    """True damping coefficients (6 per kind, DOF order u v w p q r) and coupled terms."""

    linear: tuple[float, ...] = (0.0,) * 6
    quadratic: tuple[float, ...] = (0.0,) * 6
    cubic: tuple[float, ...] = (0.0,) * 6
    coupled: tuple[CoupledTerm, ...] = field(default_factory=tuple)
    inflow_loss: float = 0.0           # fraction of static thrust lost per m/s axial inflow at inflow_ref_rpm
    inflow_ref_rpm: float = 2500.0

    def __post_init__(self) -> None:
        if not (0.0 <= self.inflow_loss < 2.0) or not self.inflow_ref_rpm > 0:
            raise ConfigError("inflow_loss must be in [0, 2) per m/s and inflow_ref_rpm > 0", field="inflow_loss")
        for name in ("linear", "quadratic", "cubic"):
            if len(getattr(self, name)) != 6:
                raise ConfigError(f"{name} needs 6 values (u v w p q r)", field=name)
        for i, term in enumerate(self.coupled):
            if term.dof not in DOFS:
                raise ConfigError(f"unknown DOF {term.dof!r}; known {DOFS}", field=f"coupled.{i}.dof")
            for f in term.factors:
                if f.strip("|") not in DOFS:
                    raise ConfigError(f"unknown factor {f!r}", field=f"coupled.{i}.factors")

    @classmethod
    def from_dict(cls, data: dict) -> SimTruth:
        unknown = set(data) - {"linear", "quadratic", "cubic", "coupled", "inflow_loss", "inflow_ref_rpm"}
        if unknown:
            raise ConfigError(f"unknown keys {sorted(unknown)}", field=sorted(unknown)[0])
        terms = tuple(CoupledTerm(str(t["dof"]), float(t["coef"]), tuple(str(f) for f in t["factors"]))
                      for t in data.get("coupled", []) or [])
        return cls(
            linear=tuple(float(x) for x in data.get("linear", (0.0,) * 6)),
            quadratic=tuple(float(x) for x in data.get("quadratic", (0.0,) * 6)),
            cubic=tuple(float(x) for x in data.get("cubic", (0.0,) * 6)),
            coupled=terms,
            inflow_loss=float(data.get("inflow_loss", 0.0)),
            inflow_ref_rpm=float(data.get("inflow_ref_rpm", 2500.0)),
        )

    @property
    def inflow_rpm_per_mps(self) -> float:
        """``c`` of the inflow loss ``T = T0(n) (1 - c u_a / n)`` (0: no loss)."""
        return self.inflow_loss * self.inflow_ref_rpm

    def applied_thrust(self, static: np.ndarray, n: np.ndarray, inflow: np.ndarray) -> np.ndarray:
        """Thrust after the inflow loss, from the static thrust ``T0(n)``, speeds ``n`` (rpm) and axial inflow
        ``u_a`` (m/s), all (m, n_thr). Returns ``static`` itself when the effect is off."""
        c = self.inflow_rpm_per_mps
        if c == 0.0:
            return static
        with np.errstate(divide="ignore", invalid="ignore"):
            per_rpm = np.where(n != 0, static / np.where(n != 0, n, 1.0), 0.0)  # K |n|: -> 0 as n -> 0
        return static - c * inflow * per_rpm

    def damping(self, nu: np.ndarray) -> np.ndarray:
        """True damping force d(nu), (n, 6) from nu (n, 6) (or (6,) -> (1, 6))."""
        nu = np.atleast_2d(np.asarray(nu, dtype=float))
        out = nu * np.asarray(self.linear) + nu * np.abs(nu) * np.asarray(self.quadratic)
        out = out + nu**3 * np.asarray(self.cubic)
        for term in self.coupled:
            prod = np.full(nu.shape[0], term.coef)
            for f in term.factors:
                col = nu[:, DOFS.index(f.strip("|"))]
                prod = prod * (np.abs(col) if f.startswith("|") else col)
            out[:, DOFS.index(term.dof)] += prod
        return out


def load_truth(path: str | Path | None = None) -> SimTruth:
    """Load a truth YAML; ``None``: the packaged DAGON truth (``pipeline/sim/dagon_truth.yaml``)."""
    if path is None:
        text = resources.files("pipeline.sim").joinpath("dagon_truth.yaml").read_text(encoding="utf-8")
        source: str | Path = "dagon_truth.yaml"
    else:
        source = Path(path)
        text = source.read_text(encoding="utf-8")
    try:
        return SimTruth.from_dict(yaml.safe_load(text) or {})
    except ConfigError as err:
        raise ConfigError(err.reason, file=source, field=err.field) from None
    except (KeyError, TypeError, ValueError) as err:
        raise ConfigError(f"invalid truth file: {err}", file=source) from None


def true_damping(nu: np.ndarray, truth: SimTruth | None = None) -> np.ndarray:
    """The simulator's true damping d(nu), (n, 6); default: the packaged DAGON truth."""
    return (truth or load_truth()).damping(nu)
