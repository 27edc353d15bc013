"""The topic map: which stream of a log carries which signal, with clock, offset and unit.

A *stream* is one topic of a ROS log (or one CSV file of a trial directory); it is decoded once and
written as one Parquet file at native rate. Each of its *signals* is a field path into the message (or a
CSV column) whose name, in the config, ends with the unit it is converted to (see :mod:`pipeline.units`).

```yaml
streams:
  dvl:
    topic: /dvl/data
    clock: header            # header stamp or log time: chosen per topic, never guessed
    offset_s: 0.0            # constant offset added to the stamps
    signals:
      u_dvl_mps: {field: velocity.x}
      v_dvl_mps: {field: velocity.y, unit: m/s}
      dvl_valid_flag: {field: bottom_lock}
  thrusters:
    topic: /thrusters/joint_states
    clock: header
    signals:
      n1_rpm: {field: "velocity[name=th1]", unit: rad/s}
  fog:
    file: fog.csv.gz         # CSV: a file inside the trial directory
    clock: column
    csv: {time_column: t, time_unit: ms, time_origin: absolute}
    signals:
      r_fog_radps: {field: rate, unit: deg/s}
  depth:
    topic: /depth              # std_msgs/msg/Float64: no header
    clock: log
    optional: true           # a trial without /depth goes on, its signals invalid (NaN) downstream
    signals:
      depth_m: {field: data}
  tank:
    file: run*.dat
    clock: column
    time: {rate_hz: 20}      # stamps rounded to 3 digits: time = first stamp + row index / 20 Hz
    csv: {time_column: t, header: false, columns: [t, x, y], skip_rows: 4, encoding: cp1252}
    signals:
      x_m: {field: x}
```

Types a log does not embed (ROS 2 sqlite3 bags before Iron carry no definitions; an MCAP schema may be
empty) come from the user's ``.msg`` / ``.idl`` files, in directories listed at the top level of the vehicle
config, searched recursively (a ROS package tree works: ``<pkg>/msg/Foo.msg`` defines ``pkg/msg/Foo``)::

    message_definitions: [msgs/]    # relative to the vehicle file

A stream with ``optional: true`` may be absent from a trial (topic or file missing, undecodable, or empty):
ingest then logs a warning, lists it under ``absent_streams`` in the ingest report, and the trial goes on;
sync gives its signals as NaN with ``<signal>__valid`` False. A stream that is not optional (the default) is
needed: a trial without it is quarantined, with the reason.

A trial that differs (an offset measured per dive, a topic renamed in one recording, a stream only it lacks) gets
per-trial overrides under the top-level ``trials`` key: ``trials: {dive07: {streams: {dvl: {offset_s: 0.12}}}}``
(a trial name or glob; any stream option; :class:`StreamOverride`), applied by ingest and sync for that trial only.

Ingest checks the stamps of every stream (zero, constant, sim-time header stamps, duplicates, quantized
stamps, steps back; :mod:`pipeline.stamps`) and names these options as the remedy.
"""

from __future__ import annotations

import codecs
import math
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from pipeline.config import checks
from pipeline.config.base import Frozen
from pipeline.config.mixing import AXES, factors
from pipeline.errors import ConfigError
from pipeline.units import conversion

MESSAGE_DEFINITIONS_DOC = (
    "Directories of .msg / .idl files (relative to the vehicle file, searched recursively; a ROS package tree "
    "works: <pkg>/msg/Foo.msg defines pkg/msg/Foo) for the message types a log does not embed (ROS 2 sqlite3 "
    "bags before Iron, empty MCAP schemas). Definitions embedded in a log win; these win over the ROS 2 "
    "standard types.")


#: The sizes a signal's ``scale`` may have: 12 orders of magnitude either way; beyond, a raw value times it
#: underflows to 0 or overflows float64 on the way through a unit conversion.
MIN_SCALE, MAX_SCALE = 1e-12, 1e12


