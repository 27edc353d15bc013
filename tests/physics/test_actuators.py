"""Actuators and control inputs: thrusters by speed, PWM (through a table, at a voltage) or measured thrust; control
surfaces as raw inputs carried from sync to the feature store; the kernels' input groups from the config."""

from __future__ import annotations

import copy
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest

from pipeline import physics
from pipeline.config import Vehicle, parse
from pipeline.config.params import CoupledParams, FeaturesParams
from pipeline.derive import derive
from pipeline.errors import ConfigError, SchemaError
from pipeline.kinematics import body_kinematics
from pipeline.store import features_table
from pipeline.sync import required_signals
from tests.estimation.test_velocity_sources import ship_dict, synced_grid
from tests.fixturepaths import SHARED, T200_CSV, shared_fixture

T200 = SHARED / "csv" / "bluerobotics_t200_performance_10-20V.csv"
KGF = 9.80665


def rudder_ship(**thruster: Any) -> dict[str, Any]:
    data = ship_dict()
    data["control_surfaces"] = [{"name": "rudder", "angle_signal": "rudder_rad"}]
    data["streams"]["tank"]["signals"]["rudder_rad"] = {"field": "delta", "unit": "deg"}
    if thruster:
        data["thrusters"] = [{**data["thrusters"][0], **thruster}]
        for key in ("speed_signal", "pwm_signal", "thrust_signal"):
            if key in thruster and thruster[key] is not None:
                data["thrusters"][0] = {k: v for k, v in data["thrusters"][0].items()
                                        if k == key or k not in ("speed_signal", "pwm_signal", "thrust_signal")}
                data["streams"]["tank"]["signals"][thruster[key]] = {"field": "x"}
    return data


def test_pwm_thruster_through_the_t200_table_at_its_voltage() -> None:
    table = {"table": str(shared_fixture(T200_CSV)), "table_pwm_column": "PWM (µs)",
             "table_thrust_column": "Force (Kg f)",
             "table_thrust_unit": "kgf", "table_voltage_column": "Voltage (V)", "voltage_V": 16.0}
    vehicle = parse(Vehicle, rudder_ship(pwm_signal="th1_pwm_s", thrust=table))
    thr = vehicle.thrusters[0]
    assert thr.input_kind == "pwm" and vehicle.actuator_signals() == ["th1_pwm_s", "rudder_rad"]
    # rows of the sheet: 1900 us -> 5.25 kgf, 1500 us -> 0, 1300 us -> -1.44 kgf; the PWM signal is in seconds
    got = physics.thrust_N(thr, np.array([1900e-6, 1500e-6, 1300e-6, 1302e-6]))
    row_1304 = -1.39  # the sheet's next row
    np.testing.assert_allclose(got[:3], np.array([5.25, 0.0, -1.44]) * KGF, rtol=1e-12)
    assert got[3] == pytest.approx((-1.44 + row_1304) / 2 * KGF, rel=0.02)
    # a voltage the sheet does not cover is refused with the voltages it has
    other = parse(Vehicle, rudder_ship(pwm_signal="th1_pwm_s", thrust={**table, "voltage_V": 12.0}))
    with pytest.raises(ConfigError, match=r"voltage_V 12 is outside the table's voltages \[16.0\]"):
        physics.thrust_N(other.thrusters[0], np.array([1.5e-3]))


def test_two_voltages_are_interpolated(tmp_path: Path) -> None:
    (tmp_path / "t.csv").write_text("pwm,volts,kgf\n1100,12,-2\n1900,12,3\n1100,16,-4\n1900,16,5\n")
    table = {"table": "t.csv", "table_pwm_column": "pwm", "table_thrust_column": "kgf", "table_thrust_unit": "kgf",
             "table_voltage_column": "volts", "voltage_V": 15.0}
    vehicle = parse(Vehicle, rudder_ship(pwm_signal="th1_pwm_s", thrust=table))
    got = physics.thrust_N(vehicle.thrusters[0], np.array([1.1e-3, 1.9e-3]), tmp_path)
    np.testing.assert_allclose(got, [-3.5 * KGF, 4.5 * KGF])


def test_measured_thrust_needs_no_model_and_is_taken_as_it_is() -> None:
    vehicle = parse(Vehicle, rudder_ship(thrust_signal="T1_meas_N", thrust=None))
    np.testing.assert_array_equal(physics.thrusts(vehicle, np.array([[3.0], [-2.0]])), [[3.0], [-2.0]])


