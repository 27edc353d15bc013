"""A rudder's lift model (``control_surfaces[].lift``, pipeline.physics.surface_forces): L = 1/2 rho A C_La alpha
U_R^2 with the cross-flow's inflow angle and the propeller's slipstream, added to tau by the derive stage. Known
answers by hand: a rudder 1 m aft, 0.02 m^2, lift slope 2.5 / rad, in fresh water."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from pipeline import physics
from pipeline.config import Vehicle, parse
from pipeline.derive import derive
from pipeline.errors import ConfigError
from tests.physics.test_actuators import rudder_ship

RHO, AREA, SLOPE, X_R = 1000.0, 0.02, 2.5, -1.0
Q = 0.5 * RHO * AREA * SLOPE  # 25 N per rad per (m/s)^2


def lifting(**lift: Any) -> Vehicle:
    data = rudder_ship()
    data["control_surfaces"][0]["lift"] = {"area_m2": AREA, "lift_slope_per_rad": SLOPE,
                                           "position_m": [X_R, 0.0, -0.2], "density_kg_m3": RHO, **lift}
    return parse(Vehicle, data)


def _nu(u: float = 0.0, v: float = 0.0, r: float = 0.0) -> np.ndarray:
    return np.array([[u, v, 0.0, 0.0, 0.0, r]])


def test_lift_from_angle_and_inflow_speed_with_its_moments() -> None:
    vehicle = lifting()
    tau = physics.surface_forces(vehicle, _nu(u=1.2), np.array([[0.1]]), np.array([[0.0]]))[0]
    lift = Q * 0.1 * 1.2**2
    # along y at (-1, 0, -0.2): roll moment -z L, yaw moment x L
    np.testing.assert_allclose(tau, [0.0, lift, 0.0, 0.2 * lift, 0.0, X_R * lift], rtol=1e-12)
    # the cross-flow at the rudder (v + r x) turns the inflow: a rudder at that angle carries no lift
    u, v, r = 1.0, 0.05, 0.1
    angle = np.arctan2(v + r * X_R, u)
    assert physics.surface_forces(vehicle, _nu(u, v, r), np.array([[angle]]), np.array([[0.0]]))[0, 1] == (
        pytest.approx(0.0, abs=1e-12))
    # at zero angle the rudder (like a skeg) pushes against the cross-flow at the stern, v + r x (here to port)
    got = physics.surface_forces(vehicle, _nu(u, v, r), np.array([[0.0]]), np.array([[0.0]]))[0, 1]
    assert got == pytest.approx(-Q * u**2 * np.arctan2(v + r * X_R, u), rel=1e-12)
    assert v + r * X_R < 0 < got


def test_the_slipstream_of_the_propeller_ahead_adds_to_the_inflow() -> None:
    vehicle = lifting(behind="prop", slipstream_diameter_m=0.1)
    thrust = 20.0
    extra = 8 * thrust / (RHO * np.pi * 0.1**2)  # far-wake slipstream, momentum theory
    got = physics.surface_forces(vehicle, _nu(u=0.8), np.array([[0.1]]), np.array([[thrust]]))[0, 1]
    assert got == pytest.approx(Q * 0.1 * (0.8**2 + extra), rel=1e-12)
    at_rest = physics.surface_forces(vehicle, _nu(), np.array([[0.1]]), np.array([[thrust]]))[0, 1]
    assert at_rest == pytest.approx(Q * 0.1 * extra, rel=1e-12)  # bollard pull: the slipstream alone
    backing = physics.surface_forces(vehicle, _nu(u=0.8), np.array([[0.1]]), np.array([[-thrust]]))[0, 1]
    assert backing == pytest.approx(Q * 0.1 * 0.8**2, rel=1e-12)  # a reversed propeller blows nothing aft


def test_derive_adds_the_rudders_force_to_tau_and_none_without_a_lift_model() -> None:
    n = 5
    kin = {c: np.zeros(n) for c in ("u_smooth_mps", "v_smooth_mps", "w_smooth_mps", "p_smooth_radps",
                                    "q_smooth_radps", "r_smooth_radps", "udot_mps2", "vdot_mps2", "wdot_mps2",
                                    "pdot_radps2", "qdot_radps2", "rdot_radps2", "roll_rad", "pitch_rad")}
    kin.update(u_smooth_mps=np.linspace(0.5, 1.0, n), v_smooth_mps=np.full(n, 0.02), r_smooth_radps=np.full(n, 0.05),
               rudder_rad=np.linspace(-0.3, 0.3, n), n1_rpm=np.full(n, 600.0), t_ns=np.arange(n) * 50_000_000)
    import pandas as pd

    frame = pd.DataFrame(kin)
    vehicle = lifting(behind="prop", slipstream_diameter_m=0.1)
    derived = derive(frame, vehicle)
    nu = frame[["u_smooth_mps", "v_smooth_mps", "w_smooth_mps", "p_smooth_radps", "q_smooth_radps",
                "r_smooth_radps"]].to_numpy()
    thrust = 1e-4 * 600.0**2
    expected = physics.surface_forces(vehicle, nu, frame[["rudder_rad"]].to_numpy(), np.full((n, 1), thrust))
    np.testing.assert_allclose(derived["tau_u_N"], thrust + expected[:, 0], rtol=1e-12)
    np.testing.assert_allclose(derived["tau_v_N"], expected[:, 1], rtol=1e-12)
    np.testing.assert_allclose(derived["tau_r_Nm"], expected[:, 5], rtol=1e-12)
    assert np.all(np.abs(derived["tau_v_N"]) > 0.1)
    # the damping target no longer carries the rudder: d_v = tau_v - M nu_dot - C nu, here with nu_dot = 0
    plain = derive(frame, parse(Vehicle, rudder_ship()))
    assert (plain["tau_v_N"] == 0).all()
    np.testing.assert_allclose(derived["d_v_N"] - plain["d_v_N"], expected[:, 1], rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize(("lift", "message"), [
    ({"behind": "bow"}, r"control_surfaces\.0\.lift.*behind and slipstream_diameter_m go together"),
    ({"behind": "bow", "slipstream_diameter_m": 0.1}, r"lift.behind 'bow' is not a thruster; thrusters: \['prop'\]"),
    ({"area_m2": 0.0}, r"control_surfaces\.0\.lift\.area_m2"),
])
def test_a_lift_model_that_cannot_be_built_is_refused_naming_the_key(lift: dict, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        lifting(**lift)
