"""Which vehicles the coupled study skips (issue 34, item 3): one whose sensors measure none of the DOFs of
``coupled.outputs`` (a heave-only ROV: w alone, the study models u̇ v̇ ṙ); any measured output DOF runs it."""

from __future__ import annotations

from typing import Any

import pytest

from pipeline.config import Params, Vehicle, coupled_skip_reason, parse


def _vehicle(sensors: dict[str, Any], signals: list[str]) -> Vehicle:
    return parse(Vehicle, {
        "name": "rov",
        "rigid_body": {"mass_kg": 10, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": "t1", "speed_signal": "n1_rpm", "position_m": [0, 0, 0], "direction": [0, 0, 1],
                       "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
        "sensors": sensors,
        "streams": {"nav": {"file": "nav.csv", "clock": "column", "csv": {"time_column": "t"},
                            "signals": {s: {"field": s} for s in ["n1_rpm", *signals]}}},
    })


HEAVE = ({"position": {"signals": ["depth_m"], "components": ["z"]}}, ["depth_m"])
HEAVE_AND_YAW_RATE = ({**HEAVE[0], "rates": {"r": "r_radps"}}, ["depth_m", "r_radps"])
PLANAR = ({"velocity": {"frame": "body", "signals": ["u_mps", "v_mps"]}, "attitude": {"yaw": "yaw_rad"}},
          ["u_mps", "v_mps", "yaw_rad"])


@pytest.mark.parametrize(("sensors", "outputs", "dofs", "skipped"), [
    (HEAVE, None, ("w",), True),
    (HEAVE, ["wdot_mps2"], ("w",), False),  # the user points the study at heave: it runs as configured
    (HEAVE_AND_YAW_RATE, None, ("w", "r"), False),  # r is measured: the study runs (u, v are the user's to drop)
    (PLANAR, None, ("u", "v"), False),
])
def test_the_study_skips_only_without_any_of_its_dofs(sensors: tuple[dict[str, Any], list[str]],
                                                      outputs: list[str] | None, dofs: tuple[str, ...],
                                                      skipped: bool) -> None:
    vehicle = _vehicle(*sensors)
    params = parse(Params, {"coupled": {"outputs": outputs, "models": ["rbf_svr"]}} if outputs else {})
    assert vehicle.sensors.dofs() == dofs
    reason = coupled_skip_reason(vehicle, params)
    if skipped:
        assert reason is not None
        assert reason.startswith("the vehicle 'rov' has no u/v/r DOFs (its sensors measure w only)")
        assert "udot_mps2, vdot_mps2, rdot_radps2 (coupled.outputs)" in reason
    else:
        assert reason is None
