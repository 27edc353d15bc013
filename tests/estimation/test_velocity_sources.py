"""Velocity sources beyond the DVL: body-frame velocities, earth-frame velocities rotated by the logged heading or
attitude, and planar (3-DOF) vehicles with no heave, roll, pitch or depth data.

The known answer: a vehicle turning from heading 0 to 90 deg with asymmetric body velocities (u != v, both varying);
its earth-frame rates are computed from them, so the recovered u, v must equal the body velocities (exactly on the
grid; within the noise through the smoother and the filters). A rotation applied the wrong way (transposed) gives
u and v errors of the order of v sin(psi), far outside the tolerances.
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
from pipeline.kinematics import body_kinematics, rpy_matrix
from pipeline.sync import required_signals, synchronize

T0_NS = 1_700_000_000_000_000_000
DURATION_S = 40.0


def ship_dict(velocity: dict[str, Any] | None = None, **sensors: Any) -> dict[str, Any]:
    """A planar ship: one propeller, earth-frame x/y rates, heading and yaw rate only (no w, roll, pitch, depth)."""
    sig = lambda *names: {n: {"field": n} for n in names}  # noqa: E731
    base = {"velocity": velocity or {"frame": "earth", "signals": ["xdot_mps", "ydot_mps"]},
            "attitude": {"yaw": "yaw_rad"}, "rates": {"r": "r_radps"}}
    base.update(sensors)
    return {
        "name": "ship",
        "rigid_body": {"mass_kg": 100.0, "inertia_kgm2": [[10.0, 0, 0], [0, 40.0, 0], [0, 0, 40.0]]},
        "added_mass": np.diag([10.0, 80.0, 80.0, 1.0, 5.0, 20.0]).tolist(),
        "thrusters": [{"name": "prop", "speed_signal": "n1_rpm", "position_m": [-1.0, 0.0, 0.0],
                       "direction": [1, 0, 0], "thrust": {"k_fwd_N_per_rpm2": 1e-4}}],
        "sensors": base,
        "streams": {"tank": {"topic": "/tank", "clock": "header",
                             "signals": sig("xdot_mps", "ydot_mps", "zdot_mps", "yaw_rad", "r_radps", "n1_rpm")}},
    }


def ship(velocity: dict[str, Any] | None = None, **sensors: Any) -> Vehicle:
    return parse(Vehicle, ship_dict(velocity, **sensors))


def turning(t_s: np.ndarray) -> dict[str, np.ndarray]:
    """Body velocities and heading of a vehicle turning from 0 to 90 deg; u and v differ and vary."""
    w = np.pi / DURATION_S
    psi = np.pi / 4 * (1 - np.cos(w * t_s))
    return {"u": 1.0 + 0.3 * np.sin(0.3 * t_s), "v": 0.25 + 0.1 * np.cos(0.5 * t_s), "psi": psi,
            "r": np.pi / 4 * w * np.sin(w * t_s),
            "udot": 0.09 * np.cos(0.3 * t_s), "vdot": -0.05 * np.sin(0.5 * t_s)}


def earth_rates(k: dict[str, np.ndarray], lever: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """NED x/y rates of the point at ``lever`` (body axes) of the turning vehicle."""
    lever = np.zeros(3) if lever is None else lever
    v_body = np.column_stack([k["u"], k["v"], np.zeros_like(k["u"])])
    v_body = v_body + np.cross(np.column_stack([0 * k["r"], 0 * k["r"], k["r"]]), lever)
    c, s = np.cos(k["psi"]), np.sin(k["psi"])
    return c * v_body[:, 0] - s * v_body[:, 1], s * v_body[:, 0] + c * v_body[:, 1]


def synced_grid(n: int = 200, lever: np.ndarray | None = None) -> tuple[pd.DataFrame, dict[str, np.ndarray]]:
    t = np.arange(n) * 0.2
    k = turning(t)
    xdot, ydot = earth_rates(k, lever)
    frame = pd.DataFrame({"t_ns": (t * 1e9).astype(np.int64), "segment": np.zeros(n, np.int32), "xdot_mps": xdot,
                          "ydot_mps": ydot, "yaw_rad": k["psi"], "r_radps": k["r"], "n1_rpm": 600.0})
    return frame, k


def test_earth_frame_rates_are_rotated_by_the_heading_into_body_u_v() -> None:
    lever = np.array([0.8, -0.3, 0.0])  # the tracked point sits ahead of and to port of the reference point
    frame, k = synced_grid(lever=lever)
    assert k["psi"][-1] > np.deg2rad(80) and np.abs(k["v"]).min() > 0.1  # a real turn, a real sway velocity
    kin = body_kinematics(frame, ship({"frame": "earth", "signals": ["xdot_mps", "ydot_mps"],
                                       "position_m": lever.tolist()}))
    np.testing.assert_allclose(kin["u_mps"], k["u"], atol=1e-12)
    np.testing.assert_allclose(kin["v_mps"], k["v"], atol=1e-12)
    assert (kin["w_mps"] == 0).all() and (kin["p_radps"] == 0).all() and (kin["q_radps"] == 0).all()
    assert (kin["roll_rad"] == 0).all() and "depth_m" not in kin.columns  # planar: none of it configured
    # the rotation applied the wrong way round (R instead of R^T) is far off: the check above can tell
    c, s = np.cos(k["psi"]), np.sin(k["psi"])
    xdot, ydot = frame["xdot_mps"].to_numpy(), frame["ydot_mps"].to_numpy()
    assert np.abs(c * xdot - s * ydot - k["u"]).max() > 0.3


def test_enu_axes_and_a_three_component_earth_velocity_with_roll_and_pitch() -> None:
    frame, k = synced_grid()
    xdot, ydot = frame.pop("xdot_mps").to_numpy(), frame.pop("ydot_mps").to_numpy()
    frame["xdot_mps"], frame["ydot_mps"] = ydot, xdot  # ENU: x east, y north
    kin = body_kinematics(frame, ship({"frame": "earth", "signals": ["xdot_mps", "ydot_mps"], "earth_axes": "enu"}))
    np.testing.assert_allclose(kin[["u_mps", "v_mps"]].to_numpy(), np.column_stack([k["u"], k["v"]]), atol=1e-12)

    # 3 components and a rolling, pitching vehicle: v_ned = R_nb(roll, pitch, yaw) v_body
    n = len(frame)
    rng = np.random.default_rng(5)
    roll, pitch = rng.uniform(-0.4, 0.4, n), rng.uniform(-0.3, 0.3, n)
    v_body = np.column_stack([k["u"], k["v"], rng.normal(0, 0.1, n)])
    v_ned = np.einsum("nij,nj->ni", rpy_matrix(roll, pitch, k["psi"]), v_body)
    frame = frame.assign(xdot_mps=v_ned[:, 0], ydot_mps=v_ned[:, 1], zdot_mps=v_ned[:, 2], roll_rad=roll,
                         pitch_rad=pitch)
    data = ship_dict({"frame": "earth", "signals": ["xdot_mps", "ydot_mps", "zdot_mps"]},
                     attitude={"roll": "roll_rad", "pitch": "pitch_rad", "yaw": "yaw_rad"})
    data["streams"]["tank"]["signals"].update({"roll_rad": {"field": "roll"}, "pitch_rad": {"field": "pitch"}})
    kin = body_kinematics(frame, parse(Vehicle, data))
    np.testing.assert_allclose(kin[["u_mps", "v_mps", "w_mps"]].to_numpy(), v_body, atol=1e-12)


def test_body_frame_velocities_are_taken_as_they_are_with_the_lever_arm() -> None:
    frame, k = synced_grid()
    lever = np.array([0.5, 0.2, 0.0])
    frame["xdot_mps"] = k["u"] - k["r"] * lever[1]  # u, v of the tracked point: v_ref + omega x r
    frame["ydot_mps"] = k["v"] + k["r"] * lever[0]
    kin = body_kinematics(frame, ship({"frame": "body", "signals": ["xdot_mps", "ydot_mps"],
                                       "position_m": lever.tolist()}))
    np.testing.assert_allclose(kin[["u_mps", "v_mps"]].to_numpy(), np.column_stack([k["u"], k["v"]]), atol=1e-12)


def native_streams(seed: int = 0, noise_mps: float = 0.01) -> tuple[dict[str, pd.DataFrame], dict]:
    """A tank stream at 20 Hz (x/y rates with noise, heading, yaw rate) and the propeller at 10 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(DURATION_S * 20) + 1) / 20.0
    k = turning(t)
    xdot, ydot = earth_rates(k)
    tank = pd.DataFrame({"t_ns": T0_NS + (t * 1e9).astype(np.int64),
                         "xdot_mps": xdot + noise_mps * rng.standard_normal(t.size),
                         "ydot_mps": ydot + noise_mps * rng.standard_normal(t.size),
                         "yaw_rad": k["psi"], "r_radps": k["r"] + 1e-4 * rng.standard_normal(t.size),
                         "n1_rpm": 600.0})
    return {"tank": tank}, k