class SignalSource(Frozen):
    """One signal: a field of the stream's messages (a CSV column), with its unit; ``sign`` and ``scale`` map a
    sensor's own convention onto the pipeline's, applied once at ingest before the unit: the signal is
    ``unit(sign * scale * raw)``. ArduSub's ``rel_alt`` (m, positive up) as a depth (positive down) is
    ``depth_m: {field: ..., sign: -1}``; a pressure sensor's depth in counts of 1 mm is
    ``{scale: 0.001, unit: m}``."""

    field: str = Field(description="Field path into the message (velocity.x, velocity[2], "
                       "velocity[name=th1]) or the CSV column name.")
    unit: str | None = Field(None, description="Unit of sign * scale * raw value; None: already in the unit "
                             "the signal name's suffix states.")
    sign: Literal[1, -1] = Field(1, description=(
        "-1 flips the signal (a sensor whose axis points the other way: rel_alt is up, depth is down)."))
    scale: float = Field(1.0, description=(
        "Factor on the raw value, before `unit` converts it (counts to the unit); its size from 1e-12 to 1e12; "
        "for a flip give `sign: -1`."))

    @field_validator("scale")
    @classmethod
    def _scale_usable(cls, scale: float) -> float:
        if not math.isfinite(scale) or not MIN_SCALE <= abs(scale) <= MAX_SCALE:
            raise ValueError(f"scale must be a finite, non-zero number of size {MIN_SCALE:g} to {MAX_SCALE:g} "
                             f"(counts of a picometre to a terametre); found {scale!r}")
        return scale

    @property
    def factor(self) -> float:
        """sign * scale: what multiplies the raw value before the unit conversion."""
        return float(self.sign) * self.scale


class CsvOptions(Frozen):
    time_column: str = Field(description="Column holding the time stamp.")
    time_unit: Literal["s", "ms", "us", "µs", "ns"] = "s"
    time_origin: Literal["absolute", "relative"] = Field(
        "absolute", description="absolute: since the Unix epoch; relative: since epoch_s.")
    epoch_s: float = Field(0.0, description="Start of a relative time column, Unix seconds.")
    delimiter: str | None = Field(None, description="None: detect comma, tab, semicolon or whitespace.")
    skip_rows: int = Field(0, ge=0, le=10_000_000, description="Preamble lines before the header (or the data).")
    header: bool = Field(True, description="False: the file has no header; give `columns`.")
    columns: list[str] | None = Field(None, description="Column names when the file has no header.")
    encoding: str = "utf-8"

    @field_validator("encoding")
    @classmethod
    def _known_encoding(cls, encoding: str) -> str:
        try:
            codecs.lookup(encoding)
        except LookupError:
            raise ValueError(f"unknown text encoding {encoding!r} (e.g. utf-8, cp1252, latin-1)") from None
        try:  # rot13, base64, hex, zlib ... are codecs too, but not from bytes to text: a file cannot be read so
            b"a".decode(encoding)  # (an empty input would skip the check)
        except UnicodeError:
            pass  # a text codec that needs more bytes (utf-16)
        except LookupError:
            raise ValueError(f"{encoding!r} is not a text encoding (bytes to text); give the file's character "
                             "encoding (e.g. utf-8, cp1252, latin-1, utf-16)") from None
        return encoding

    @field_validator("epoch_s")
    @classmethod
    def _epoch_in_range(cls, epoch_s: float) -> float:
        return checks.check_offset_s(epoch_s, "epoch_s")  # type: ignore[return-value]

    @model_validator(mode="after")
    def _columns_when_headerless(self) -> CsvOptions:
        if not self.header and not self.columns:
            raise ValueError("a CSV without header needs `columns`")
        return self


#: The rates ``time: {rate_hz}`` accepts: one sample per 1000 s (a slow tank logger is far faster) to one per
#: nanosecond (the resolution of the int64 stamps). Outside, k / rate_hz leaves int64 nanoseconds within a few
#: thousand rows, or two rows share a stamp.
MIN_RATE_HZ, MAX_RATE_HZ = 1e-3, 1e9


class TimeOptions(Frozen):
    """Rebuild a stream's time from the row index: uniformly sampled from its first stamp."""

    rate_hz: float = Field(gt=0, allow_inf_nan=False, description=(
        "Sampling rate of the stream. Its time becomes first + k / rate_hz (k: the row or message index, "
        "dropped rows counted), the first stamp taken from `clock` and `offset_s` added. For stamps that are "
        "zero, constant, duplicated or rounded (3 significant digits) while the samples are uniform. "
        f"From {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz."))

    @field_validator("rate_hz")
    @classmethod
    def _rate_in_range(cls, rate_hz: float) -> float:
        if not MIN_RATE_HZ <= rate_hz <= MAX_RATE_HZ:
            raise ValueError(f"rate_hz {rate_hz:g} is outside {MIN_RATE_HZ:g} to {MAX_RATE_HZ:g} Hz (one sample "
                             "per 1000 s to one per nanosecond, the stamps' resolution)")
        return rate_hz


Axis = Literal["roll", "pitch", "yaw", "throttle", "forward", "lateral"]


