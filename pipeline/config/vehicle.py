"""The vehicle: rigid body, added mass, thrusters, sensor mounting, and the topic map.

Matrices are 6x6 in Fossen's DOF order [u v w p q r] (surge, sway, heave, roll, pitch, yaw); the models
choose which DOFs they use (``dofs``), nothing here hard-wires 3 DOF.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import Field, PrivateAttr, ValidationError, ValidationInfo, field_validator, model_validator

from pipeline.config import checks, mixing
from pipeline.config.actuators import (  # noqa: F401  (re-exported: the vehicle's parts)
    MAX_THRUST_COEFFICIENT,
    THRUST_COLUMN,
    ControlSurface,
    SurfaceLift,
    ThrustCurve,
    Thruster,
    thrust_column,
)
from pipeline.config.base import Frozen, Vec3
from pipeline.config.rigid_body import RigidBody, rigid_body_mass
from pipeline.config.sources import MESSAGE_DEFINITIONS_DOC, StreamSource, TrialOverride
from pipeline.config.vehicle_methods import VehicleMethods
from pipeline.errors import ConfigError


class DvlMount(Frozen):
    velocity: tuple[str, str, str] = Field(description="Signals of the DVL's x, y, z velocity.")
    valid: str | None = Field(None, description="Bottom-lock flag signal (nonzero = valid).")
    zero_is_invalid: bool = Field(True, description="An exact zero vector means lost lock, not rest.")
    position_m: Vec3 = (0.0, 0.0, 0.0)
    rotation_rpy_deg: Vec3 = Field((0.0, 0.0, 0.0), description="DVL frame to body frame, roll-pitch-yaw (deg, "
                                   f"each within +/-{checks.MAX_ANGLE_DEG:g}).")

    @field_validator("rotation_rpy_deg")
    @classmethod
    def _angles(cls, rpy: Vec3) -> Vec3:
        far = max(abs(a) for a in rpy)
        if far > checks.MAX_ANGLE_DEG:
            raise ValueError(f"rotation_rpy_deg {list(rpy)}: an angle of {far:g} deg; accepted: each within "
                             f"+/-{checks.MAX_ANGLE_DEG:g} deg")
        return rpy


class AttitudeSource(Frozen):
    quaternion: str | None = Field(None, description="Quaternion signal (columns _w _x _y _z).")
    convention: Literal["frd_ned", "flu_enu"] = Field(
        "frd_ned", description="body FRD -> NED (marine), or ROS body FLU -> ENU.")
    roll: str | None = None
    pitch: str | None = None
    yaw: str | None = None

    @model_validator(mode="after")
    def _one_kind(self) -> AttitudeSource:
        if (self.quaternion is None) == (self.yaw is None):
            raise ValueError("give either `quaternion` or `roll`/`pitch`/`yaw` signals")
        return self


class RateSource(Frozen):
    """Angular rates in body FRD axes: per body axis, the signal and a sign (gyro axis mapping)."""

    p: str | None = None
    q: str | None = None
    r: str | None = None
    signs: Vec3 = Field((1.0, 1.0, 1.0), description="Per body axis p, q, r: 1 or -1 (the gyro's axis points the "
                        "other way).")

    @field_validator("signs")
    @classmethod
    def _unit_signs(cls, signs: Vec3) -> Vec3:
        if any(s not in (1.0, -1.0) for s in signs):
            raise ValueError(f"signs {list(signs)}: each must be 1 or -1 (a rate is measured or flipped, not scaled)")
        return signs


class VelocitySource(Frozen):
    """Linear velocity measured directly, not by a DVL: in body axes, or in earth axes (towing-tank x/y rates,
    GNSS, a motion-capture system's rates) rotated into body axes by the logged attitude at each sample.

    Two signals make a planar source (u, v; or earth x, y): w is then not measured (0, as an unconfigured rate),
    and earth-frame x/y rates are rotated by the heading alone. Three signals are rotated by roll, pitch and yaw.
    """

    frame: Literal["body", "earth"] = Field(description=(
        "body: the signals are u, v[, w] in body FRD axes; earth: x, y[, z] in the earth axes of `earth_axes`, "
        "rotated into body axes by the attitude (sensors.attitude) at each sample."))
    signals: list[str] = Field(min_length=2, max_length=3, description=(
        "Signals of the velocity components: 2 (planar: u, v or x, y) or 3 (with w or z)."))
    earth_axes: Literal["ned", "enu"] = Field("ned", description=(
        "earth frame only: ned (x north / along heading 0, y east / 90 deg clockwise, z down: the axes the attitude "
        "is given in) or enu (x east, y north, z up; ROS), converted to NED explicitly."))
    position_m: Vec3 = Field((0.0, 0.0, 0.0), description=(
        "Body-axes position of the point whose velocity is measured (GNSS antenna); the reference point's velocity "
        "is v - omega x r."))
    valid: str | None = Field(None, description="Validity flag signal (nonzero = valid); None: always valid.")
    axes: Literal["frd", "flu"] = Field("frd", description=(
        "body frame only: frd (x forward, y starboard, z down: the project's body axes) or flu (x forward, y left, "
        "z up: ROS REP-103, e.g. the twist of a nav_msgs/Odometry in its child frame), converted to FRD: "
        "u = x, v = -y, w = -z."))

    @model_validator(mode="after")
    def _axes_in_body_frame(self) -> VelocitySource:
        if self.frame == "earth" and self.axes != "frd":
            raise ValueError("`axes` names body axes (frame: body); for earth-frame velocities give `earth_axes`")
        return self


#: The earth axes a position source may give: horizontal (x, y), vertical alone (z: a depth sensor), or all three.
COMPONENT_SETS = ({"x", "y"}, {"z"}, {"x", "y", "z"})


class PositionSource(Frozen):
    """Positions in a local earth frame (motion capture, GNSS in local coordinates, a depth sensor), differentiated
    into velocities: per earth axis, the white-jerk smoother of the kalman method (positions at their own stamps,
    noise estimated from the data) gives the earth-frame velocity and acceleration; they are rotated into body axes
    by the logged attitude (the heading alone when not all three axes are given), as an earth-frame velocity source
    is. A depth alone (``components: [z]``) gives w, the heave of a level vehicle; u and v are not measured (0).
    """

    signals: list[str] = Field(min_length=1, max_length=3, description=(
        "Signals of the position components in m, in the order of `components`: by default 2 (planar: x, y) or "
        "3 (x, y, z)."))
    components: list[Literal["x", "y", "z"]] | None = Field(None, description=(
        "The earth axis of each signal: [x, y], [z] (a depth: the heave of a depth-hold trial) or [x, y, z], in "
        "any order. None: x, y[, z] in the order of `signals`."))
    earth_axes: Literal["ned", "enu"] = Field("ned", description=(
        "ned (x north, y east, z down) or enu (x east, y north, z up; ROS), converted to NED explicitly."))
    position_m: Vec3 = Field((0.0, 0.0, 0.0), description=(
        "Body-axes position of the tracked point (marker set origin, GNSS antenna) relative to the reference point."))
    valid: str | None = Field(None, description="Validity flag signal (nonzero = valid); None: always valid.")

    @model_validator(mode="after")
    def _components_match(self) -> PositionSource:
        given = self.components or ["x", "y", "z"][: len(self.signals)]
        if len(given) != len(self.signals):
            raise checks.KeyedError("components", f"{len(given)} components for {len(self.signals)} signals: name "
                                    "the earth axis of each signal")
        if len(set(given)) != len(given) or set(given) not in COMPONENT_SETS:
            what = "a single signal gives a depth: `components: [z]`" if self.components is None else (
                f"found {given}")
            raise checks.KeyedError("components", "positions are [x, y] (planar), [z] (a depth) or [x, y, z]; "
                                    + what)
        return self

    @property
    def axes_given(self) -> tuple[str, ...]:
        """The earth axis of each signal, in signal order."""
        return tuple(self.components or ("x", "y", "z")[: len(self.signals)])


class AccelerometerSource(Frozen):
    """An IMU's accelerometers: specific force f = a - g (the point's acceleration less gravity; at rest and level
    an FRD IMU reads (0, 0, -g)) along three body axes, at the IMU's position. The kalman method turns it into
    measurements of the reference point's body accelerations (u_dot, v_dot, w_dot) with the attitude and the
    smoothed rates and velocities, estimating a constant bias per axis (pipeline.estimation.accelerometer)."""

    signals: tuple[str, str, str] = Field(description="Signals of the specific force along x, y, z (m/s^2).")
    position_m: Vec3 = Field((0.0, 0.0, 0.0), description=(
        "Body-axes position of the IMU relative to the reference point (its lever arm)."))
    axes: Literal["frd", "flu"] = Field("frd", description=(
        "frd (x forward, y starboard, z down: the project's body axes) or flu (x forward, y left, z up: ROS "
        "REP-103, a sensor_msgs/Imu in its own frame), converted to FRD: x, -y, -z."))


def position_rate_column(signal: str) -> str:
    """The column holding the smoothed time derivative (m/s) of the position signal ``signal``."""
    return f"{signal}_rate_mps"


@dataclass(frozen=True)
class LinearVelocity:
    """The configured linear-velocity sensor, whichever key states it (``sensors.dvl`` or ``sensors.velocity``)."""

    key: str                      # the config key: sensors.dvl or sensors.velocity
    frame: str                    # body (a DVL is body after its constant mounting rotation) or earth
    velocity: tuple[str, ...]     # the component signals, 2 (planar) or 3
    valid: str | None
    zero_is_invalid: bool
    position_m: Vec3
    rotation_rpy_deg: Vec3        # constant sensor -> body rotation (DVL mounting); zero otherwise
    earth_axes: str = "ned"
    axes: str = "frd"             # body frame: frd, or flu (ROS), converted to FRD
    differentiated: bool = False  # sensors.position: ``velocity`` holds positions, differentiated by the smoother
    components: tuple[str, ...] = ()  # the axis (x, y, z) of each signal; empty: x, y[, z] in signal order

    @property
    def axes_given(self) -> tuple[str, ...]:
        """The sensor axis (x, y, z) of each signal, in signal order."""
        return self.components or ("x", "y", "z")[: len(self.velocity)]

    @property
    def dofs(self) -> tuple[str, ...]:
        """The body DOFs it measures, in u, v, w order: u, v (planar), w (a depth alone) or u, v, w."""
        given = set(self.axes_given)
        return tuple(d for d, a in zip("uvw", "xyz", strict=True) if a in given)

    @property
    def velocity_columns(self) -> tuple[str, ...]:
        """The columns holding the velocity components: the signals, or, for positions, their smoothed rates
        (:func:`position_rate_column`)."""
        return tuple(position_rate_column(s) for s in self.velocity) if self.differentiated else self.velocity


class Sensors(Frozen):
    dvl: DvlMount | None = Field(None, description="A DVL (body-frame velocity after a constant mounting rotation).")
    velocity: VelocitySource | None = Field(None, description=(
        "Velocities from another source: body or earth frame (give one of `dvl`, `velocity`, `position`)."))
    position: PositionSource | None = Field(None, description=(
        "Positions in a local earth frame (motion capture, GNSS), differentiated into velocities."))
    attitude: AttitudeSource | None = Field(None, description=(
        "The attitude signals. None: the vehicle is taken as level (roll = pitch = 0, heading 0; a warning per "
        "trial): a heave-only vehicle with a depth sensor. Earth-frame horizontal velocities or positions need it."))
    rates: RateSource = RateSource()
    accelerometer: AccelerometerSource | None = Field(None, description=(
        "IMU accelerometers (optional): extra measurements of the body accelerations for the kalman method."))
    depth: str | None = None

    @model_validator(mode="after")
    def _one_velocity_source(self) -> Sensors:
        if sum(x is not None for x in (self.dvl, self.velocity, self.position)) != 1:
            raise ValueError("give exactly one velocity source: `dvl` (a DVL with its mounting), `velocity` "
                             "(frame: body or earth, with its signals) or `position` (earth-frame positions, "
                             "differentiated)")
        return self

    @model_validator(mode="after")
    def _mounts_on_board(self) -> Sensors:
        for key in ("dvl", "velocity", "position", "accelerometer"):
            mount = getattr(self, key)
            if mount is not None:
                try:
                    checks.check_body_point(mount.position_m, "position_m")
                except ValueError as err:
                    raise checks.KeyedError(f"{key}.position_m", str(err)) from None
        return self

    @model_validator(mode="after")
    def _heading_for_earth_axes(self) -> Sensors:
        source = self.linear_velocity()
        if self.attitude is None and source.frame == "earth" and {"u", "v"} & set(source.dofs):
            raise checks.KeyedError(source.key.split(".", 1)[1], (
                "earth-frame horizontal velocities or positions are rotated into body axes by the heading: give "
                "sensors.attitude (without it the vehicle is taken as level, which only a vertical source, "
                "`components: [z]`, allows)"))
        return self

    def dofs(self) -> tuple[str, ...]:
        """The body DOFs the sensors measure, in u v w p q r order: the velocity source's, then each rate given
        (the others are 0 in the kinematics table; a heave-only ROV measures w alone)."""
        rates = tuple(d for d, s in zip("pqr", (self.rates.p, self.rates.q, self.rates.r), strict=True) if s)
        return self.linear_velocity().dofs + rates

    def linear_velocity(self) -> LinearVelocity:
        if self.dvl is not None:
            d = self.dvl
            return LinearVelocity("sensors.dvl", "body", tuple(d.velocity), d.valid, d.zero_is_invalid,
                                  d.position_m, d.rotation_rpy_deg)
        if self.position is not None:
            x = self.position
            return LinearVelocity("sensors.position", "earth", tuple(x.signals), x.valid, False, x.position_m,
                                  (0.0, 0.0, 0.0), x.earth_axes, differentiated=True, components=x.axes_given)
        v = self.velocity
        assert v is not None
        return LinearVelocity("sensors.velocity", v.frame, tuple(v.signals), v.valid, False, v.position_m,
                              (0.0, 0.0, 0.0), v.earth_axes, axes=v.axes)


class Vehicle(VehicleMethods, Frozen):
    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$")
    rigid_body: RigidBody
    added_mass: list[list[float]] = Field(description=(
        "6x6 added-mass matrix M_A: symmetric, positive semi-definite (zero is fine); M_RB + M_A positive definite."))
    thrusters: list[Thruster] = Field(min_length=1)
    control_surfaces: list[ControlSurface] = Field(default_factory=list, description=(
        "Rudders, fins: their angles are carried to the feature store as inputs of the learned models."))
    sensors: Sensors
    streams: dict[str, StreamSource] = Field(min_length=1)
    message_definitions: list[str] = Field(default_factory=list, description=MESSAGE_DEFINITIONS_DOC)
    trials: dict[str, TrialOverride] = Field(default_factory=dict, description=(
        "Per-trial overrides: trial name or glob (trial id: the log's name without extensions) -> what differs "
        "for the matching trials. Several matching keys apply in config order, a later one winning per key."))

    _base_dir: Path = PrivateAttr(default_factory=Path.cwd)
    _source: str | None = PrivateAttr(default=None)

    def override_keys(self) -> dict[str, dict[str, dict[str, Any]]]:
        """Every trial override as given: ``{pattern: {stream: {key: value}}}``, in config order."""
        return {pattern: {name: o.model_dump(mode="json", exclude_unset=True) for name, o in t.streams.items()}
                for pattern, t in self.trials.items()}

    def _apply_overrides(self, trial: str) -> Vehicle:
        """This vehicle with ``trial``'s overrides applied. Each override was validated on its own at load; two
        matching keys that only together make an invalid stream raise a ConfigError here, naming the trial, the
        keys and the stream."""
        matching = [(pattern, t) for pattern, t in self.trials.items()
                    if checks.applies_to(pattern, trial)]
        streams = dict(self.streams)
        for _, t in matching:
            for name, override in t.streams.items():
                try:
                    streams[name] = override.apply(streams[name])
                except (ValidationError, ValueError) as err:
                    keys = [p for p, t2 in matching if name in t2.streams]
                    why = "; ".join(e["msg"] for e in err.errors()) if isinstance(err, ValidationError) else str(err)
                    raise ConfigError(f"trial {trial!r}: the overrides {keys} of stream {name!r} together give an "
                                      f"invalid stream: {why}", field=f"trials.{keys[-1]}.streams.{name}") from None
        return self.model_copy(update={"streams": streams})

    def actuator_signals(self) -> list[str]:
        """Every actuator and control input signal, in config order: each thruster's input (speed, PWM or thrust),
        then each control surface's angle. Carried from sync to the feature store."""
        return list(dict.fromkeys([t.input_signal for t in self.thrusters]
                                  + [c.angle_signal for c in self.control_surfaces]))

    @field_validator("added_mass")
    @classmethod
    def _added_mass_psd(cls, rows: list[list[float]]) -> list[list[float]]:
        added = checks.square(rows, 6, "the added-mass matrix M_A")
        checks.check_symmetric(added, "the added-mass matrix M_A")
        checks.check_positive_semidefinite(added, "the added-mass matrix M_A", hint=(
            ": M_A holds positive masses (M_A = -diag(X_udot, Y_vdot, ...)); a negative diagonal usually means "
            "the hydrodynamic derivatives were entered with their sign"))
        return rows

    @field_validator("streams")
    @classmethod
    def _stream_names_safe(cls, streams: dict[str, StreamSource]) -> dict[str, StreamSource]:
        for name in streams:
            try:
                checks.check_safe_name(name, "stream name")
            except ValueError as err:
                raise checks.KeyedError(name, str(err)) from None
        return streams

    @model_validator(mode="after")
    def _mass_matrix_usable(self) -> Vehicle:
        """M = M_RB + M_A finite and conditioned. It is positive definite already (M_RB is, with a positive mass
        and inertia; M_A is semi-definite), as :func:`pipeline.physics.mass_matrix` needs."""
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is what the next line reports
            mass = rigid_body_mass(self.rigid_body) + np.asarray(self.added_mass, dtype=float)
        if not np.all(np.isfinite(mass)):
            raise checks.KeyedError("rigid_body", "the mass matrix M = M_RB + M_A has non-finite entries (mass_kg "
                                    f"{self.rigid_body.mass_kg:g} with cg_m {list(self.rigid_body.cg_m)})")
        try:
            checks.check_conditioned(mass, "the mass matrix M = M_RB + M_A")
        except ValueError as err:
            raise checks.KeyedError("added_mass", str(err)) from None
        return self

    @model_validator(mode="after")
    def _mixing_pushes_its_axes(self) -> Vehicle:
        """A stream's mixing frame and the thrusters driven by its outputs agree (:func:`mixing.wrong_pushes`):
        forward input pushes forward, and so on; the frame's matrix is shown where they do not."""
        by_signal = {t.input_signal: t for t in self.thrusters if t.input_kind == "pwm"}
        for name, stream in self.streams.items():
            if stream.mixing is None or not all(o in by_signal for o in stream.mixing.outputs):
                continue
            driven = [by_signal[o] for o in stream.mixing.outputs]
            directions = np.asarray([t.direction for t in driven], dtype=float)
            if not np.all(np.linalg.norm(directions, axis=1) > 0):
                continue  # a zero direction: its own check names it
            a = stream.mixing.factors()
            wrong = mixing.wrong_pushes(mixing.axis_forces(
                a, np.asarray(stream.mixing.directions or [1] * len(driven)),
                np.asarray([t.position_m for t in driven]), directions))
            if wrong:
                raise checks.KeyedError(
                    f"streams.{name}.mixing", "; ".join(wrong) + f". The frame {stream.mixing.frame or '(matrix)'} "
                    f"mixes [{mixing.show(a, [t.name for t in driven])}]: reverse the thrusters' `direction` that "
                    "disagree (a positive PWM's push, body FRD) or set the motor's `directions` entry to -1 "
                    "(ArduSub's MOT_n_DIRECTION); docs/user-guide.md 8.3")
        return self

    @model_validator(mode="after")
    def _references_exist(self) -> Vehicle:
        """Every signal named is defined by exactly one stream; thrusters and surfaces have their own names and
        inputs. Each error is keyed at the reference (``thrusters.1.speed_signal``)."""
        KeyedError = checks.KeyedError
        names = self.signal_names()
        known = set(names)
        dupes = sorted({n for n in known if names.count(n) > 1})
        if dupes:
            where = [s for s, stream in self.streams.items() if dupes[0] in stream.signals]
            if not where:  # only mixed outputs define it
                where = [s for s, stream in self.streams.items() if stream.mixing and dupes[0] in stream.mixing.outputs]
                raise KeyedError(f"streams.{where[-1]}.mixing.outputs", f"signals defined in more than one stream: "
                                 f"{dupes} ({dupes[0]!r} mixed in streams {where})")
            raise KeyedError(f"streams.{where[-1]}.signals.{dupes[0]}",
                             f"signals defined in more than one stream: {dupes} ({dupes[0]!r} in streams {where})")
        for i, thr in enumerate(self.thrusters):
            if thr.input_signal not in known:
                raise KeyedError(f"thrusters.{i}.{thr.input_kind}_signal",
                                 f"thrusters[{i}].{thr.input_kind}_signal {thr.input_signal!r} is not a configured "
                                 f"signal; known: {sorted(known)}")
        for i, surface in enumerate(self.control_surfaces):
            if surface.angle_signal not in known:
                raise KeyedError(f"control_surfaces.{i}.angle_signal",
                                 f"control_surfaces[{i}].angle_signal {surface.angle_signal!r} is not a configured "
                                 f"signal; known: {sorted(known)}")
            if surface.lift is not None and surface.lift.behind is not None and surface.lift.behind not in {
                    t.name for t in self.thrusters}:
                raise KeyedError(f"control_surfaces.{i}.lift.behind",
                                 f"control_surfaces[{i}].lift.behind {surface.lift.behind!r} is not a thruster; "
                                 f"thrusters: {[t.name for t in self.thrusters]}")
        parts: list[tuple[str, Thruster | ControlSurface]] = (
            [(f"thrusters.{i}", t) for i, t in enumerate(self.thrusters)]
            + [(f"control_surfaces.{i}", c) for i, c in enumerate(self.control_surfaces)])
        seen: dict[str, str] = {}
        for key, part in parts:
            if part.name in seen:
                raise KeyedError(f"{key}.name", f"thruster and control-surface names must be unique; {part.name!r} "
                                 f"is also {seen[part.name]}.name")
            seen[part.name] = key
        driven: dict[str, str] = {}
        for key, part in parts:
            signal = part.input_signal if isinstance(part, Thruster) else part.angle_signal
            field = f"{part.input_kind}_signal" if isinstance(part, Thruster) else "angle_signal"
            if signal in driven:
                raise KeyedError(f"{key}.{field}", f"each thruster and control surface needs its own input signal; "
                                 f"{signal!r} also drives {driven[signal]}")
            driven[signal] = key
        for key, name in self._sensor_references():
            if name not in known:
                raise KeyedError(key,
                                 f"{key} {name!r} is not a configured signal (define it under `streams`); "
                                 f"known: {sorted(known)}")
        return self

    @field_validator("trials")
    @classmethod
    def _overrides_valid(cls, trials: dict[str, TrialOverride], info: ValidationInfo) -> dict[str, TrialOverride]:
        """Each override names a configured stream and gives a valid stream once applied on its own."""
        streams: dict[str, StreamSource] = info.data.get("streams") or {}
        for pattern, t in trials.items():
            for name, override in t.streams.items():
                key = f"trials.{pattern}.streams.{name}"
                if name not in streams:
                    raise ValueError(f"{key}: no stream {name!r} to override; streams: {sorted(streams)}")
                try:
                    override.apply(streams[name])
                except ValidationError as err:
                    why = "; ".join(f"{'.'.join(map(str, e['loc'])) or '(stream)'}: {e['msg']}" for e in err.errors())
                    raise ValueError(f"{key}: {why}") from None
                except ValueError as err:
                    raise ValueError(f"{key}: {err}") from None
        return trials

    def _sensor_references(self) -> list[tuple[str, str]]:
        """(config key, signal) of every signal the sensors section names."""
        s = self.sensors
        source = s.linear_velocity()
        refs = [(f"{source.key}.{'velocity' if source.key == 'sensors.dvl' else 'signals'}.{j}", n)
                for j, n in enumerate(source.velocity)]
        if source.valid is not None:
            refs.append((f"{source.key}.valid", source.valid))
        att = s.attitude
        if att is not None:
            refs += [(f"sensors.attitude.{k}", n) for k, n in (("quaternion", att.quaternion), ("roll", att.roll),
                                                               ("pitch", att.pitch), ("yaw", att.yaw)) if n]
        refs += [(f"sensors.rates.{k}", n) for k, n in zip("pqr", (s.rates.p, s.rates.q, s.rates.r), strict=True)
                 if n]
        if s.accelerometer is not None:
            refs += [(f"sensors.accelerometer.signals.{j}", n) for j, n in enumerate(s.accelerometer.signals)]
        if s.depth:
            refs.append(("sensors.depth", s.depth))
        return refs