@pytest.mark.parametrize("method", ["kalman", "gaussian"])
def test_earth_frame_rates_through_sync_and_differentiate_recover_u_v_and_their_rates(method: str) -> None:
    vehicle = ship()
    assert required_signals(vehicle) == ["xdot_mps", "ydot_mps", "yaw_rad", "r_radps", "n1_rpm"]
    streams, _ = native_streams()
    synced = synchronize(streams, vehicle, SyncParams())
    params = DifferentiateParams(method=method)
    kin, report = differentiate(synced, vehicle, params, streams)
    t = (kin["t_ns"].to_numpy() - T0_NS) / 1e9
    truth = turning(t)
    assert t.max() - t.min() > 0.8 * DURATION_S
    for col, key, tol in (("u_smooth_mps", "u", 0.006), ("v_smooth_mps", "v", 0.006),
                          ("udot_mps2", "udot", 0.02), ("vdot_mps2", "vdot", 0.02)):
        rms = float(np.sqrt(np.mean((kin[col].to_numpy() - truth[key]) ** 2)))
        assert rms < tol, (col, rms)
    assert (kin["w_mps"] == 0).all() and (kin["wdot_mps2"] == 0).all()  # planar: w not measured, not invented
    # each earth axis' noise is estimated on its own signal (0.01 m/s)
    assert report["noise"]["xdot_mps"]["sd"] == pytest.approx(0.01, rel=0.25)
    if method == "kalman":
        assert set(report["dofs"]) == {"u", "v", "r"}


