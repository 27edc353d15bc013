"""A frame's mixing matrix: the pilot's RC inputs (an autopilot's OverrideRCIn channels) mixed into per-motor PWM.

An ROV autopilot (ArduSub) takes six pilot inputs, each a PWM around a neutral, and mixes them into one command per
motor by its frame's factors. Where the motors' own outputs are logged (``/mavros/rc/out``, ServoOutputRaw) map
those as ``pwm_signal`` instead: they are what the thrusters got. Where only the inputs are, a stream's ``mixing``
rebuilds the motor PWMs at ingest (the config model is :class:`pipeline.config.sources.Mixing`), as the autopilot's
manual mode does::

    x_j = clip((pwm_j - neutral) / range, -1, 1)                     for j in roll pitch yaw throttle forward lateral
    m_i = clip(direction_i * sum_j A_ij x_j, -1, 1),   pwm_i = neutral + range * m_i

A (motors x 6) in ArduSub's factor order (``add_motor_raw_6dof``: roll, pitch, yaw, throttle, forward, lateral).
Not modelled: an attitude or depth controller's own additions (stabilize, depth hold: use motor outputs, or
manual-mode trials), the vectored frame's forward/vertical coupling limit (``MOT_FV_CPLNG_K``, when throttle and
forward are given together), thrust linearization (``MOT_THST_EXPO``), output slew, RC dead zones.

:func:`wrong_pushes` checks a frame against the thrusters' geometry: a full forward input must push the vehicle
forward (+X), lateral right (+Y), throttle up (-Z) and yaw clockwise (+N), each motor taken as linear (thrust +1
along its direction per full output); a reversed thruster direction or ``directions`` entry fails it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # no pydantic here: ingest mixes with a snapshot's view of the config (pipeline.config.snapshot)
    from pipeline.config.sources import Mixing

#: The pilot axes, in the column order of a mixing matrix (ArduSub's add_motor_raw_6dof).
AXES = ("roll", "pitch", "yaw", "throttle", "forward", "lateral")

#: ArduSub's frames by name: motors x AXES. ``ardusub_vectored``: the BlueROV2's vectored 6-thruster frame
#: (FRAME_CONFIG 1; motors 1-4 horizontal, vectored at 45 degrees; 5-6 vertical), from AP_Motors6DOF.cpp.
PRESETS: dict[str, tuple[tuple[float, ...], ...]] = {
    "ardusub_vectored": (
        (0.0, 0.0, 1.0, 0.0, -1.0, 1.0),
        (0.0, 0.0, -1.0, 0.0, -1.0, -1.0),
        (0.0, 0.0, -1.0, 0.0, 1.0, 1.0),
        (0.0, 0.0, 1.0, 0.0, 1.0, -1.0),
        (1.0, 0.0, 0.0, -1.0, 0.0, 0.0),
        (-1.0, 0.0, 0.0, -1.0, 0.0, 0.0),
    ),
}

#: The body force a full input of each checked pilot axis must make: (DOF index in u v w p q r, sign). Roll and
#: pitch are not checked: a frame may have no such control (the vectored frame has no pitch).
PUSHES: dict[str, tuple[int, float]] = {"forward": (0, 1.0), "lateral": (1, 1.0), "throttle": (2, -1.0),
                                        "yaw": (5, 1.0)}
_PUSH_WORDS = {"forward": "forward (+X)", "lateral": "to the right (+Y)", "throttle": "up (-Z)",
               "yaw": "clockwise (+N)"}


def axis_forces(a: np.ndarray, motor_directions: np.ndarray, positions_m: np.ndarray, directions: np.ndarray
                ) -> np.ndarray:
    """The generalized force (u v w p q r) of a full input of each pilot axis, (len(AXES), 6): the mixing matrix
    ``a`` (motors x AXES) times the motors' ``motor_directions`` (1 / -1), each motor linear, through the allocation
    of the thrusters at ``positions_m`` pushing along ``directions`` (motors x 3, normalized here)."""
    d = np.asarray(directions, dtype=float)
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    allocation = np.vstack([d.T, np.cross(np.asarray(positions_m, dtype=float), d).T])
    return (allocation @ (np.asarray(motor_directions, dtype=float)[:, None] * a)).T


def wrong_pushes(forces: np.ndarray) -> list[str]:
    """What a frame gets wrong, from :func:`axis_forces`: one line per checked axis that pushes the wrong way."""
    out = []
    for axis, (dof, sign) in PUSHES.items():
        f = forces[AXES.index(axis)]
        if sign * f[dof] < -1e-6 * max(1.0, float(np.abs(f).max())):
            tau = ", ".join(f"{x:.3g}" for x in f)
            out.append(f"a full {axis} input pushes the vehicle the wrong way, not {_PUSH_WORDS[axis]}: "
                       f"tau [u v w p q r] = [{tau}] per unit motor thrust")
    return out


def show(a: np.ndarray, names: list[str] | None = None) -> str:
    """A mixing matrix as lines ``motor 1 (t1): roll 0, pitch 0, yaw 1, ...``."""
    return "; ".join(f"motor {i + 1}{f' ({names[i]})' if names else ''}: "
                     + ", ".join(f"{axis} {x:g}" for axis, x in zip(AXES, row, strict=True))
                     for i, row in enumerate(np.asarray(a, dtype=float)))


def factors(mixing: Mixing) -> np.ndarray:
    """The mixing matrix of a :class:`Mixing` (or a snapshot's view of one), motors x :data:`AXES`."""
    rows = PRESETS[mixing.frame] if mixing.frame is not None else mixing.matrix
    try:
        return np.asarray(rows, dtype=float)
    except ValueError:  # ragged rows
        return np.zeros((0, 0))


def mix_pwm(mixing: Mixing, inputs_s: dict[str, np.ndarray], n: int) -> dict[str, np.ndarray]:
    """Motor PWMs (s) from the input signals' PWMs (s), ``n`` samples, as the module notes say: output name ->
    values. A NaN input gives NaN for the motors it drives (unknown, not neutral). Takes a :class:`Mixing` or a
    snapshot's view of one (fields only)."""
    neutral, full = mixing.neutral_us * 1e-6, mixing.range_us * 1e-6
    x = np.zeros((n, len(AXES)))
    for j, axis in enumerate(AXES):
        if axis in mixing.inputs:
            x[:, j] = np.clip((np.asarray(inputs_s[mixing.inputs[axis]], dtype=float) - neutral) / full, -1, 1)
    a = factors(mixing)
    out = np.nan_to_num(x, nan=0.0) @ a.T
    out[(np.isnan(x).astype(float) @ (a != 0.0).T.astype(float)) > 0] = np.nan
    directions = np.asarray(mixing.directions or [1] * a.shape[0], dtype=float)
    m = np.clip(out * directions, -1.0, 1.0)
    return {name: neutral + full * m[:, i] for i, name in enumerate(mixing.outputs)}
