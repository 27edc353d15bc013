from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from pipeline import physics
from pipeline.config import Vehicle, parse
from pipeline.errors import ConfigError
from tests.fixturepaths import SHARED, T200_CSV, shared_fixture

T200 = SHARED / "csv" / "bluerobotics_t200_performance_10-20V.csv"
KGF = 9.80665


def vehicle_dict(**changes: Any) -> dict[str, Any]:
    data: dict[str, Any] = {
        "name": "box",
        "rigid_body": {
            "mass_kg": 10.0,
            "inertia_kgm2": [[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0]],
            "cg_m": (0.1, -0.05, 0.2),
            "cb_m": (0.0, 0.0, 0.0),
            "buoyancy_N": 100.0,
            "gravity_mps2": 10.0,
        },
        "added_mass": np.diag([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]).tolist(),
        "thrusters": [
            {"name": "a", "speed_signal": "n1_rpm", "position_m": (-0.5, -0.2, 0.0), "direction": (1, 0, 0),
             "thrust": {"k_fwd_N_per_rpm2": 2e-6, "k_bwd_N_per_rpm2": 1e-6}},
            {"name": "b", "speed_signal": "n2_rpm", "position_m": (-0.5, 0.2, 0.0), "direction": (2, 0, 0),
             "thrust": {"k_fwd_N_per_rpm2": 2e-6}},
            {"name": "c", "speed_signal": "n3_rpm", "position_m": (0.3, 0.0, 0.1), "direction": (0, 1, 1),
             "thrust": {"k_fwd_N_per_rpm2": 2e-6}},
        ],
        "sensors": {"dvl": {"velocity": ["u_mps", "v_mps", "w_mps"]}, "attitude": {"yaw": "yaw_rad"}},
        "streams": {"s": {"topic": "/s", "clock": "log", "signals": {
            k: {"field": k} for k in ("n1_rpm", "n2_rpm", "n3_rpm", "u_mps", "v_mps", "w_mps", "yaw_rad")}}},
    }
    data.update(changes)
    return data


@pytest.fixture
def vehicle() -> Vehicle:
    return parse(Vehicle, vehicle_dict())


def test_rigid_body_mass_hand_computed(vehicle: Vehicle) -> None:
    m, (x, y, z) = 10.0, (0.1, -0.05, 0.2)
    expected = np.array([
        [m, 0, 0, 0, m * z, -m * y],
        [0, m, 0, -m * z, 0, m * x],
        [0, 0, m, m * y, -m * x, 0],
        [0, -m * z, m * y, 1.0 + m * (y * y + z * z), -m * x * y, -m * x * z],
        [m * z, 0, -m * x, -m * x * y, 2.0 + m * (x * x + z * z), -m * y * z],
        [-m * y, m * x, 0, -m * x * z, -m * y * z, 3.0 + m * (x * x + y * y)],
    ])
    np.testing.assert_allclose(physics.rigid_body_mass(vehicle.rigid_body), expected, atol=1e-14)
    M = physics.mass_matrix(vehicle)
    np.testing.assert_allclose(M, expected + np.diag([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]), atol=1e-14)


def test_coriolis_skew_symmetric_no_work(vehicle: Vehicle) -> None:
    M = physics.mass_matrix(vehicle)
    M[0, 5] = M[5, 0] = 0.7  # coupled added mass
    nu = np.random.default_rng(1).normal(size=(50, 6))
    C = physics.coriolis_matrix(M, nu)
    np.testing.assert_allclose(C + np.transpose(C, (0, 2, 1)), 0.0, atol=1e-12)
    force = physics.coriolis_force(M, nu)
    np.testing.assert_allclose(force, np.einsum("nij,nj->ni", C, nu), atol=1e-12)
    np.testing.assert_allclose(np.einsum("ni,ni->n", nu, force), 0.0, atol=1e-11)


def test_coriolis_known_answer_surge_sway() -> None:
    M = np.diag([2.0, 3.0, 4.0, 1.0, 1.0, 5.0])
    nu = np.array([[1.0, 0.5, 0.0, 0.0, 0.0, 0.2]])
    # horizontal plane: X = -m22 v r, Y = m11 u r, N = (m22 - m11) u v
    expected = [[-3.0 * 0.5 * 0.2, 2.0 * 1.0 * 0.2, 0.0, 0.0, 0.0, (3.0 - 2.0) * 1.0 * 0.5]]
    np.testing.assert_allclose(physics.coriolis_force(M, nu), expected, atol=1e-14)


def test_allocation_matrix_known_layout(vehicle: Vehicle) -> None:
    B = physics.allocation_matrix(vehicle)
    s = 1 / np.sqrt(2)
    expected = np.array([
        [1, 1, 0],
        [0, 0, s],
        [0, 0, s],
        [0, 0, 0 * s - 0.1 * s],          # r x d: y dz - z dy = 0 - 0.1 s
        [0, 0, -(0.3 * s - 0.0)],          # z dx - x dz
        [0.2, -0.2, 0.3 * s],              # x dy - y dx
    ])
    np.testing.assert_allclose(B, expected, atol=1e-14)
    tau = physics.generalized_forces(vehicle, np.array([[1000.0, -1000.0, 0.0]]))
    # a: +2 N forward at y=-0.2; b: k_bwd defaults to k_fwd, -2 N at y=+0.2
    np.testing.assert_allclose(tau, [[0.0, 0, 0, 0, 0, 0.2 * 2.0 + 0.2 * 2.0]], atol=1e-12)


