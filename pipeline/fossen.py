"""The physics model as simulator parameters: a plain YAML in Fossen's notation and UUV Simulator's Fossen model.

Fossen (2011, eq. 7.7-7.9): ``(M_RB + M_A) nudot + C_RB(nu) nu + C_A(nu) nu + D_l nu + D_q(nu) nu + g(eta) = tau``
with ``D_q(nu) = diag(d_q,i |nu_i|)``. A decoupled ``ls`` model (:class:`~pipeline.models.decoupled.
LinearQuadraticDamping`, ``d_i = d_l,i nu_i + d_q,i nu_i |nu_i|`` per DOF) is exactly that with diagonal ``D_l`` and
``D_q``; ``M_RB`` and ``M_A`` come from the vehicle config (not identified), C from M as the project's simulator
and rollouts compute it (:func:`pipeline.physics.coriolis_force`). DOFs the model was not fitted for have zero
damping, listed under ``not_identified``: fill them in before simulating those DOFs.

Each identified coefficient is written with its 95 % confidence interval (OLS, widened by the residuals'
autocorrelation time; ``null`` for a model pickled before the fit kept its covariance), the trials it was
fitted on and the model file with its sha256.

UUV Simulator (``uuv_gazebo_plugins``, hydrodynamic model ``<type>fossen</type>``) takes ``<added_mass>`` (36
values, row-major) and ``<linear_damping>`` / ``<quadratic_damping>`` (6 diagonal values) as hydrodynamic
derivatives (X_u, X_u|u| ...), i.e. with the opposite sign of the damping coefficients here; the rigid body
comes from the link's URDF inertial, so :func:`load_uuv` takes ``M_RB`` from the caller. The coefficients'
intervals and trials are XML comments. Both files are written atomically; the same model gives the same bytes.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline import __version__, physics
from pipeline.api import Model
from pipeline.config import config_hash
from pipeline.config.rigid_body import rigid_body_mass
from pipeline.errors import ModelError
from pipeline.rollout import DecoupledDynamics, rollout
from pipeline.tableio import atomic_path
from pipeline.vocabulary import DOFS

__all__ = ["FORMAT", "FossenModel", "fossen_document", "load_fossen", "load_uuv", "uuv_snippet", "write_fossen",
           "write_uuv"]

FORMAT = "auvid-fossen/1"
NOTATION = ("Fossen (2011): (M_RB + M_A) nudot + C_RB(nu) nu + C_A(nu) nu + D_l nu + D_q(nu) nu + g(eta) = tau, "
            "D_q(nu) = diag(d_q,i |nu_i|); body frame, DOFs u v w p q r, SI units (N, N m, m/s, rad/s)")


class FossenError(ModelError):
    """A model that has no Fossen form, or a parameter file that cannot be read back."""


@dataclass
class FossenModel:
    """The matrices of a Fossen model (6x6 each) and the DOFs to simulate; ``dynamics`` / ``simulate`` as
    :class:`pipeline.api.Model`'s (``tau``: the generalized forces of ``dofs`` minus restoring forces)."""

    M_RB: np.ndarray
    M_A: np.ndarray
    D_l: np.ndarray
    D_q: np.ndarray
    dofs: list[str]

    def dynamics(self) -> DecoupledDynamics:
        idx = [DOFS.index(d) for d in self.dofs]
        if np.any(self.D_l[np.ix_(idx, idx)] - np.diag(np.diag(self.D_l[np.ix_(idx, idx)]))) or \
                np.any(self.D_q - np.diag(np.diag(self.D_q))):
            raise FossenError("off-diagonal damping terms are not supported by this simulator (diagonal D_l, D_q)")
        damping = {d: _damping(float(self.D_l[i, i]), float(self.D_q[i, i])) for d, i in zip(self.dofs, idx,
                                                                                               strict=True)}
        return DecoupledDynamics(self.M_RB + self.M_A, self.dofs, damping, physics.coriolis_force)

    def simulate(self, nu0: Any, tau: Any, t_s: Any) -> np.ndarray:
        t_s = np.asarray(t_s, dtype=float)
        inputs = np.asarray(tau(t_s) if callable(tau) else tau, dtype=float).reshape(t_s.size, len(self.dofs))
        out, _ = rollout(self.dynamics(), np.asarray(nu0, dtype=float).reshape(1, -1), inputs[None],
                         float(t_s[1] - t_s[0]))
        return out[0]


