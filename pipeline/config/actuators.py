"""The vehicle's actuators in its config: thrusters (their thrust map: coefficients or a table) and control
surfaces (an angle signal, and optionally a lift model). Re-exported by :mod:`pipeline.config.vehicle`."""

from __future__ import annotations

import math
import re
from typing import Literal

from pydantic import Field, field_validator, model_validator

from pipeline.config import checks
from pipeline.config.base import Frozen, Vec3

#: The largest thrust coefficient k (N per rpm^2): a large ship's propeller gives ~1e6 N at ~100 rpm (k ~ 100).
MAX_THRUST_COEFFICIENT = 1e4


class ThrustCurve(Frozen):
    """T = k n|n| (n in rpm), with separate coefficients forward and backward; or a measured table, looked up by
    propeller speed (``table_speed_column``, rpm) or by PWM pulse width (``table_pwm_column``), at one supply
    voltage when the table holds several (``table_voltage_column`` and ``voltage_V``)."""

    k_fwd_N_per_rpm2: float | None = Field(None, ge=0, le=MAX_THRUST_COEFFICIENT, description=(
        f"Forward coefficient (thrust N per rpm^2, 0 to {MAX_THRUST_COEFFICIENT:g}: a small thruster is ~1e-6, a "
        "ship's propeller ~100)."))
    k_bwd_N_per_rpm2: float | None = Field(None, ge=0, le=MAX_THRUST_COEFFICIENT, description=(
        "Backward coefficient, positive like the forward one (reverse thrust is -k_bwd n^2)."))
    table: str | None = Field(None, description="CSV thrust table, path relative to the vehicle file.")
    table_speed_column: str | None = Field(None, description="Column of propeller speed (rpm) in the table.")
    table_pwm_column: str | None = Field(None, description="Column of PWM pulse width in the table (a thruster "
                                         "driven by `pwm_signal`).")
    table_pwm_unit: Literal["us", "ms", "s"] = Field("us", description="Unit of the table's PWM column.")
    table_thrust_column: str | None = None
    table_thrust_unit: str = "N"
    table_voltage_column: str | None = Field(None, description="Column of supply voltage (V), for a table measured "
                                             "at several voltages.")
    voltage_V: float | None = Field(None, gt=0, le=10_000.0, description=(
        "Supply voltage of the vehicle (V, up to 10000): the table's rows at this voltage are used (between two "
        "measured voltages, the thrust is interpolated)."))

    @model_validator(mode="after")
    def _one_kind(self) -> ThrustCurve:
        has_k = self.k_fwd_N_per_rpm2 is not None
        if has_k == (self.table is not None):
            raise ValueError("give either k_fwd_N_per_rpm2 (and optionally k_bwd_N_per_rpm2) or a table")
        if self.table is not None and self.table_thrust_column is None:
            raise ValueError("a thrust table needs table_thrust_column")
        if self.table is not None and self.table_speed_column is None and self.table_pwm_column is None:
            raise ValueError("a thrust table needs table_speed_column (rpm) or table_pwm_column (PWM)")
        if (self.table_voltage_column is None) != (self.voltage_V is None):
            raise ValueError("table_voltage_column and voltage_V go together: give the table's voltage column and "
                             "the vehicle's supply voltage")
        return self


#: the feature-store column of a thruster's thrust (the derive stage writes it): ``T_<thruster name>_N``
THRUST_COLUMN = re.compile(r"^T_([A-Za-z0-9_\-]+)_N$")


def thrust_column(thruster_name: str) -> str:
    """The feature-store column of a thruster's thrust, ``T_<name>_N`` (:data:`THRUST_COLUMN`)."""
    return f"T_{thruster_name}_N"


