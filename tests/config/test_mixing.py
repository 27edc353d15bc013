"""Thruster commands from an autopilot (issue 34, item 3): the motors' own PWM (servo outputs) mapped as
``pwm_signal``, or the pilot's RC inputs mixed into motor PWMs by a frame's mixing matrix at ingest; both checked
against ArduSub's vectored frame computed by hand."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pipeline.config import Vehicle, parse
from pipeline.config.mixing import AXES, PRESETS, axis_forces, mix_pwm, wrong_pushes
from pipeline.errors import ConfigError
from pipeline.ingest import ingest_log
from pipeline.sim.ardusub_vectored import DIRECTIONS as VECTORED_DIRECTIONS
from pipeline.sim.ardusub_vectored import POSITIONS as VECTORED_POSITIONS

T0_MS = 1_700_000_000_000
AXES_IN = ("pitch", "roll", "throttle", "yaw", "forward", "lateral")  # ArduSub's RC channels 1-6
#: RC inputs (us) per sample, channels 1-6 ...
RC_IN = np.array([
    [1500, 1500, 1300, 1600, 1700, 1500],   # down 0.5, yaw 0.25, forward 0.5
    [1500, 1700, 1500, 1500, 1900, 1900],   # roll 0.5, forward 1, lateral 1: motors 2, 3 saturate
    [1500, 1500, 1500, 1500, 2100, 1500],   # beyond the stick's range: as a full input
])
#: ... and the motor outputs (us) ArduSub's vectored frame gives, by hand (module notes of pipeline.config.mixing):
#: m1 = yaw - fwd + lat, m2 = -yaw - fwd - lat, m3 = -yaw + fwd + lat, m4 = yaw + fwd - lat, m5 = roll - thr,
#: m6 = -roll - thr, each clipped to +-1, PWM = 1500 + 400 m
SERVO_OUT = np.array([
    [1400, 1200, 1600, 1800, 1700, 1700],
    [1500, 1100, 1900, 1500, 1700, 1300],
    [1100, 1100, 1900, 1900, 1500, 1500],
])
MOTORS = [f"m{i}_s" for i in range(1, 7)]


def _vehicle(mixing: dict[str, Any] | None) -> dict[str, Any]:
    rc = {f"{a}_s": {"field": f"ch{i + 1}", "unit": "us"} for i, a in enumerate(AXES_IN)}
    servo = {f"m{i}_s": {"field": f"out{i}", "unit": "us"} for i in range(1, 7)}
    signals = {"u_mps": {"field": "u"}, "v_mps": {"field": "v"}, "yaw_rad": {"field": "psi"},
               **rc, **({} if mixing else servo)}
    table = {"table": "t200.csv", "table_pwm_column": "pwm", "table_thrust_column": "N"}
    return {
        "name": "rov",
        "rigid_body": {"mass_kg": 10, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": f"t{i}", "pwm_signal": f"m{i}_s", "position_m": [0, 0, 0], "direction": [1, 0, 0],
                       "thrust": table} for i in range(1, 7)],
        "sensors": {"velocity": {"frame": "body", "signals": ["u_mps", "v_mps"]}, "attitude": {"yaw": "yaw_rad"}},
        "streams": {"log": {"file": "log.csv", "clock": "column", "csv": {"time_column": "t", "time_unit": "ms"},
                            "signals": signals, **({"mixing": mixing} if mixing else {})}},
    }


VECTORED = {"frame": "ardusub_vectored", "inputs": {a: f"{a}_s" for a in AXES_IN}, "outputs": MOTORS}


def _trial(directory: Path) -> Path:
    directory.mkdir(parents=True)
    head = "t,u,v,psi," + ",".join(f"ch{i}" for i in range(1, 7)) + "," + ",".join(f"out{i}" for i in range(1, 7))
    rows = [",".join(map(str, [T0_MS + 100 * k, 0.5, 0, 0, *RC_IN[k], *SERVO_OUT[k]])) for k in range(len(RC_IN))]
    (directory / "log.csv").write_text(head + "\n" + "\n".join(rows) + "\n")
    return directory


@pytest.mark.parametrize("mixing", [None, VECTORED], ids=["servo_outputs", "rc_inputs_mixed"])
def test_motor_pwm_from_servo_outputs_or_mixed_inputs(tmp_path: Path, mixing: dict[str, Any] | None) -> None:
    v = parse(Vehicle, _vehicle(mixing))
    assert set(MOTORS) <= set(v.signal_names())
    table = ingest_log(_trial(tmp_path / "dive01"), v).tables["log"]
    got = np.column_stack([table[m].to_numpy() for m in MOTORS])
    np.testing.assert_allclose(got * 1e6, SERVO_OUT, rtol=0, atol=1e-6)


def test_mixing_directions_and_unknown_inputs() -> None:
    """MOT_n_DIRECTION flips a motor; a NaN input leaves the motors it drives unknown, the others mixed."""
    mixing = parse(Vehicle, _vehicle({**VECTORED, "directions": [1, 1, 1, 1, 1, -1]})).streams["log"].mixing
    assert mixing is not None
    inputs = {f"{a}_s": RC_IN[:, j] * 1e-6 for j, a in enumerate(AXES_IN)}
    inputs["throttle_s"] = np.array([np.nan, 1.5e-3, 1.5e-3])
    out = mix_pwm(mixing, inputs, 3)
    np.testing.assert_allclose(out["m6_s"][1:] * 1e6, [1700, 1500])  # -(-roll - thr)
    assert np.isnan(out["m5_s"][0]) and np.isnan(out["m6_s"][0])
    np.testing.assert_allclose(out["m1_s"] * 1e6, SERVO_OUT[:, 0])


def test_the_preset_is_ardusubs_vectored_frame() -> None:
    """The factors of AP_Motors6DOF.cpp (SUB_FRAME_VECTORED), as docs/user-guide.md shows them."""
    assert np.array_equal(PRESETS["ardusub_vectored"], [
        [0, 0, 1, 0, -1, 1], [0, 0, -1, 0, -1, -1], [0, 0, -1, 0, 1, 1], [0, 0, 1, 0, 1, -1],
        [1, 0, 0, -1, 0, 0], [-1, 0, 0, -1, 0, 0]])
    guide = (Path(__file__).resolve().parents[2] / "docs" / "user-guide.md").read_text()
    for row in PRESETS["ardusub_vectored"]:
        assert "| " + " | ".join(f"{x:+g}" if x else "0" for x in row) + " |" in guide


@pytest.mark.parametrize(("change", "key", "message"), [
    ({"inputs": {"yaw": "nope_s"}}, "streams.log.mixing.inputs.yaw", "not a signal of this stream"),
    ({"outputs": MOTORS[:5]}, "streams.log.mixing.outputs", "5 outputs for a frame of 6 motors"),
    ({"outputs": ["u_mps", *MOTORS[1:]]}, "streams.log.mixing.outputs.0", "must end with _s"),
    ({"outputs": ["yaw_s", *MOTORS[1:]]}, "streams.log.mixing.outputs.0", "already a signal of this stream"),
    ({"frame": None, "matrix": [[1, 0, 0, 0, 0]] * 6}, "streams.log.mixing.matrix", "6 factors"),
    ({"matrix": [[1, 0, 0, 0, 0, 0]] * 6}, "streams.log.mixing", "either `frame`"),
    ({"frame": "bluerov_heavy"}, "streams.log.mixing.frame", "ardusub_vectored"),
    ({"directions": [1, 1, 1, 1, 1]}, "streams.log.mixing.directions", "5 directions for 6 motors"),
])
def test_a_bad_mixing_names_the_key(change: dict[str, Any], key: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message) as err:
        parse(Vehicle, _vehicle({**VECTORED, **change}))
    assert err.value.field == key


def test_a_user_matrix_mixes_as_given(tmp_path: Path) -> None:
    """A 2-motor frame by hand: m1 = forward + yaw, m2 = forward - yaw, only those axes given."""
    mixing = {"matrix": [[0, 0, 1, 0, 1, 0], [0, 0, -1, 0, 1, 0], *[[0] * 6] * 4],
              "inputs": {"forward": "forward_s", "yaw": "yaw_s"}, "outputs": MOTORS}
    table = ingest_log(_trial(tmp_path / "dive01"), parse(Vehicle, _vehicle(mixing))).tables["log"]
    np.testing.assert_allclose(table["m1_s"].to_numpy() * 1e6, [1800, 1900, 1900])  # 0.5 + 0.25; 1; 1 (clipped)
    np.testing.assert_allclose(table["m2_s"].to_numpy() * 1e6, [1600, 1900, 1900])
    np.testing.assert_allclose(table["m3_s"].to_numpy() * 1e6, 1500)


def _geometry(vehicle: dict[str, Any], directions: np.ndarray) -> dict[str, Any]:
    """The vehicle's thrusters placed as the BlueROV2's (pipeline.sim.ardusub_vectored) along ``directions``."""
    for i, thr in enumerate(vehicle["thrusters"]):
        thr["position_m"], thr["direction"] = VECTORED_POSITIONS[i].tolist(), directions[i].tolist()
    return vehicle


def test_the_vectored_frame_pushes_each_axis_with_the_bluerov2_geometry() -> None:
    """B A for the BlueROV2's thrusters: each checked pilot axis pushes its own DOF alone (per unit motor thrust:
    forward 4 x cos 45 deg = 2.83 N along +X, throttle 2 N up, yaw 4 x 0.189 m x ... about +N)."""
    forces = axis_forces(np.asarray(PRESETS["ardusub_vectored"]), np.ones(6), VECTORED_POSITIONS, VECTORED_DIRECTIONS)
    np.testing.assert_allclose(forces[AXES.index("forward")], [2 * np.sqrt(2), 0, 0, 0, 4 * 0.085 * np.sqrt(0.5), 0],
                               atol=1e-12)
    np.testing.assert_allclose(forces[AXES.index("lateral")], [0, 2 * np.sqrt(2), 0, -4 * 0.085 * np.sqrt(0.5), 0, 0],
                               atol=1e-12)
    np.testing.assert_allclose(forces[AXES.index("throttle")], [0, 0, -2, 0, 0, 0], atol=1e-12)
    np.testing.assert_allclose(forces[AXES.index("yaw")], [0, 0, 0, 0, 0, 4 * (0.156 + 0.111) * np.sqrt(0.5)],
                               atol=1e-12)
    assert wrong_pushes(forces) == []
    parse(Vehicle, _geometry(_vehicle(VECTORED), VECTORED_DIRECTIONS))  # accepted


@pytest.mark.parametrize(("flip", "axes"), [(range(4), ["forward", "lateral", "yaw"]), ([4, 5], ["throttle"])],
                         ids=["horizontal", "vertical"])
def test_thrusters_that_push_against_the_frame_are_refused_with_the_matrix_shown(flip: Any, axes: list[str]) -> None:
    """Reversed thruster directions: forward input would drive the vehicle backward. The error names the stream's
    mixing, each axis pushed the wrong way, and the frame's matrix; the motors' `directions` -1 undo it."""
    directions = VECTORED_DIRECTIONS.copy()
    directions[list(flip)] *= -1
    with pytest.raises(ConfigError) as err:
        parse(Vehicle, _geometry(_vehicle(VECTORED), directions))
    assert err.value.field == "streams.log.mixing"
    message = str(err.value)
    assert sorted(a for a in AXES if f"a full {a} input pushes the vehicle the wrong way" in message) == sorted(axes)
    assert "motor 1 (t1): roll 0, pitch 0, yaw 1, throttle 0, forward -1, lateral 1" in message
    motor_directions = [-1 if i in flip else 1 for i in range(6)]
    parse(Vehicle, _geometry(_vehicle({**VECTORED, "directions": motor_directions}), directions))