def test_a_velocity_source_is_required_once_and_named() -> None:
    data = ship_dict()
    data["sensors"]["dvl"] = {"velocity": ["xdot_mps", "ydot_mps", "zdot_mps"]}
    with pytest.raises(ConfigError, match="exactly one velocity source"):
        parse(Vehicle, data)
    data = ship_dict()
    del data["sensors"]["velocity"]
    with pytest.raises(ConfigError, match="exactly one velocity source"):
        parse(Vehicle, data)
    with pytest.raises(ConfigError, match="sensors.velocity.signals"):
        ship({"frame": "earth", "signals": ["xdot_mps"]})
    with pytest.raises(ConfigError, match="sensors.velocity.signals.*'surge_mps'.*not a configured signal"):
        ship({"frame": "body", "signals": ["surge_mps", "ydot_mps"]})


def clean_dvl_trial() -> tuple[Vehicle, dict[str, pd.DataFrame]]:
    """A noise-free 4-Hz DVL losing lock 10 s of every minute (the ingest benchmark's), body-frame: u = cos(t/10),
    v = 0.05 and w = 0 exactly; heading and yaw rate at 20 Hz. Known accelerations: -sin(t/10)/10, 0, 0."""
    data = ship_dict({"frame": "body", "signals": ["u_dvl_mps", "v_dvl_mps", "w_dvl_mps"]})
    dvl_signals = ("u_dvl_mps", "v_dvl_mps", "w_dvl_mps")
    data["streams"] = {
        "dvl": {"topic": "/dvl", "clock": "header", "signals": {n: {"field": n} for n in dvl_signals}},
        "nav": {"topic": "/nav", "clock": "header", "signals": {n: {"field": n} for n in ("yaw_rad", "r_radps",
                                                                                         "n1_rpm")}}}
    td = np.arange(0.0, 180.0, 0.25)
    td = td[(td % 60) >= 10]
    tn = np.arange(0.0, 180.0, 0.05)
    streams = {"dvl": pd.DataFrame({"t_ns": T0_NS + (td * 1e9).astype(np.int64), "u_dvl_mps": np.cos(td / 10),
                                    "v_dvl_mps": 0.05, "w_dvl_mps": 0.0}),
               "nav": pd.DataFrame({"t_ns": T0_NS + (tn * 1e9).astype(np.int64), "yaw_rad": 0.3 * np.sin(tn / 20),
                                    "r_radps": 0.015 * np.cos(tn / 20), "n1_rpm": 600.0})}
    return parse(Vehicle, data), streams


def truth_of(t_s: np.ndarray) -> dict[str, np.ndarray]:
    return {"u_mps": np.cos(t_s / 10), "udot_mps2": -np.sin(t_s / 10) / 10, "v_mps": 0.05 + 0 * t_s,
            "vdot_mps2": 0 * t_s, "rdot_radps2": -0.015 / 20 * np.sin(t_s / 20)}


@pytest.mark.parametrize(("method", "tol_mps", "tol_mps2"), [("kalman", 1e-4, 1e-4), ("gaussian", 1e-3, 1e-3)])
def test_a_noise_free_velocity_source_gives_the_true_accelerations(method: str, tol_mps: float, tol_mps2: float,
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    """Its noise estimates (0 for w, float rounding for v) are floored instead of ending the stage ('cannot
    estimate the noise', or a smoother 'not positive definite' / nonsense derivatives from a 1e-36 variance)."""
    from pipeline.estimation.noise import NOISE_FLOOR

    vehicle, streams = clean_dvl_trial()
    synced = synchronize(streams, vehicle, SyncParams())
    kin, report = differentiate(synced, vehicle, DifferentiateParams(method=method), streams)
    for name in ("v_dvl_mps", "w_dvl_mps"):
        assert report["noise"][name] == {"sd": NOISE_FLOOR, "outlier_rate": 0.0, "samples": 588, "source": "floor"}
        assert f"signal {name!r} looks noise-free" in caplog.text
    assert report["noise"]["u_dvl_mps"]["source"] == "estimated"
    t = (kin["t_ns"].to_numpy() - T0_NS) / 1e9
    assert t.max() - t.min() > 150  # the lock losses bridged (kalman) or cut (gaussian), not the whole trial
    truth = truth_of(t)
    for col in ("u_mps", "v_mps"):
        assert np.abs(kin[col].to_numpy() - truth[col]).max() < tol_mps, col
    for col in ("udot_mps2", "vdot_mps2", "rdot_radps2"):
        assert np.abs(kin[col].to_numpy() - truth[col]).max() < tol_mps2, col
