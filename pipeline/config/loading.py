"""The config loaders behind :mod:`pipeline.config` (which exports these names lazily): YAML -> validated models,
the params-against-vehicle checks."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from pipeline.config.checks import KeyedError
from pipeline.config.params import EXPLICIT_MODELS, Params
from pipeline.config.vehicle import THRUST_COLUMN, Vehicle, thrust_column
from pipeline.config.yamlload import load_yaml
from pipeline.errors import ConfigError
from pipeline.vocabulary import DOFS, VELOCITY, acceleration_column

__all__ = ["check_params_against_vehicle", "coupled_skip_reason", "load_params", "load_vehicle", "measured_dofs",
           "parse", "todo_markers"]

M = TypeVar("M", bound=BaseModel)

log = logging.getLogger("pipeline.config")  # the name the warnings had before the loaders moved here


def _key(item: Any) -> str:
    """The dotted key of one pydantic error; a :class:`KeyedError` adds the key below where its check ran."""
    loc = [str(p) for p in item["loc"]]
    error = (item.get("ctx") or {}).get("error")
    if isinstance(error, KeyedError):
        loc.append(error.key)
    return ".".join(loc)


def _describe(err: ValidationError) -> str:
    return "; ".join(f"{_key(item) or '(top level)'}: {item['msg']}" for item in err.errors())


def parse(model: type[M], data: Any, source: str | Path = "<memory>") -> M:
    """Validate ``data`` as ``model``; a ConfigError names ``source`` and every offending key."""
    try:
        return model.model_validate(data if data is not None else {})
    except ValidationError as err:
        first_key = _key(err.errors()[0]) if err.errors() else None
        raise ConfigError(f"invalid {model.__name__} config: {_describe(err)}", file=source,
                          field=first_key or None) from None
    except ConfigError as err:  # raised inside a validator by a helper: add the file
        if err.file is not None:
            raise
        raise ConfigError(err.reason, file=source, field=err.field) from None


def todo_markers(data: Any, key: str = "") -> list[tuple[str, str]]:
    """(key, what to give) of every ``"TODO: ..."`` value left in a config (``auvid init`` writes them)."""
    if isinstance(data, dict):
        return [m for k, v in data.items() for m in todo_markers(v, f"{key}.{k}" if key else str(k))]
    if isinstance(data, list):
        return [m for i, v in enumerate(data) for m in todo_markers(v, f"{key}.{i}")]
    if isinstance(data, str) and data.strip().upper().startswith("TODO"):
        return [(key or "(top level)", data.strip()[4:].lstrip(" :") or "a value")]
    return []


def load_vehicle(path: str | Path) -> Vehicle:
    """Load and validate a vehicle config YAML file; a config with ``TODO`` values left lists each of them."""
    data = load_yaml(path)
    todo = todo_markers(data)
    if todo:
        listed = "; ".join(f"{key}: {what}" for key, what in todo)
        raise ConfigError(f"{len(todo)} value(s) still to fill in (TODO): {listed}", file=path, field=todo[0][0])
    vehicle = parse(Vehicle, data, path)
    vehicle._base_dir = Path(path).resolve().parent
    vehicle._source = str(path)
    return vehicle


def load_params(path: str | Path | None) -> Params:
    """Load and validate ``params.yaml``; ``None`` gives the defaults."""
    if path is None:
        return Params()
    return parse(Params, load_yaml(path), path)


def check_params_against_vehicle(vehicle: Vehicle, params: Params, params_path: str | Path | None = None) -> None:
    """Params that name signals must name signals of the vehicle: ``differentiate.noise_sd`` keys are signals of
    its streams (any trial's overrides included), as are ``sync.interpolation`` and ``sync.max_gap_s`` keys (but
    ``default``); ``differentiate.sigma_s_per_signal`` keys body-velocity columns.
    A misspelt key would otherwise be ignored and the noise estimated from the data without a word."""
    known = set(vehicle.signal_names())
    for trial in vehicle.trials:
        known |= set(vehicle.for_trial(trial).signal_names())
    checks = (("noise_sd", params.differentiate.noise_sd, known),
              ("sigma_s_per_signal", params.differentiate.sigma_s_per_signal, set(VELOCITY)))
    for key, given, valid in checks:
        unknown = sorted(set(given) - valid)
        if unknown:
            raise ConfigError(f"differentiate.{key} names {unknown}, which are not "
                              + ("signals of the vehicle's streams" if key == "noise_sd" else "velocity columns")
                              + f"; known: {sorted(valid)}", file=params_path, field=f"differentiate.{key}")
    for key, mapping in (("interpolation", params.sync.interpolation), ("max_gap_s", params.sync.max_gap_s)):
        unknown = sorted(set(mapping) - known - {"default"})  # the sync stage refused it later, without the file
        if unknown:
            raise ConfigError(f"sync.{key} names {unknown}, which are not signals of the vehicle's streams; known: "
                              f"{sorted(known)}", file=params_path, field=f"sync.{key}.{unknown[0]}")
    _warn_thrust_inputs(vehicle, params, params_path)


def measured_dofs(vehicle: Vehicle, params: Params, params_path: str | Path | None = None) -> Params:
    """``params`` with ``decoupled.dofs`` the vehicle's sensors measure (a DOF they do not is 0 in its store, and
    its damping would be fitted on a column of zeros). Left at its default (u v r, a horizontal vehicle's): the
    default's DOFs the sensors measure, or, where the velocity source measures neither u nor v (a heave-only ROV's
    depth), the DOFs it measures (w); logged when that differs from the default, and the params unchanged (the same
    object) when not. Set by the user: a DOF the sensors do not measure is a ConfigError naming the key."""
    p = params.decoupled
    measured = vehicle.sensors.dofs()
    if "dofs" in p.model_fields_set:
        for i, dof in enumerate(p.dofs):
            if dof not in measured:
                raise ConfigError(f"decoupled.dofs names {dof}, which the vehicle {vehicle.name!r} does not measure "
                                  f"(its sensors measure {', '.join(measured) or 'none'} only): its damping would be "
                                  f"fitted on a column of zeros; list only measured DOFs", file=params_path,
                                  field=f"decoupled.dofs.{i}")
        return params
    linear = vehicle.sensors.linear_velocity().dofs
    dofs = [d for d in p.dofs if d in measured] if {"u", "v"} & set(linear) else list(linear)
    if dofs == list(p.dofs):
        return params
    if not dofs:
        raise ConfigError(f"the vehicle {vehicle.name!r} measures none of the decoupled study's DOFs: set "
                          f"decoupled.dofs", file=params_path, field="decoupled.dofs")
    log.info("decoupled.dofs left at its default (%s): the vehicle %r measures %s only, so the decoupled study "
             "takes %s", ", ".join(p.dofs), vehicle.name, ", ".join(measured) or "none", ", ".join(dofs))
    # model_copy marks dofs as set (the other keys keep their state), so a second call changes nothing
    return params.model_copy(update={"decoupled": p.model_copy(update={"dofs": dofs})})


def coupled_skip_reason(vehicle: Vehicle, params: Params) -> str | None:
    """Why the coupled study (stages tune and train) has nothing to learn on this vehicle, or None when it runs:
    its outputs (``coupled.outputs``, the accelerations u̇ v̇ ṙ by default) are all of DOFs the vehicle's sensors do
    not measure (a heave-only ROV measures w alone; the others are 0 in its store). One measured output DOF is
    enough for the study to run as configured."""
    modelled = [d for d in DOFS if acceleration_column(d) in params.coupled.outputs]
    measured = vehicle.sensors.dofs()
    if not modelled or set(modelled) & set(measured):
        return None
    return (f"the vehicle {vehicle.name!r} has no {'/'.join(modelled)} DOFs (its sensors measure "
            f"{', '.join(measured) or 'none'} only), and the coupled study needs them: it learns "
            f"{', '.join(params.coupled.outputs)} (coupled.outputs) from their velocities; the damping of "
            f"{', '.join(measured) or 'the measured DOFs'} is the decoupled stage's")


def _warn_thrust_inputs(vehicle: Vehicle, params: Params, params_path: str | Path | None) -> None:
    """``coupled.inputs`` naming the thrust of a thruster the vehicle does not have (the default names DAGON's
    th1 th2 th3) is said when the configs load, not only when the tune stage, after ingest ... features, refuses
    it. A warning, not an error: a run that never reaches the coupled models must not be stopped by them."""
    if not set(params.coupled.models) - set(EXPLICIT_MODELS):
        return
    if coupled_skip_reason(vehicle, params) is not None:
        return  # the tune and train stages skip (and say why): their inputs do not matter
    columns = [thrust_column(t.name) for t in vehicle.thrusters]
    unknown = [c for c in params.coupled.inputs if THRUST_COLUMN.match(c) and c not in columns]
    if unknown:
        log.warning("%scoupled.inputs names %s, thrust columns of thrusters the vehicle %r does not have; its "
                    "thrusters' columns are %s: the tune stage will refuse the coupled models' inputs until "
                    "coupled.inputs lists them", f"{params_path}: " if params_path else "", unknown, vehicle.name,
                    columns)
