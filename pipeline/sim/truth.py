"""The simulator's true hydrodynamic damping: what no user knows, what every test can check against.

``d(nu) = D_l nu + D_q nu|nu| + D_c nu^3 + sum_k c_k prod(factors_k)`` per DOF, with coupled terms such as
``|v| r`` or ``u v`` (``dagon_truth.yaml``). Sign convention as in :mod:`pipeline.physics`: d is on the left
of ``M nu_dot + C(nu) nu + d(nu) + g(eta) = tau``, so it opposes motion.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from pipeline.errors import ConfigError
from pipeline.physics import DOFS


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

    def __post_init__(self) -> None:
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
        unknown = set(data) - {"linear", "quadratic", "cubic", "coupled"}
        if unknown:
            raise ConfigError(f"unknown keys {sorted(unknown)}", field=sorted(unknown)[0])
        terms = tuple(CoupledTerm(str(t["dof"]), float(t["coef"]), tuple(str(f) for f in t["factors"]))
                      for t in data.get("coupled", []) or [])
        return cls(
            linear=tuple(float(x) for x in data.get("linear", (0.0,) * 6)),
            quadratic=tuple(float(x) for x in data.get("quadratic", (0.0,) * 6)),
            cubic=tuple(float(x) for x in data.get("cubic", (0.0,) * 6)),
            coupled=terms,
        )

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