def _damping(d_l: float, d_q: float) -> Any:
    def d(x: np.ndarray) -> np.ndarray:
        return d_l * x + d_q * x * np.abs(x)
    return d


def _matrix(m: np.ndarray) -> list[list[float]]:
    return [[float(v) for v in row] for row in np.asarray(m, dtype=float)]


def fossen_document(model: Model) -> dict[str, Any]:
    """The YAML document of a decoupled linear-quadratic model (``ls``): matrices, per-coefficient intervals and
    trials, provenance. FossenError for any other model."""
    estimators = model.estimators
    if model.kind != "decoupled" or not all(callable(getattr(e, "coefficient_intervals", None))
                                            for e in estimators.values()):
        raise FossenError(f"model {model.name!r} is not a linear-quadratic damping model (decoupled 'ls'); only such "
                          "a model has Fossen's D_l and D_q")
    assert model.vehicle is not None
    vehicle = model.vehicle
    D_l, D_q = np.zeros((6, 6)), np.zeros((6, 6))
    coefficients: dict[str, Any] = {}
    for dof in model.dofs:
        est, card, i = estimators[dof], model.cards[dof], DOFS.index(dof)
        coef = np.ravel(est.coef_)
        ci = est.coefficient_intervals(0.95)
        D_l[i, i], D_q[i, i] = float(coef[0]), float(coef[1])
        trials = sorted((card.get("lineage") or {}).get("trials") or [])
        source = {"file": f"{model.files[dof].parent.name}/{model.files[dof].name}",
                  "sha256": card.get("model_sha256")}
        for k, key in enumerate((f"D_l[{dof},{dof}]", f"D_q[{dof},{dof}]")):
            coefficients[key] = {"value": float(coef[k]),
                                 "ci95": None if ci is None else [float(ci[k, 0]), float(ci[k, 1])],
                                 "trials": trials, "model": source}
    return {"format": FORMAT, "notation": NOTATION, "vehicle": vehicle.name, "model": model.name,
            "version": model.version, "dofs": list(DOFS), "identified_dofs": list(model.dofs),
            "not_identified": [d for d in DOFS if d not in model.dofs],
            "M_RB": _matrix(rigid_body_mass(vehicle.rigid_body)), "M_A": _matrix(physics.added_mass_matrix(vehicle)),
            "M_A_source": "vehicle config (not identified)", "D_l": _matrix(D_l), "D_q": _matrix(D_q),
            "coefficients": coefficients,
            "provenance": {"package_version": __version__, "vehicle_hash": config_hash(vehicle),
                           "trials": model.trials}}


def write_fossen(model: Model, target: str | Path) -> Path:
    """Write :func:`fossen_document` as YAML (atomically)."""
    text = "# auvid: identified hydrodynamic model in Fossen's notation (see notation)\n" + yaml.safe_dump(
        fossen_document(model), sort_keys=False, width=120, default_flow_style=None)
    with atomic_path(target) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(target)


def _square(doc: dict[str, Any], key: str, path: Path) -> np.ndarray:
    try:
        m = np.asarray(doc[key], dtype=float)
    except (KeyError, TypeError, ValueError):
        raise FossenError(f"{key!r} missing or not a matrix of numbers", file=path) from None
    if m.shape != (6, 6) or not np.all(np.isfinite(m)):
        raise FossenError(f"{key!r} must be a finite 6x6 matrix, found shape {m.shape}", file=path)
    return m


