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
