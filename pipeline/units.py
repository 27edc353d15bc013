"""Units: every column name ends with the unit of its values, and conversion to it happens once, at ingest.

A signal name in the vehicle config ends with one of :data:`SUFFIXES` (``u_dvl_mps``, ``n1_rpm``,
``yaw_rad``). The source unit of the raw field is declared next to it (``unit: deg/s``); :func:`conversion`
returns the affine map from the source unit to the unit the suffix names. Propeller speed is kept in rpm
inside the pipeline (declared once, here), since thrust tables and the papers use it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pipeline.errors import ConfigError


@dataclass(frozen=True)
class Unit:
    dimension: str
    factor: float  # value_in_target = value * factor + offset
    offset: float = 0.0


# suffix -> (dimension, the unit it names)
SUFFIXES: dict[str, tuple[str, str]] = {
    "mps": ("velocity", "m/s"),
    "mps2": ("acceleration", "m/s^2"),
    "radps": ("angular_velocity", "rad/s"),
    "radps2": ("angular_acceleration", "rad/s^2"),
    "rad": ("angle", "rad"),
    "m": ("length", "m"),
    "rpm": ("rotation_speed", "rpm"),
    "N": ("force", "N"),
    "Nm": ("moment", "N*m"),
    "Pa": ("pressure", "Pa"),
    "degC": ("temperature", "degC"),
    "V": ("voltage", "V"),
    "A": ("current", "A"),
    "W": ("power", "W"),
    "s": ("time", "s"),
    "flag": ("flag", "1"),
    "1": ("dimensionless", "1"),
    "quat": ("quaternion", "1"),
}

# source unit -> Unit relative to the SI / pipeline unit of its dimension
SOURCE_UNITS: dict[str, Unit] = {
    "m/s": Unit("velocity", 1.0),
    "mm/s": Unit("velocity", 1e-3),
    "cm/s": Unit("velocity", 1e-2),
    "knot": Unit("velocity", 1852.0 / 3600.0),
    "m/s^2": Unit("acceleration", 1.0),
    "g": Unit("acceleration", 9.80665),
    "rad/s": Unit("angular_velocity", 1.0),
    "deg/s": Unit("angular_velocity", math.pi / 180.0),
    "deg/h": Unit("angular_velocity", math.pi / 180.0 / 3600.0),
    "rad/s^2": Unit("angular_acceleration", 1.0),
    "deg/s^2": Unit("angular_acceleration", math.pi / 180.0),
    "rad": Unit("angle", 1.0),
    "deg": Unit("angle", math.pi / 180.0),
    "m": Unit("length", 1.0),
    "mm": Unit("length", 1e-3),
    "cm": Unit("length", 1e-2),
    "ft": Unit("length", 0.3048),
    "rpm": Unit("rotation_speed", 1.0),
    "rev/s": Unit("rotation_speed", 60.0),
    "Hz": Unit("rotation_speed", 60.0),
    "rad/s(shaft)": Unit("rotation_speed", 60.0 / (2.0 * math.pi)),
    "N": Unit("force", 1.0),
    "kgf": Unit("force", 9.80665),
    "lbf": Unit("force", 4.4482216152605),
    "N*m": Unit("moment", 1.0),
    "Nm": Unit("moment", 1.0),
    "Pa": Unit("pressure", 1.0),
    "kPa": Unit("pressure", 1e3),
    "bar": Unit("pressure", 1e5),
    "mbar": Unit("pressure", 1e2),
    "dbar": Unit("pressure", 1e4),
    "psi": Unit("pressure", 6894.757293168),
    "degC": Unit("temperature", 1.0),
    "K": Unit("temperature", 1.0, -273.15),
    "V": Unit("voltage", 1.0),
    "A": Unit("current", 1.0),
    "W": Unit("power", 1.0),
    "s": Unit("time", 1.0),
    "ms": Unit("time", 1e-3),
    "us": Unit("time", 1e-6),
    "ns": Unit("time", 1e-9),
    "1": Unit("dimensionless", 1.0),
    "flag": Unit("flag", 1.0),
    "quat": Unit("quaternion", 1.0),
}

# A propeller speed given in rad/s is unambiguous only when stated for a rotation speed signal.
_ROTATION_ALIASES = {"rad/s": "rad/s(shaft)", "rev/min": "rpm", "RPM": "rpm", "rps": "rev/s"}

TIME_UNITS_NS: dict[str, int] = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "µs": 1_000, "ns": 1}


def suffix_of(name: str) -> str:
    """The unit suffix of a column name; raises ConfigError if it has none we know."""
    for suffix in sorted(SUFFIXES, key=len, reverse=True):
        if name.endswith("_" + suffix):
            return suffix
    known = ", ".join("_" + s for s in SUFFIXES)
    raise ConfigError(f"signal name {name!r} must end with a unit suffix; known: {known}", field=name)


_PRETTY = {"m/s^2": "m/s²", "rad/s^2": "rad/s²", "N*m": "N·m", "degC": "°C"}


def axis_label(column: str) -> str:
    """A figure axis label from a column name: ``udot_mps2`` -> ``u̇ [m/s²]``, ``d_u_N`` -> ``d_u [N]``,
    ``r_radps`` -> ``r [rad/s]``. A name without a known unit suffix is returned unchanged."""
    for suffix in sorted(SUFFIXES, key=len, reverse=True):
        if column.endswith("_" + suffix) and len(column) > len(suffix) + 1:
            name = column[: -len(suffix) - 1]
            if len(name) > 3 and name.endswith("dot") and "_" not in name:
                name = name[:-3] + "\u0307"  # combining dot above: u̇
            unit = SUFFIXES[suffix][1]
            return f"{name} [{_PRETTY.get(unit, unit)}]"
    return column


def conversion(signal: str, source_unit: str | None) -> Unit:
    """The affine map from ``source_unit`` to the unit named by ``signal``'s suffix.

    ``None`` means the source is already in the target unit.
    """
    dimension, _target = SUFFIXES[suffix_of(signal)]
    if source_unit is None:
        return Unit(dimension, 1.0)
    unit_name = source_unit
    if dimension == "rotation_speed":
        unit_name = _ROTATION_ALIASES.get(source_unit, source_unit)
    unit = SOURCE_UNITS.get(unit_name)
    if unit is None:
        raise ConfigError(
            f"unknown unit {source_unit!r} for signal {signal!r}; known: {sorted(SOURCE_UNITS)}", field=signal
        )
    if unit.dimension != dimension:
        raise ConfigError(
            f"unit {source_unit!r} is a {unit.dimension}, but signal {signal!r} is a {dimension} "
            f"(from its suffix)",
            field=signal,
        )
    return unit