def load_fossen(path: str | Path) -> FossenModel:
    """A Fossen YAML written by :func:`write_fossen` (or by hand in the same form), checked."""
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as err:
        raise FossenError(f"not valid YAML ({err})", file=path) from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise FossenError(f"not an {FORMAT} document", file=path)
    dofs = doc.get("identified_dofs")
    if not isinstance(dofs, list) or not dofs or not set(dofs) <= set(DOFS):
        raise FossenError(f"identified_dofs must list DOFs of {list(DOFS)}", file=path)
    return FossenModel(*(_square(doc, k, path) for k in ("M_RB", "M_A", "D_l", "D_q")), [d for d in DOFS if d in dofs])


# ------------------------------------------------------------------------------------------- UUV Simulator

def _values(xs: Any) -> str:
    return " ".join(repr(float(x) + 0.0) for x in np.ravel(xs))  # + 0.0: no "-0.0"


def uuv_snippet(model: Model) -> str:
    """UUV Simulator's ``<hydrodynamic_model>`` (type fossen) for the vehicle's base link, with comments giving
    each identified coefficient's interval and trials. Hydrodynamic derivatives: damping with its sign flipped."""
    doc = fossen_document(model)
    D_l, D_q = np.asarray(doc["D_l"]), np.asarray(doc["D_q"])
    lines = [f"<!-- auvid {__version__}: model {doc['model']} of vehicle {doc['vehicle']}"
             f"{' (version ' + doc['version'] + ')' if doc['version'] else ''}; trials: "
             f"{', '.join(doc['provenance']['trials'])} -->",
             "<!-- damping as hydrodynamic derivatives: linear_damping = -D_l, quadratic_damping = -D_q (diagonal); "
             f"not identified (0, fill in): {', '.join(doc['not_identified']) or 'none'} -->"]
    for key, c in doc["coefficients"].items():
        ci = "n/a" if c["ci95"] is None else f"[{-c['ci95'][1]!r}, {-c['ci95'][0]!r}]"
        lines.append(f"<!-- {key}: derivative {-c['value']!r}, 95 % CI {ci}, trials {', '.join(c['trials'])} -->")
    lines += ["<hydrodynamic_model>", "  <type>fossen</type>",
              f"  <added_mass>{_values(doc['M_A'])}</added_mass>",
              f"  <linear_damping>{_values(-np.diag(D_l))}</linear_damping>",
              f"  <quadratic_damping>{_values(-np.diag(D_q))}</quadratic_damping>",
              "</hydrodynamic_model>"]
    return "\n".join(lines) + "\n"


def write_uuv(model: Model, target: str | Path) -> Path:
    with atomic_path(target) as tmp:
        tmp.write_text(uuv_snippet(model), encoding="utf-8")
    return Path(target)


def load_uuv(path: str | Path, M_RB: np.ndarray, dofs: list[str]) -> FossenModel:
    """A UUV Simulator ``<hydrodynamic_model>`` of type fossen (diagonal or full 36-value damping) as a
    :class:`FossenModel`; ``M_RB`` (the link's inertia, not in the plugin's parameters) from the caller."""
    path = Path(path)
    text = path.read_text(encoding="utf-8")
    match = re.search(r"<hydrodynamic_model>.*?</hydrodynamic_model>", text, re.S)
    if match is None:
        raise FossenError("no <hydrodynamic_model> element", file=path)
    try:
        node = ET.fromstring(match.group(0))
    except ET.ParseError as err:
        raise FossenError(f"<hydrodynamic_model> is not well-formed XML ({err})", file=path) from None
    if (node.findtext("type") or "").strip() != "fossen":
        raise FossenError("hydrodynamic model type is not 'fossen'", file=path)

    def matrix(tag: str, diagonal_ok: bool) -> np.ndarray:
        try:
            values = np.array((node.findtext(tag) or "").split(), dtype=float)
        except ValueError:
            raise FossenError(f"<{tag}> holds a value that is not a number", file=path) from None
        if values.size == 36:
            return values.reshape(6, 6)
        if values.size == 6 and diagonal_ok:
            return np.diag(values)
        raise FossenError(f"<{tag}> must hold 36{' or 6' if diagonal_ok else ''} values, found {values.size}",
                          file=path)

    return FossenModel(np.asarray(M_RB, dtype=float), matrix("added_mass", False), -matrix("linear_damping", True),
                       -matrix("quadratic_damping", True), list(dofs))