def test_thrust_k_forward_backward(vehicle: Vehicle) -> None:
    n = np.array([-2000.0, -1000.0, 0.0, 1000.0, 3000.0])
    np.testing.assert_array_equal(physics.thrust_N(vehicle.thrusters[0], n),
                                  [-4.0, -1.0, 0.0, 2.0, 18.0])
    np.testing.assert_array_equal(physics.thrust_N(vehicle.thrusters[1], n), [-8.0, -2.0, 0.0, 2.0, 18.0])


def _table_thruster(table: str, col: str = " Force (Kg f)", unit: str = "kgf") -> dict[str, Any]:
    return {"name": "t200", "speed_signal": "n1_rpm", "position_m": (0, 0, 0), "direction": (1, 0, 0),
            "thrust": {"table": table, "table_speed_column": " RPM", "table_thrust_column": col,
                       "table_thrust_unit": unit}}


def test_thrust_table_t200_exact_points_midpoints_kgf() -> None:
    thr = parse(Vehicle, vehicle_dict(thrusters=[_table_thruster(str(shared_fixture(T200_CSV)))])).thrusters[0]
    # rows of the sheet: 1900 us -> 3533 rpm, 5.25 kgf; 1100 us -> 3465 rpm (unsigned), -4.07 kgf
    np.testing.assert_allclose(physics.thrust_N(thr, np.array([3533.0, 0.0])), [5.25 * KGF, 0.0])
    np.testing.assert_allclose(physics.thrust_N(thr, np.array([-3465.0])), [-4.07 * KGF])
    speed, thrust = physics.thrust_table(thr)
    mid = (speed[:-1] + speed[1:]) / 2
    np.testing.assert_allclose(physics.thrust_N(thr, mid), (thrust[:-1] + thrust[1:]) / 2, rtol=1e-12)
    np.testing.assert_allclose(physics.thrust_N(thr, speed), thrust, rtol=1e-12)
    assert np.all(np.diff(speed) > 0) and speed[0] < 0 < speed[-1]


def test_thrust_table_relative_path_clamps_and_warns(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    (tmp_path / "tab.csv").write_text("rpm,thrust\n-1000,-2\n0,0\n1000,1\n2000,4\n")
    thr = _table_thruster("tab.csv", col="thrust", unit="N")
    thr["thrust"]["table_speed_column"] = "rpm"
    yaml_path = tmp_path / "v.yaml"
    import yaml

    yaml_path.write_text(yaml.safe_dump(vehicle_dict(thrusters=[thr])))
    from pipeline.config import load_vehicle

    v = load_vehicle(yaml_path)
    with caplog.at_level("WARNING"):
        out = physics.thrusts(v, np.array([[500.0], [1500.0], [3000.0], [-5000.0]]))
    np.testing.assert_allclose(out[:, 0], [0.5, 2.5, 4.0, -2.0])
    assert "outside the thrust table" in caplog.text


def test_restoring_force_known_angles(vehicle: Vehicle) -> None:
    W, B = 100.0, 100.0  # neutral: only moments from CG below CB
    zg, xg, yg = 0.2, 0.1, -0.05
    g0 = physics.restoring_force(vehicle, np.array([0.0]), np.array([0.0]))
    np.testing.assert_allclose(g0, [[0, 0, 0, -yg * W, xg * W, 0]], atol=1e-12)
    g = physics.restoring_force(vehicle, np.array([np.pi / 2]), np.array([0.0]))
    np.testing.assert_allclose(g, [[0, 0, 0, zg * W, 0, -xg * W]], atol=1e-12)
    heavy = parse(Vehicle, vehicle_dict(rigid_body={**vehicle_dict()["rigid_body"], "buoyancy_N": 90.0,
                                                    "cg_m": (0, 0, 0)}))
    g = physics.restoring_force(heavy, np.array([0.0]), np.array([np.pi / 6]))
    np.testing.assert_allclose(g, [[10.0 * 0.5, 0, -10.0 * np.cos(np.pi / 6), 0, 0, 0]], atol=1e-12)
    assert B == W


def test_damping_target_identity(vehicle: Vehicle) -> None:
    rng = np.random.default_rng(3)
    M = physics.mass_matrix(vehicle)
    nu, nudot, d = rng.normal(size=(3, 20, 6))
    g = physics.restoring_force(vehicle, rng.normal(size=20) * 0.1, rng.normal(size=20) * 0.1)
    tau = nudot @ M.T + physics.coriolis_force(M, nu) + d + g
    np.testing.assert_allclose(physics.damping_target(M, tau, nudot, nu, g), d, atol=1e-12)


def test_non_positive_definite_mass_names_key() -> None:
    bad = np.diag([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    bad[5, 5] = -50.0
    with pytest.raises(ConfigError, match="added_mass") as info:  # refused at load since issue 17
        physics.mass_matrix(parse(Vehicle, vehicle_dict(added_mass=bad.tolist())))
    assert info.value.field == "added_mass"
    asym = np.diag([1.0, 2.0, 3.0, 0.1, 0.2, 0.3])
    asym[0, 1] = 0.5
    with pytest.raises(ConfigError, match="symmetric"):
        physics.mass_matrix(parse(Vehicle, vehicle_dict(added_mass=asym.tolist())))
    rb = {**vehicle_dict()["rigid_body"], "inertia_kgm2": [[1, 0, 0], [0, -1, 0], [0, 0, 1]]}
    with pytest.raises(ConfigError) as info:
        physics.mass_matrix(parse(Vehicle, vehicle_dict(rigid_body=rb)))
    assert info.value.field == "rigid_body.inertia_kgm2"


def test_zero_direction_names_thruster() -> None:
    data = vehicle_dict()
    data["thrusters"][2]["direction"] = (0, 0, 0)
    with pytest.raises(ConfigError) as info:
        physics.allocation_matrix(parse(Vehicle, data))
    assert info.value.field == "thrusters.2.direction"
    assert "'c'" in str(info.value)