class Mixing(Frozen):
    """Motor PWMs mixed from the pilot's inputs (see the module notes); the outputs become signals of the stream."""

    frame: Literal["ardusub_vectored"] | None = Field(None, description=(
        "A named frame: ardusub_vectored (the BlueROV2's 6 thrusters, ArduSub FRAME_CONFIG 1). Or give `matrix`."))
    matrix: list[list[float]] | None = Field(None, description=(
        "One row per motor, columns roll, pitch, yaw, throttle, forward, lateral (ArduSub's factor order)."))
    inputs: dict[Axis, str] = Field(min_length=1, description=(
        "Pilot axis -> the stream's signal of its PWM (a pulse width `<name>_s`, `unit: us`); an axis left out "
        "is neutral. ArduSub's default channels: 1 pitch, 2 roll, 3 throttle, 4 yaw, 5 forward, 6 lateral."))
    outputs: list[str] = Field(min_length=1, description=(
        "Names of the motor PWM signals, one per matrix row (`<name>_s`): what thrusters' `pwm_signal` names."))
    directions: list[Literal[1, -1]] | None = Field(None, description=(
        "Per motor, 1 or -1 (ArduSub's MOT_n_DIRECTION); default all 1."))
    neutral_us: float = Field(1500.0, gt=0, le=20_000.0, description="PWM of a neutral input and a stopped motor "
                              "(us; a pulse within a 50-Hz frame: up to 20000).")
    range_us: float = Field(400.0, gt=0, le=20_000.0, description="PWM from neutral to a full input or output (us, "
                            "up to 20000).")

    @model_validator(mode="after")
    def _shape(self) -> Mixing:
        if (self.frame is None) == (self.matrix is None):
            raise ValueError("give either `frame` (a named frame) or `matrix` (one row of 6 factors per motor)")
        rows = self.factors()
        if rows.ndim != 2 or rows.shape[1] != len(AXES):
            raise checks.KeyedError("matrix", f"a mixing matrix has one row of {len(AXES)} factors {list(AXES)} per "
                                    f"motor; found rows of {sorted({len(r) for r in self.matrix or []})}")
        if len(self.outputs) != rows.shape[0]:
            raise checks.KeyedError("outputs", f"{len(self.outputs)} outputs for a frame of {rows.shape[0]} motors "
                                    f"({self.frame or 'matrix'}): name one PWM signal per motor")
        if self.directions is not None and len(self.directions) != rows.shape[0]:
            raise checks.KeyedError("directions", f"{len(self.directions)} directions for {rows.shape[0]} motors")
        for key, names in (("inputs", list(self.inputs.values())), ("outputs", self.outputs)):
            for j, name in enumerate(names):
                if not name.endswith("_s"):
                    where = f"{key}.{list(self.inputs)[j]}" if key == "inputs" else f"{key}.{j}"
                    raise checks.KeyedError(where, f"{name!r}: a pulse width, its name must end with _s")
        dupes = sorted({n for n in self.outputs if self.outputs.count(n) > 1})
        if dupes:
            raise checks.KeyedError("outputs", f"each motor needs its own output signal; repeated: {dupes}")
        return self

    def factors(self) -> np.ndarray:
        """The mixing matrix, motors x :data:`AXES`."""
        return factors(self)  # type: ignore[arg-type]


