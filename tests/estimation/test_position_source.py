"""Positions to be differentiated (``sensors.position``: motion capture, GNSS in a local earth frame).

The known answer: a vehicle on a circle with sideslip. Its course turns at a constant rate r and its heading lags
the course by the sideslip beta, so in body axes u = V cos(beta) and v = V sin(beta) are constant and u', v' are 0,
while the earth-frame velocity and acceleration rotate all the time: the rotation into body axes and the
-omega x v term of the body acceleration must both be right. Positions at 20 Hz, 13 ms off the grid.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd
import pytest

from pipeline.config import Vehicle, parse
from pipeline.config.params import DifferentiateParams, SyncParams
from pipeline.errors import ConfigError
from pipeline.estimation.differentiate import differentiate
from pipeline.sync import required_signals, synchronize

T0_NS = 1_700_000_000_000_000_000
DURATION_S = 40.0
SPEED_MPS, BETA_RAD, RATE_RADPS = 1.2, 0.3, 0.2
LEVER_M = (0.6, -0.2, 0.0)  # the marker set sits ahead of and to port of the reference point


def vehicle_dict(position: dict[str, Any] | None = None) -> dict[str, Any]:
    sig = lambda *names: {n: {"field": n} for n in names}  # noqa: E731
    return {
        "name": "mocap_boat",
        "rigid_body": {"mass_kg": 30.0, "inertia_kgm2": [[1.0, 0, 0], [0, 4.0, 0], [0, 0, 4.0]]},
        "added_mass": np.diag([3.0, 20.0, 20.0, 0.1, 0.5, 2.0]).tolist(),
        "thrusters": [{"name": "prop", "speed_signal": "n1_rpm", "position_m": [-0.5, 0.0, 0.0],
                       "direction": [1, 0, 0], "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
        "sensors": {"position": position or {"signals": ["x_m", "y_m"], "position_m": list(LEVER_M)},
                    "attitude": {"yaw": "yaw_rad"}, "rates": {"r": "r_radps"}},
        "streams": {"mocap": {"topic": "/mocap", "clock": "header", "signals": sig("x_m", "y_m", "yaw_rad")},
                    "boat": {"topic": "/boat", "clock": "header", "signals": sig("r_radps", "n1_rpm")}},
    }


def circle(t_s: np.ndarray, enu: bool = False) -> dict[str, np.ndarray]:
    """NED positions of the tracked point (at LEVER_M) and the heading of a vehicle on a circle with sideslip."""
    course = 0.4 + RATE_RADPS * t_s
    psi = course - BETA_RAD
    radius = SPEED_MPS / RATE_RADPS
    x_ref, y_ref = 3.0 + radius * np.sin(course), -2.0 - radius * np.cos(course)  # velocity V (cos, sin) course
    c, s = np.cos(psi), np.sin(psi)
    x, y = x_ref + c * LEVER_M[0] - s * LEVER_M[1], y_ref + s * LEVER_M[0] + c * LEVER_M[1]
    if enu:
        x, y = y, x
    return {"x": x, "y": y, "psi": psi}


def streams(seed: int = 0, noise_m: float = 0.0, enu: bool = False) -> dict[str, pd.DataFrame]:
    rng = np.random.default_rng(seed)
    t = np.arange(int(DURATION_S * 20) + 1) / 20.0 + 0.013
    k = circle(t, enu)
    mocap = pd.DataFrame({"t_ns": T0_NS + np.round(t * 1e9).astype(np.int64),
                          "x_m": k["x"] + noise_m * rng.standard_normal(t.size),
                          "y_m": k["y"] + noise_m * rng.standard_normal(t.size), "yaw_rad": k["psi"]})
    tb = np.arange(int(DURATION_S * 50) + 1) / 50.0
    boat = pd.DataFrame({"t_ns": T0_NS + np.round(tb * 1e9).astype(np.int64),
                         "r_radps": RATE_RADPS + 1e-4 * rng.standard_normal(tb.size), "n1_rpm": 600.0})
    return {"mocap": mocap, "boat": boat}


def run(vehicle: Vehicle, native: dict[str, pd.DataFrame], **params: Any) -> tuple[pd.DataFrame, dict]:
    synced = synchronize(native, vehicle, SyncParams())
    return differentiate(synced, vehicle, DifferentiateParams(**params), native)


def middle(kin: pd.DataFrame, margin_s: float = 3.0) -> pd.DataFrame:
    t = (kin["t_ns"].to_numpy() - T0_NS) / 1e9
    return kin[(t > margin_s) & (t < DURATION_S - margin_s)]


def test_noise_free_positions_on_a_circle_give_the_body_velocities_exactly() -> None:
    vehicle = parse(Vehicle, vehicle_dict())
    assert required_signals(vehicle) == ["x_m", "y_m", "yaw_rad", "r_radps", "n1_rpm"]
    kin, report = run(vehicle, streams(), noise_sd={"x_m": 1e-5, "y_m": 1e-5})
    mid = middle(kin)
    assert len(mid) > 0.8 * DURATION_S * 20
    np.testing.assert_allclose(mid["u_mps"], SPEED_MPS * np.cos(BETA_RAD), atol=5e-5)
    np.testing.assert_allclose(mid["v_mps"], SPEED_MPS * np.sin(BETA_RAD), atol=5e-5)
    np.testing.assert_allclose(mid[["udot_mps2", "vdot_mps2"]], 0.0, atol=1e-4)  # 1e-5 here
    assert (kin["w_mps"] == 0).all()  # planar: not measured
    assert set(report["dofs"]) == {"u", "v", "r"}
    assert report["dofs"]["u"]["process_noise_source"].startswith("sensors.position")


@pytest.mark.parametrize("enu", [False, True])
def test_noisy_positions_give_u_v_within_the_noise_and_honest_sds(enu: bool) -> None:
    position = {"signals": ["x_m", "y_m"], "position_m": list(LEVER_M), "earth_axes": "enu" if enu else "ned"}
    kin, report = run(parse(Vehicle, vehicle_dict(position)), streams(seed=3, noise_m=0.005, enu=enu))
    mid = middle(kin)
    assert report["noise"]["x_m"]["sd"] == pytest.approx(0.005, rel=0.3)
    for col, truth, tol in (("u_mps", SPEED_MPS * np.cos(BETA_RAD), 0.01), ("v_mps", SPEED_MPS * np.sin(BETA_RAD),
                                                                             0.01),
                            ("udot_mps2", 0.0, 0.05), ("vdot_mps2", 0.0, 0.05)):
        err = mid[col].to_numpy() - truth
        assert float(np.sqrt(np.mean(err**2))) < tol, (col, err)
    # the SDs say how sure: the errors are of their size, neither far larger nor far smaller
    z = (mid["u_mps"].to_numpy() - SPEED_MPS * np.cos(BETA_RAD)) / mid["u_smooth_std_mps"].to_numpy()
    assert 0.3 < float(np.sqrt(np.mean(z**2))) < 3.0


def test_the_gaussian_method_filters_the_differentiated_positions() -> None:
    kin, _ = run(parse(Vehicle, vehicle_dict()), streams(seed=1, noise_m=0.005), method="gaussian", sigma_s=0.5)
    mid = middle(kin)
    assert float(np.sqrt(np.mean((mid["v_smooth_mps"] - SPEED_MPS * np.sin(BETA_RAD)) ** 2))) < 0.01
    assert float(np.sqrt(np.mean(mid["udot_mps2"] ** 2))) < 0.05


def test_one_velocity_source_and_known_position_signals() -> None:
    data = vehicle_dict()
    data["sensors"]["velocity"] = {"frame": "earth", "signals": ["x_m", "y_m"]}
    with pytest.raises(ConfigError, match="exactly one velocity source"):
        parse(Vehicle, data)
    with pytest.raises(ConfigError, match="sensors.position.signals.*'east_m'.*not a configured signal"):
        parse(Vehicle, vehicle_dict({"signals": ["x_m", "east_m"]}))
