"""A small vehicle config and signal builders shared by the sync / kinematics / derive / store tests."""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from pipeline.config import Vehicle, parse

PERIOD_NS = 50_000_000  # 20 Hz


def vehicle_dict(**sensors: Any) -> dict[str, Any]:
    def sig(*names: str) -> dict[str, Any]:
        return {n: {"field": n} for n in names}

    base_sensors: dict[str, Any] = {
        "dvl": {"velocity": ["u_dvl_mps", "v_dvl_mps", "w_dvl_mps"], "valid": "dvl_lock_flag"},
        "attitude": {"quaternion": "ahrs_quat"},
        "rates": {"p": "p_gyro_radps", "q": "q_gyro_radps", "r": "r_fog_radps"},
        "depth": "depth_m",
    }
    base_sensors.update(sensors)
    return {
        "name": "testbot",
        "rigid_body": {"mass_kg": 30.0, "inertia_kgm2": [[1.0, 0, 0], [0, 2.0, 0], [0, 0, 2.5]],
                       "cg_m": [0.0, 0.0, 0.02], "cb_m": [0.0, 0.0, 0.0]},
        "added_mass": np.diag([5.0, 20.0, 20.0, 0.5, 1.0, 1.5]).tolist(),
        "thrusters": [
            {"name": "left", "speed_signal": "n1_rpm", "position_m": [-0.4, -0.2, 0.0], "direction": [1, 0, 0],
             "thrust": {"k_fwd_N_per_rpm2": 2e-5, "k_bwd_N_per_rpm2": 1e-5}},
            {"name": "right", "speed_signal": "n2_rpm", "position_m": [-0.4, 0.2, 0.0], "direction": [1, 0, 0],
             "thrust": {"k_fwd_N_per_rpm2": 2e-5, "k_bwd_N_per_rpm2": 1e-5}},
            {"name": "lateral", "speed_signal": "n3_rpm", "position_m": [0.3, 0.0, 0.0], "direction": [0, 1, 0],
             "thrust": {"k_fwd_N_per_rpm2": 1e-5}},
        ],
        "sensors": base_sensors,
        "streams": {
            "dvl": {"topic": "/dvl", "clock": "header",
                    "signals": sig("u_dvl_mps", "v_dvl_mps", "w_dvl_mps", "dvl_lock_flag")},
            "ahrs": {"topic": "/ahrs", "clock": "header", "signals": sig("ahrs_quat")},
            "gyro": {"topic": "/gyro", "clock": "header", "signals": sig("p_gyro_radps", "q_gyro_radps")},
            "fog": {"topic": "/fog", "clock": "header", "signals": sig("r_fog_radps")},
            "thrusters": {"topic": "/thr", "clock": "header", "signals": sig("n1_rpm", "n2_rpm", "n3_rpm")},
            "depth": {"topic": "/depth", "clock": "header", "signals": sig("depth_m")},
        },
    }


def make_vehicle(**sensors: Any) -> Vehicle:
    return parse(Vehicle, vehicle_dict(**sensors))


def stream(t_ns: np.ndarray, **columns: np.ndarray) -> pd.DataFrame:
    frame = pd.DataFrame({"t_ns": np.asarray(t_ns, dtype=np.int64)})
    for name, values in columns.items():
        frame[name] = np.asarray(values, dtype=np.float64)
    return frame


def constant_streams(duration_s: float = 20.0, t0_ns: int = 1_700_000_000_000_000_000) -> dict[str, pd.DataFrame]:
    """Streams at different native rates, all constant and valid, starting at t0_ns (a grid multiple)."""
    def times(rate_hz: float) -> np.ndarray:
        return t0_ns + np.arange(int(duration_s * rate_hz) + 1, dtype=np.int64) * int(1e9 / rate_hz)

    td, ta, tg, tt = times(5), times(50), times(100), times(10)
    return {
        "dvl": stream(td, u_dvl_mps=np.full(len(td), 0.5), v_dvl_mps=np.zeros(len(td)) + 0.1,
                      w_dvl_mps=np.full(len(td), 0.0), dvl_lock_flag=np.ones(len(td))),
        "ahrs": stream(ta, ahrs_quat_w=np.ones(len(ta)), ahrs_quat_x=np.zeros(len(ta)),
                       ahrs_quat_y=np.zeros(len(ta)), ahrs_quat_z=np.zeros(len(ta))),
        "gyro": stream(tg, p_gyro_radps=np.zeros(len(tg)), q_gyro_radps=np.zeros(len(tg))),
        "fog": stream(tg, r_fog_radps=np.zeros(len(tg))),
        "thrusters": stream(tt, n1_rpm=np.full(len(tt), 1000.0), n2_rpm=np.full(len(tt), 1000.0),
                            n3_rpm=np.zeros(len(tt))),
        "depth": stream(tt, depth_m=np.full(len(tt), 2.0)),
    }