@pytest.mark.parametrize(("change", "message"), [
    ({"pwm_signal": "th1_pwm_s"}, "exactly one of speed_signal"),
    ({"speed_signal": None}, "exactly one of speed_signal"),
    ({"speed_signal": None, "pwm_signal": "th1_pwm_1"}, "must end with _s"),
    ({"speed_signal": None, "pwm_signal": "th1_pwm_s"}, "table_pwm_column"),
    ({"speed_signal": None, "thrust_signal": "T1_meas_N"}, None),
])
def test_a_thruster_is_driven_by_exactly_one_signal(change: dict[str, Any], message: str | None) -> None:
    data = ship_dict()
    thr = {k: v for k, v in {**data["thrusters"][0], **change}.items() if v is not None}
    data["thrusters"] = [thr]
    data["streams"]["tank"]["signals"].update({"th1_pwm_s": {"field": "a"}, "th1_pwm_1": {"field": "b"},
                                               "T1_meas_N": {"field": "c"}})
    if message is None:
        assert parse(Vehicle, data).thrusters[0].input_signal == "T1_meas_N"
    else:
        with pytest.raises(ConfigError, match=message):
            parse(Vehicle, data)


def test_control_surface_is_checked_at_config_load() -> None:
    data = rudder_ship()
    bad = copy.deepcopy(data)
    bad["control_surfaces"][0]["angle_signal"] = "rudder_deg_rad"
    with pytest.raises(ConfigError, match=r"control_surfaces\[0\].angle_signal 'rudder_deg_rad' is not a configured"):
        parse(Vehicle, bad)
    bad["control_surfaces"][0]["angle_signal"] = "rudder_deg"
    with pytest.raises(ConfigError, match="must end with _rad"):
        parse(Vehicle, bad)


def test_a_rudder_angle_is_carried_from_sync_to_the_feature_store() -> None:
    vehicle = parse(Vehicle, rudder_ship())
    assert required_signals(vehicle)[-2:] == ["n1_rpm", "rudder_rad"]  # sync makes it valid where it is
    frame, _ = synced_grid()
    frame["rudder_rad"] = np.deg2rad(10.0) * np.sin(np.arange(len(frame)) * 0.1)
    kin = body_kinematics(frame, vehicle)
    np.testing.assert_array_equal(kin["rudder_rad"], frame["rudder_rad"])
    kin = kin.assign(**{c: 0.0 for c in ("u_smooth_mps", "v_smooth_mps", "w_smooth_mps", "p_smooth_radps",
                                         "q_smooth_radps", "r_smooth_radps", "udot_mps2", "vdot_mps2", "wdot_mps2",
                                         "pdot_radps2", "qdot_radps2", "rdot_radps2")})
    derived = derive(kin, vehicle)
    np.testing.assert_array_equal(derived["rudder_rad"], frame["rudder_rad"])
    assert (derived["tau_r_Nm"] == 0).all()  # the propeller is on the centre line; the rudder adds no tau
    table = features_table(derived, "zigzag", FeaturesParams(), vehicle.actuator_signals())
    np.testing.assert_array_equal(table.column("rudder_rad").to_numpy(), frame["rudder_rad"].to_numpy())
    with pytest.raises(SchemaError, match="rudder_rad"):  # not a column the schema knows unless configured
        features_table(derived, "zigzag", FeaturesParams())
    with pytest.raises(SchemaError, match=r"lacks the configured input signal\(s\) \['rudder_rad'\]"):
        features_table(derived.drop(columns="rudder_rad"), "zigzag", FeaturesParams(), vehicle.actuator_signals())


def test_kalman_validity_requires_the_rudder() -> None:
    from pipeline.estimation.kalman import _other_required_valid
    from pipeline.sync import valid_column

    vehicle = parse(Vehicle, rudder_ship())
    synced = pd.DataFrame({valid_column(s): True for s in ("yaw_rad", "n1_rpm", "rudder_rad")}, index=range(4))
    synced.loc[2, valid_column("rudder_rad")] = False
    assert _other_required_valid(synced, vehicle).tolist() == [True, True, False, True]


def test_kernel_input_groups_come_from_the_config() -> None:
    assert CoupledParams().n_velocity_inputs() == 3  # the default [u v r n1 n2 n3]
    ship = CoupledParams(inputs=["u_mps", "v_mps", "r_radps", "rudder_rad", "n1_rpm"])
    assert ship.actuators() == ["rudder_rad", "n1_rpm"] and ship.n_velocity_inputs() == 3
    named = CoupledParams(inputs=["u_mps", "v_mps", "r_radps", "rudder_rad", "T1_meas_N"],
                          actuator_inputs=["rudder_rad", "T1_meas_N"])
    assert named.n_velocity_inputs() == 3
    with pytest.raises(ConfigError, match=r"velocities first.*\['u_mps', 'r_radps', 'rudder_rad', 'n1_rpm'\]"):
        parse(CoupledParams, {"inputs": ["u_mps", "rudder_rad", "r_radps", "n1_rpm"]})
    with pytest.raises(ConfigError, match="not in coupled.inputs"):
        parse(CoupledParams, {"inputs": ["u_mps", "n1_rpm"], "actuator_inputs": ["rudder_rad"]})
