"""The public model API (``import auvid``): the fitted models of a run directory or a registry version, each with
``predict(nu, tau)`` -> nudot and a free-run ``simulate(nu0, tau, t_s)``.

::

    import auvid
    models = auvid.load("runs/basin")
    nudot = models["ls"].predict(nu, tau)

``load`` takes a run directory (``data/models/``), a retraining home (``registry.json``: its current version, another
``version=``, or the per-output models an ``alias=`` such as ``champion`` names) or a version directory
``HOME/models/<version>``. Models load only through their cards (sha256 checked, :mod:`pipeline.models.card`),
and only those the run's params name.

Two kinds of model, one contract (``nu``: ``(n, k)`` velocities of ``model.dofs``, SI units):

- ``decoupled`` (``ls``, ``gp``, ...: one damping model per DOF): ``nudot = M^-1 (tau - C(nu) nu - d(nu))`` with M
  and C from the vehicle config (:mod:`pipeline.physics`); ``tau`` is the generalized force of those DOFs minus the
  restoring forces (``model.inputs``: ``tau_u_N`` ... in the feature store's names);
- ``coupled`` (``coupled_<name>``: one estimator for all outputs): ``nudot = F(nu, inputs)``, ``tau`` being the
  model's other inputs in its card's order (``model.inputs``: thruster speeds or ``tau_*``).

``predict(nu, tau, interval=True)`` returns ``(nudot, lower, upper)``: for a coupled model, its 90 % prediction
interval from the train stage (its card's ``interval``: split conformal, the half-width growing with the
prediction, :func:`pipeline.evaluate.interval_half_width`); for a decoupled set whose damping models all give a
latent SD (the GP), a band of +- 2 sd (the SD mapped through ``M^-1``, DOFs taken as independent); else
``lower = upper = None``. ``model.interval_kind`` says which. ``simulate`` integrates the model's own dynamics with
RK4 at the step of ``t_s`` (uniform), inputs held over each step, as the simulate stage does
(:func:`pipeline.rollout.rollout`).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from pipeline import layout, physics, registry
from pipeline.config import Params, Vehicle, config_hash, load_params, load_vehicle, measured_dofs
from pipeline.errors import ModelError
from pipeline.rollout import CoupledDynamics, DecoupledDynamics, rollout
from pipeline.vocabulary import TAU_COLUMNS, VELOCITY_COLUMNS, acceleration_column

log = logging.getLogger(__name__)

__all__ = ["BAND_SIGMAS", "LoadError", "Model", "ModelSet", "load"]

BAND_SIGMAS = 2.0


class LoadError(ModelError):
    """Nothing to load where the caller pointed (no run directory, no registry, an unknown version or alias)."""


@dataclass
class Model:
    """One fitted model, ready to predict and simulate. ``cards``: the model card of each file it was loaded from
    (``{dof: card}`` for a decoupled set, ``{"coupled": card}``), ``files``: those files."""

    name: str
    kind: str  # "decoupled" | "coupled"
    dofs: list[str]
    inputs: list[str]  # the columns ``tau`` holds, in order
    estimators: dict[str, Any]
    cards: dict[str, dict[str, Any]]
    files: dict[str, Path]
    version: str | None = None
    vehicle: Vehicle | None = None
    _dynamics: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = field(default=None, repr=False)

    @property
    def outputs(self) -> list[str]:
        """The acceleration columns ``predict`` returns, in order (``udot_mps2`` ...)."""
        return [acceleration_column(d) for d in self.dofs]

    @property
    def has_interval(self) -> bool:
        return self.interval_kind is not None

    @property
    def interval_kind(self) -> str | None:
        """What ``predict(..., interval=True)``'s band is: "90 % interval" (a coupled model's, from its card),
        "2-sd band" (a decoupled set of GPs) or None (no band)."""
        if self.kind == "coupled":
            interval = (self.cards.get("coupled") or {}).get("interval") or {}
            return "90 % interval" if all(o in interval for o in self.outputs) else None
        if all(hasattr(m, "sample_functions") for m in self.estimators.values()):
            return "2-sd band"
        return None

    @property
    def trials(self) -> list[str]:
        """The trials the model was fitted on (from its cards)."""
        found: set[str] = set()
        for card in self.cards.values():
            found |= set((card.get("lineage") or {}).get("trials") or [])
            found |= set((card.get("trained_on") or {}).get("trials") or [])
        return sorted(found)

    def dynamics(self) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
        """``f(nu (B, k), tau (B, m)) -> nudot (B, k)``: what ``predict`` evaluates and ``simulate`` integrates."""
        if self._dynamics is None:
            if self.kind == "coupled":
                self._dynamics = CoupledDynamics(self.estimators["coupled"])
            else:
                damping = {d: _column_predictor(self.estimators[d]) for d in self.dofs}
                assert self.vehicle is not None
                self._dynamics = DecoupledDynamics(physics.mass_matrix(self.vehicle), self.dofs, damping,
                                                   physics.coriolis_force)
        return self._dynamics

    def _arrays(self, nu: Any, tau: Any) -> tuple[np.ndarray, np.ndarray]:
        nu = np.atleast_2d(np.asarray(nu, dtype=float))
        tau = np.atleast_2d(np.asarray(tau, dtype=float))
        k, m = len(self.dofs), len(self.inputs)
        if nu.shape[1] != k or tau.shape[1] != m or nu.shape[0] != tau.shape[0]:
            raise ValueError(f"model {self.name!r}: nu must be (n, {k}) for DOFs {self.dofs} and tau (n, {m}) for "
                             f"inputs {self.inputs}; got nu {nu.shape}, tau {tau.shape}")
        return nu, tau

    def predict(self, nu: Any, tau: Any, interval: bool = False) -> Any:
        """nudot ``(n, k)`` for velocities ``nu (n, k)`` and inputs ``tau (n, m)``; ``interval=True``:
        ``(nudot, lower, upper)`` with the model's band where it has one (else ``None, None``; the module's doc)."""
        nu, tau = self._arrays(nu, tau)
        nudot = np.asarray(self.dynamics()(nu, tau), dtype=float)
        if not interval:
            return nudot
        if not self.has_interval:
            return nudot, None, None
        if self.kind == "coupled":
            from pipeline.evaluate import interval_half_width  # scikit-learn's metrics: not at `import auvid`

            card = self.cards["coupled"]["interval"]
            half = np.column_stack([np.broadcast_to(interval_half_width(card[o], None, nudot[:, j]), len(nudot))
                                    for j, o in enumerate(self.outputs)])
            return nudot, nudot - half, nudot + half
        dyn = self.dynamics()
        assert isinstance(dyn, DecoupledDynamics)
        sd_d = np.column_stack([np.asarray(self.estimators[d].predict(nu[:, [j]], return_std=True)[1]).ravel()
                                for j, d in enumerate(self.dofs)])
        sd = np.sqrt(sd_d**2 @ (dyn.M_inv**2).T)  # d -> M^-1 d, independent DOFs
        return nudot, nudot - BAND_SIGMAS * sd, nudot + BAND_SIGMAS * sd

    def simulate(self, nu0: Any, tau: Any, t_s: Any) -> np.ndarray:
        """Free run from ``nu0 (k,)`` over the uniform times ``t_s (N,)``: ``tau`` is an ``(N, m)`` array or a
        function ``tau(t_s) -> (N, m)``; returns nu ``(N, k)`` (NaN from a step where it became non-finite)."""
        t_s = np.asarray(t_s, dtype=float)
        if t_s.ndim != 1 or t_s.size < 2:
            raise ValueError("t_s must be a 1-D array of at least two times [s]")
        dt = np.diff(t_s)
        if not np.allclose(dt, dt[0], rtol=1e-6, atol=0.0) or dt[0] <= 0:
            raise ValueError("t_s must be increasing with a constant step (the integrator's step)")
        inputs = np.asarray(tau(t_s) if callable(tau) else tau, dtype=float).reshape(t_s.size, -1)
        nu0 = np.asarray(nu0, dtype=float).reshape(1, -1)
        self._arrays(np.repeat(nu0, t_s.size, axis=0), inputs)  # the shapes checked
        out, _ = rollout(self.dynamics(), nu0, inputs[None], float(dt[0]))
        return out[0]


def _column_predictor(estimator: Any) -> Callable[[np.ndarray], np.ndarray]:
    """A 1-D damping model as ``x (B,) -> d (B,)``."""
    def f(x: np.ndarray) -> np.ndarray:
        return np.asarray(estimator.predict(np.asarray(x, dtype=float).reshape(-1, 1)), dtype=float).ravel()
    return f


class ModelSet(Mapping[str, Model]):
    """The models :func:`load` found, by name (``ls``, ``gp``, ``coupled_<name>``; ``name@version`` when an alias
    picks the same name from two versions). ``champion``: ``{output column: model}`` when loaded by alias."""

    def __init__(self, models: dict[str, Model], source: Path, version: str | None = None,
                 champion: dict[str, Model] | None = None) -> None:
        self._models = models
        self.source, self.version, self.champion = source, version, champion or {}

    def __getitem__(self, name: str) -> Model:
        if name not in self._models:
            raise KeyError(f"no model {name!r} in {self.source}; available: {sorted(self._models)}")
        return self._models[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._models)

    def __len__(self) -> int:
        return len(self._models)

    def __repr__(self) -> str:
        return f"ModelSet({sorted(self._models)}, source={str(self.source)!r}, version={self.version!r})"


# ---------------------------------------------------------------------------------------------- loading

def _read_card(path: Path) -> dict[str, Any] | None:
    try:
        card = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        log.warning("unreadable model card %s; its model is not loaded", path)
        return None
    return card if isinstance(card, dict) else None


def _models_in(models_dir: Path, vehicle: Vehicle | None, params: Params, version: str | None,
               wanted: set[str] | None = None) -> dict[str, Model]:
    """Every model of ``models_dir`` (``data/models``) that the params name (``wanted``: only these names)."""
    from pipeline.models.card import load_model

    out: dict[str, Model] = {}
    dofs = list(params.decoupled.dofs)
    base = models_dir / "decoupled"
    for name in params.decoupled.models:
        if wanted is not None and name not in wanted:
            continue
        files = {d: base / f"{d}_{name}.joblib" for d in dofs}
        if not all(f.is_file() for f in files.values()):
            continue
        if vehicle is None:
            raise LoadError(f"decoupled model {name!r} needs the vehicle config (M, C): none found; pass vehicle=",
                            file=models_dir)
        loaded = {d: load_model(f) for d, f in files.items()}  # sha256 checked against the card
        cards = {d: c for d, (_, c) in loaded.items()}
        hashes = {(c.get("lineage") or {}).get("vehicle_hash") for c in cards.values()} - {None}
        if hashes and hashes != {config_hash(vehicle)}:
            log.warning("decoupled model %r was fitted with another vehicle config than %s (vehicle_hash differs)",
                        name, vehicle.name)
        out[name] = Model(name, "decoupled", dofs, [TAU_COLUMNS[d] for d in dofs],
                          {d: e for d, (e, _) in loaded.items()}, cards, files, version, vehicle)
    states = [VELOCITY_COLUMNS[d] for d in dofs]
    for name in params.coupled.models:
        key = f"coupled_{name}"
        path = models_dir / "coupled" / f"{name}.joblib"
        if (wanted is not None and key not in wanted) or not path.is_file():
            continue
        card = _read_card(path.with_name(f"{name}.card.json")) or {}
        inputs, outputs = card.get("inputs"), card.get("outputs")
        if not isinstance(inputs, list) or inputs[:len(states)] != states \
                or outputs != [acceleration_column(d) for d in dofs]:
            log.info("coupled model %r (inputs %s, outputs %s) does not fit DOFs %s; not loaded", name, inputs,
                     outputs, dofs)
            continue
        estimator, card = load_model(path)
        out[key] = Model(key, "coupled", dofs, list(inputs[len(states):]), {"coupled": estimator},
                         {"coupled": card}, {"coupled": path}, version, vehicle)
    return out


def _configs(run: Path, vehicle: str | Path | Vehicle | None, params: str | Path | Params | None,
             home: Path | None = None) -> tuple[Vehicle | None, Params]:
    if not isinstance(params, Params):
        path = Path(params) if params is not None else run / "params.yaml"
        params = load_params(path if path.is_file() else None)
    if not isinstance(vehicle, Vehicle):
        candidates = [Path(vehicle)] if vehicle is not None else [run / "vehicle.yaml"] + (
            [home / "vehicle.yaml"] if home is not None else [])
        found = next((p for p in candidates if p.is_file()), None)
        if vehicle is not None and found is None:
            raise LoadError("vehicle config not found", file=vehicle)
        vehicle = load_vehicle(found) if found is not None else None
    return vehicle, params if vehicle is None else measured_dofs(vehicle, params)


def load(root_or_version: str | Path, *, version: str | None = None, alias: str | None = None,
         vehicle: str | Path | Vehicle | None = None, params: str | Path | Params | None = None) -> ModelSet:
    """The models of a run directory, a retraining home (its current version, ``version=`` or ``alias=``) or a
    version directory ``HOME/models/<version>``. ``vehicle``/``params`` (paths or loaded configs) default to the
    run's ``vehicle.yaml`` / ``params.yaml`` (a registry version: the home's ``vehicle.yaml``, the version's
    ``params.yaml``). LoadError when there is nothing to load there."""
    path = Path(root_or_version).expanduser().resolve()
    if not path.exists():
        raise LoadError("no such run directory, retraining home or version", file=path)
    if registry.registry_path(path).is_file():
        data = registry.load(path)
        if alias is not None:
            return _load_alias(path, data, alias, vehicle, params)
        name = version or data.get("current")
        if name is None:
            raise LoadError("the registry has no current version (give version=)", file=registry.registry_path(path))
        try:
            registry.require_version(data, name, path)
        except registry.UnknownVersion as err:
            raise LoadError(err.reason, file=err.file) from None
        return _load_version(path, name, vehicle, params)
    if alias is not None or version is not None:
        raise LoadError("version= and alias= need a retraining home (a directory with registry.json)", file=path)
    if registry.registry_path(path.parent.parent).is_file() and path.parent.name == "models":
        return _load_version(path.parent.parent, path.name, vehicle, params)
    if not (path / layout.MODELS).is_dir():
        raise LoadError(f"no {layout.MODELS}/ here: not a run directory (nor a retraining home with registry.json)",
                        file=path)
    v, p = _configs(path, vehicle, params)
    models = _models_in(path / layout.MODELS, v, p, None)
    if not models:
        raise LoadError(f"no fitted model that the params name under {layout.MODELS}/", file=path)
    return ModelSet(models, path)


def _load_version(home: Path, name: str, vehicle: Any, params: Any, wanted: set[str] | None = None) -> ModelSet:
    run = home / "models" / name
    if not (run / layout.MODELS).is_dir():
        raise LoadError(f"version {name} has no {layout.MODELS}/", file=run)
    v, p = _configs(run, vehicle, params, home)
    models = _models_in(run / layout.MODELS, v, p, name, wanted)
    if not models:
        raise LoadError(f"no fitted model{' ' + str(sorted(wanted)) if wanted else ''} in version {name}", file=run)
    return ModelSet(models, run, name)


def _load_alias(home: Path, data: dict[str, Any], alias: str, vehicle: Any, params: Any) -> ModelSet:
    entries = registry.resolve_alias(data, alias, home)
    by_version: dict[str, set[str]] = {}
    for entry in entries.values():
        by_version.setdefault(entry["version"], set()).add(entry["model"])
    loaded = {v: _load_version(home, v, vehicle, params, names) for v, names in sorted(by_version.items())}
    counts: dict[str, int] = {}
    for names in by_version.values():
        for n in names:
            counts[n] = counts.get(n, 0) + 1
    models = {(n if counts[n] == 1 else f"{n}@{v}"): loaded[v][n] for v, names in by_version.items() for n in names}
    champion = {out: loaded[e["version"]][e["model"]] for out, e in sorted(entries.items())}
    return ModelSet(dict(sorted(models.items())), home, None, champion)