class StreamSource(Frozen):
    topic: str | None = Field(None, description="Topic in a ROS log / MCAP file.")
    file: str | None = Field(None, description="CSV file name (or glob) inside the trial directory.")
    clock: Literal["log", "header", "column"] = Field(
        description="Which time stamps the stream: log time, the message header stamp, or the CSV time "
        "column. Never guessed.")
    offset_s: float = Field(0.0, description="Constant offset added to every stamp of this stream.")
    time: TimeOptions | None = Field(None, description=(
        "None: every sample keeps its own stamp. {rate_hz: R}: time from the row index, uniformly sampled "
        "at R Hz from the first stamp (the remedy for zero, duplicate or quantized stamps)."))
    csv: CsvOptions | None = None
    optional: bool = Field(False, description=(
        "True: a trial may lack this stream (topic or file absent, undecodable or empty); it goes on with the "
        "stream's signals invalid (NaN), with a warning and an entry in the ingest report's absent_streams. "
        "False: a trial without it is quarantined."))
    signals: dict[str, SignalSource] = Field(min_length=1)
    mixing: Mixing | None = Field(None, description=(
        "Motor PWMs mixed at ingest from this stream's pilot-input signals (RC override channels) by a frame's "
        "mixing matrix; its outputs become signals of the stream. Where the motor outputs are logged "
        "(/mavros/rc/out), map those instead."))

    @model_validator(mode="after")
    def _mixing_on_own_signals(self) -> StreamSource:
        if self.mixing is None:
            return self
        for axis, name in self.mixing.inputs.items():
            if name not in self.signals:
                raise checks.KeyedError(f"mixing.inputs.{axis}", f"{name!r} is not a signal of this stream; "
                                        f"signals: {sorted(self.signals)}")
        for j, name in enumerate(self.mixing.outputs):
            if name in self.signals:
                raise checks.KeyedError(f"mixing.outputs.{j}", f"{name!r} is already a signal of this stream: "
                                        "name the mixed motor PWM apart from the logged signals")
        return self

    @model_validator(mode="after")
    def _one_source(self) -> StreamSource:
        if (self.topic is None) == (self.file is None):
            raise ValueError("give exactly one of `topic` (ROS log) or `file` (CSV)")
        if self.file is not None:
            if self.csv is None:
                raise ValueError("a CSV stream needs `csv` options (time_column, time_unit, ...)")
            if self.clock != "column":
                raise ValueError("a CSV stream is stamped by its time column: set `clock: column`")
        elif self.clock == "column":
            raise ValueError("`clock: column` is for CSV streams; a topic uses `log` or `header`")
        return self

    @field_validator("offset_s")
    @classmethod
    def _offset_in_range(cls, offset_s: float) -> float:
        return checks.check_offset_s(offset_s)  # type: ignore[return-value]

    @field_validator("signals")
    @classmethod
    def _units_known(cls, signals: dict[str, SignalSource]) -> dict[str, SignalSource]:
        return _check_units(signals)


def _check_units(signals: dict[str, SignalSource]) -> dict[str, SignalSource]:
    """Each signal's name ends with a known unit suffix and its ``unit`` converts to it; a quaternion takes no
    ``sign`` or ``scale`` (-q is the same rotation; a scaled one is none)."""
    for name, source in signals.items():
        if name.endswith("_quat") and source.factor != 1.0:
            key = "sign" if source.sign != 1 else "scale"
            raise checks.KeyedError(f"{name}.{key}", f"signal {name!r} is a quaternion: `sign` and `scale` do not "
                                    "apply (-q is the same rotation); map its axes with sensors.attitude.convention")
        try:
            conversion(name, source.unit)
        except ConfigError as err:
            raise checks.KeyedError(f"{name}.unit" if source.unit is not None else name, err.reason) from None
    return signals


class StreamOverride(Frozen):
    """What one trial changes of a stream's source: any of its options; the keys left out keep the stream's value.

    ``signals`` changes the field path or unit of signals the stream already has (their names stay)."""

    topic: str | None = Field(None, description="Topic in this trial's log.")
    file: str | None = Field(None, description="CSV file name (or glob) in this trial's directory.")
    clock: Literal["log", "header", "column"] | None = None
    offset_s: float | None = Field(None, description="Constant offset added to every stamp, for this trial.")
    time: TimeOptions | None = None
    csv: CsvOptions | None = None
    optional: bool | None = Field(None, description="True: this trial may lack the stream.")
    signals: dict[str, SignalSource] | None = Field(None, description=(
        "Field path / unit of some of the stream's signals in this trial (names as under the stream)."))

    @field_validator("offset_s")
    @classmethod
    def _offset_in_range(cls, offset_s: float | None) -> float | None:
        return checks.check_offset_s(offset_s)

    def apply(self, stream: StreamSource) -> StreamSource:
        """``stream`` with this override's keys; validated as a stream (a ValueError says what is wrong)."""
        given = self.model_dump(exclude_unset=True)
        merged = stream.model_dump()
        unknown = sorted(set(given.get("signals") or {}) - set(stream.signals))
        if unknown:
            raise ValueError(f"signals {unknown} are not signals of this stream; known: {sorted(stream.signals)}")
        if "signals" in given:
            merged["signals"] = {**merged["signals"], **given.pop("signals")}
        merged.update(given)
        return StreamSource.model_validate(merged)


class TrialOverride(Frozen):
    """Per-trial changes to the vehicle config, for the trials whose name matches the key (a name or a glob)."""

    streams: dict[str, StreamOverride] = Field(default_factory=dict, description=(
        "Stream name -> the source options that differ in these trials (offset_s measured per dive, a topic "
        "renamed in one recording, optional: true for a stream one trial lacks)."))