class Thruster(Frozen):
    """One thruster, driven by exactly one signal: propeller speed (rpm; ingest converts rev/s or rad/s), PWM pulse
    width (through a table's PWM column), or a measured thrust (N)."""

    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$", description="Unique; it names the thrust column T_<name>_N.")
    speed_signal: str | None = Field(None, description="Signal carrying this thruster's propeller speed, in rpm.")
    pwm_signal: str | None = Field(None, description=(
        "Signal carrying the PWM pulse width (name it <name>_s, `unit: us`); thrust from the table's PWM column."))
    thrust_signal: str | None = Field(None, description="Signal carrying a measured thrust in N (no thrust model).")
    position_m: Vec3
    direction: Vec3 = Field(description="Thrust direction in body axes: any non-zero vector, normalized by the "
                            "pipeline ([1, 1, 0] is 45 degrees between x and y).")
    thrust: ThrustCurve | None = Field(None, description="Thrust model; not needed with `thrust_signal`.")
    lag_s: float = Field(0.0, ge=0, le=60.0, description="First-order lag of the propeller (simulator only; s, 0 to "
                         "60).")

    @field_validator("position_m")
    @classmethod
    def _on_board(cls, point: Vec3) -> Vec3:
        return checks.check_body_point(point, "position_m")  # type: ignore[return-value]

    @model_validator(mode="after")
    def _direction_nonzero(self) -> Thruster:
        norm = math.hypot(*self.direction)
        if not norm > 1e-9 or not math.isfinite(norm):
            raise checks.KeyedError("direction", f"thruster {self.name!r}: a thrust direction must be a non-zero "
                                    f"vector; found {list(self.direction)} (length {norm:g})")
        return self

    @model_validator(mode="after")
    def _one_input(self) -> Thruster:
        given = [k for k in ("speed_signal", "pwm_signal", "thrust_signal") if getattr(self, k) is not None]
        if len(given) != 1:
            raise ValueError(f"give exactly one of speed_signal (rpm), pwm_signal (PWM through a table) or "
                             f"thrust_signal (measured thrust, N); found {given or 'none'}")
        if self.thrust_signal is not None:
            if not self.thrust_signal.endswith("_N"):
                raise ValueError(f"thrust_signal {self.thrust_signal!r}: a force, its name must end with _N")
            return self
        if self.thrust is None:
            raise ValueError(f"{given[0]} needs a thrust model: `thrust` (k_fwd_N_per_rpm2, or a table)")
        if self.pwm_signal is not None:
            if not self.pwm_signal.endswith("_s"):
                raise ValueError(f"pwm_signal {self.pwm_signal!r}: a pulse width, its name must end with _s "
                                 "(give `unit: us` in its stream)")
            if self.thrust.table is None or self.thrust.table_pwm_column is None:
                raise ValueError("pwm_signal needs a thrust table with table_pwm_column (PWM -> thrust)")
        elif self.thrust.table is not None and self.thrust.table_speed_column is None:
            raise ValueError("speed_signal with a thrust table needs table_speed_column (rpm)")
        return self

    @property
    def input_signal(self) -> str:
        """The signal driving this thruster, whichever kind."""
        return next(s for s in (self.speed_signal, self.pwm_signal, self.thrust_signal) if s is not None)

    @property
    def input_kind(self) -> Literal["speed", "pwm", "thrust"]:
        return "speed" if self.speed_signal is not None else "pwm" if self.pwm_signal is not None else "thrust"


class SurfaceLift(Frozen):
    """A rudder's or fin's lift, L = 1/2 rho A C_La alpha U_R^2, along ``axis`` at ``position_m``
    (pipeline.physics.surface_forces; docs/models.md)."""

    area_m2: float = Field(gt=0, le=1e3, description="Its planform area (m^2).")
    lift_slope_per_rad: float = Field(gt=0, le=10.0, description="dC_L/d(alpha) per rad (a rudder of aspect ratio "
                                      "1-2: about 2-3).")
    position_m: Vec3 = Field(description="Its centre of pressure in the body frame (m).")
    axis: Literal["y", "z"] = Field("y", description="The lift's body axis: y for a rudder, z for a diving plane; a "
                                    "positive angle lifts along +axis.")
    behind: str | None = Field(None, description="The thruster whose slipstream it sits in: its thrust T adds "
                               "8 T / (rho pi D^2) to U_R^2 (momentum theory's far wake).")
    slipstream_diameter_m: float | None = Field(None, gt=0, le=100.0, description="That propeller's diameter D (m).")
    density_kg_m3: float = Field(1025.0, ge=900.0, le=1100.0, description="The water's density (kg/m^3).")

    @model_validator(mode="after")
    def _slipstream(self) -> SurfaceLift:
        if (self.behind is None) != (self.slipstream_diameter_m is None):
            raise ValueError("behind and slipstream_diameter_m go together: the thruster and its propeller's diameter")
        return self


class ControlSurface(Frozen):
    """A rudder, fin or plane: its deflection angle is an input of the learned models (raw, as a feature column);
    with ``lift`` its force is added to the generalized forces tau, else it adds nothing to them."""

    name: str
    angle_signal: str = Field(description="Signal carrying the deflection angle (name it <name>_rad; ingest converts "
                              "`unit: deg`).")
    lift: SurfaceLift | None = Field(None, description="Its lift model; none: the angle is a model input only.")

    @model_validator(mode="after")
    def _angle(self) -> ControlSurface:
        if not self.angle_signal.endswith("_rad"):
            raise ValueError(f"angle_signal {self.angle_signal!r}: an angle, its name must end with _rad")
        return self
