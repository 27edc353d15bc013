from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from scipy.spatial.transform import Rotation

from pipeline.config.params import DifferentiateParams
from pipeline.errors import SchemaError, SyncError
from pipeline.estimation.gaussian import gaussian_derivative
from pipeline.estimation.grid import filter_segments
from pipeline.kinematics import attitude_from_quaternion, body_kinematics, rpy_matrix
from pipeline.vocabulary import ACCELERATION, SMOOTH, VELOCITY
from tests.sync.helpers import PERIOD_NS, make_vehicle

DT = PERIOD_NS / 1e9


def _table(t_s: np.ndarray, segment: np.ndarray, nu: np.ndarray) -> pd.DataFrame:
    frame = pd.DataFrame({"t_ns": np.round(t_s * 1e9).astype(np.int64), "segment": segment.astype(np.int32)})
    for j, name in enumerate(VELOCITY):
        frame[name] = nu[:, j]
    frame["n1_rpm"] = np.arange(len(t_s), dtype=float)
    return frame


def test_gaussian_derivative_is_exact_for_a_quadratic_in_the_interior() -> None:
    t = np.arange(400) * DT
    x = 0.3 - 1.7 * t + 0.45 * t**2
    d = gaussian_derivative(x, DT, 0.25, truncate=3.0)
    inner = slice(15, -15)  # radius = 3 sigma = 15 samples
    # exact up to float rounding: |x| < 80, kernel sum of ~31 terms -> ~1e-12
    assert d[inner] == pytest.approx(-1.7 + 0.9 * t[inner], abs=1e-11)
    # scipy's raw kernel (no moment correction) would be ~3 % low at 3 sigma: the correction matters
    assert abs(d[100] - (-1.7 + 0.9 * t[100])) < 1e-11


def test_gaussian_derivative_divides_by_dt() -> None:
    for dt in (0.01, 0.05, 0.2):
        t = np.arange(400) * dt
        assert gaussian_derivative(2.0 * t, dt, 0.25)[200] == pytest.approx(2.0, rel=1e-12)


def test_differentiate_drops_edge_samples_per_segment_and_never_spans_gaps() -> None:
    n = 200
    t = np.arange(n) * DT
    seg = np.full(n, -1)
    seg[10:90] = 0
    seg[100:200] = 1
    nu = np.zeros((n, 6))
    nu[:, 0] = 0.2 + 0.05 * t**2
    nu[:, 5] = np.where(seg == 1, 5.0, 0.1 * t)  # a jump between segments must not leak
    out = filter_segments(_table(t, seg, nu), DifferentiateParams(method="gaussian", sigma_s=0.25, gaussian_degree=2,
                                                                  edge_sigmas=3.0))
    kept = np.round(out["t_ns"].to_numpy() / PERIOD_NS).astype(int)
    expected = np.concatenate([np.arange(25, 75), np.arange(115, 185)])
    assert kept.tolist() == expected.tolist()
    ts = out["t_ns"].to_numpy() / 1e9
    assert out["udot_mps2"].to_numpy() == pytest.approx(0.1 * ts, abs=1e-12)
    r_dot = out["rdot_radps2"].to_numpy()
    assert r_dot[out["segment"] == 0] == pytest.approx(0.1, abs=1e-12)
    assert r_dot[out["segment"] == 1] == pytest.approx(0.0, abs=1e-12)
    # smoothed quadratic: Gaussian smoothing adds sigma^2 x''/2 (times the discrete moment)
    assert out["u_smooth_mps"].to_numpy() == pytest.approx(0.2 + 0.05 * ts**2 + 0.05 * 0.25**2, abs=1e-4)
    assert out["n1_rpm"].tolist() == expected.astype(float).tolist()  # passed through, rows aligned
    assert list(out.columns[:20]) == ["t_ns", "segment", *VELOCITY, *SMOOTH, *ACCELERATION]


def test_bias_corrected_gaussian_is_exact_to_degree_four_and_cancels_the_plain_kernels_bias() -> None:
    n = 300
    t = np.arange(n) * DT
    nu = np.zeros((n, 6))
    nu[:, 0] = 0.3 - 0.2 * t + 0.04 * t**2 - 0.01 * t**3 + 0.002 * t**4
    nu[:, 5] = 0.1 * t**3
    corrected = filter_segments(_table(t, np.zeros(n), nu),
                                DifferentiateParams(method="gaussian", sigma_s=0.35, gaussian_degree=4))
    plain = filter_segments(_table(t, np.zeros(n), nu),
                            DifferentiateParams(method="gaussian", sigma_s=0.35, gaussian_degree=2))
    assert len(corrected) == len(plain) == n - 2 * 21  # 3 sigma = 1.05 s = 21 samples dropped each side
    ts = corrected["t_ns"].to_numpy() / 1e9
    exact_udot = -0.2 + 0.08 * ts - 0.03 * ts**2 + 0.008 * ts**3
    assert corrected["udot_mps2"].to_numpy() == pytest.approx(exact_udot, abs=1e-9)
    assert corrected["rdot_radps2"].to_numpy() == pytest.approx(0.3 * ts**2, abs=1e-9)
    # smoothing is exact for the cubic (the plain kernel adds sigma^2 x''/2 = 0.35^2 * 0.3 t)
    assert corrected["r_smooth_radps"].to_numpy() == pytest.approx(0.1 * ts**3, abs=1e-9)
    # ... and the plain derivative is off by about sigma^2 x'''/2 (a little less: the kernel is cut at 3 sigma)
    assert plain["rdot_radps2"].to_numpy() - 0.3 * ts**2 == pytest.approx(0.35**2 / 2 * 0.6, rel=0.1)


def test_savgol_is_exact_for_a_cubic() -> None:
    n = 120
    t = np.arange(n) * DT
    nu = np.zeros((n, 6))
    nu[:, 1] = 1.0 + t - 0.3 * t**2 + 0.02 * t**3
    params = DifferentiateParams(method="savgol", savgol_window_s=1.0, savgol_order=3)
    out = filter_segments(_table(t, np.zeros(n), nu), params)
    assert len(out) == n - 2 * 10  # window 21 samples: 10 dropped each side
    ts = out["t_ns"].to_numpy() / 1e9
    assert out["vdot_mps2"].to_numpy() == pytest.approx(1 - 0.6 * ts + 0.06 * ts**2, abs=1e-10)


def test_too_short_everywhere_is_a_sync_error() -> None:
    t = np.arange(20) * DT
    with pytest.raises(SyncError, match="no segment longer"):
        filter_segments(_table(t, np.zeros(20), np.zeros((20, 6))),
                        DifferentiateParams(method="gaussian", sigma_s=0.25))


def _synced(n: int, q: np.ndarray, v_dvl: np.ndarray, rates: np.ndarray) -> pd.DataFrame:
    frame = pd.DataFrame({"t_ns": np.arange(n, dtype=np.int64) * PERIOD_NS, "segment": np.zeros(n, np.int32)})
    for j, c in enumerate("wxyz"):
        frame[f"ahrs_quat_{c}"] = q[:, j]
    for j, c in enumerate(("u_dvl_mps", "v_dvl_mps", "w_dvl_mps")):
        frame[c] = v_dvl[:, j]
    for j, c in enumerate(("p_gyro_radps", "q_gyro_radps", "r_fog_radps")):
        frame[c] = rates[:, j]
    for c in ("n1_rpm", "n2_rpm", "n3_rpm", "depth_m"):
        frame[c] = 1.0
    return frame


def _rpy_cases(n: int = 50) -> np.ndarray:
    rng = np.random.default_rng(3)
    return np.stack([rng.uniform(-1.2, 1.2, n), rng.uniform(-1.4, 1.4, n), rng.uniform(-3.1, 3.1, n)], axis=1)


def test_both_quaternion_conventions_give_the_same_roll_pitch_yaw() -> None:
    rpy = _rpy_cases()
    R_ned_frd = rpy_matrix(rpy[:, 0], rpy[:, 1], rpy[:, 2])
    T = np.array([[0.0, 1, 0], [1, 0, 0], [0, 0, -1]])  # NED <-> ENU (its own inverse)
    F = np.diag([1.0, -1, -1])  # FRD <-> FLU
    R_enu_flu = T @ R_ned_frd @ F
    as_wxyz = lambda R: np.roll(Rotation.from_matrix(R).as_quat(), 1, axis=1)  # noqa: E731
    for convention, R in (("frd_ned", R_ned_frd), ("flu_enu", R_enu_flu)):
        got = np.stack(attitude_from_quaternion(as_wxyz(R), convention), axis=1)
        assert got == pytest.approx(rpy, abs=1e-12), convention
    # the ROS quaternion read as if it were marine gives a different (wrong) attitude: the conversion matters
    wrong = np.stack(attitude_from_quaternion(as_wxyz(R_enu_flu), "frd_ned"), axis=1)
    assert not np.allclose(wrong, rpy, atol=1e-3)
    # and the body kinematics use it: a ROS vehicle config recovers the same angles
    n = len(rpy)
    ros = make_vehicle(attitude={"quaternion": "ahrs_quat", "convention": "flu_enu"})
    kin = body_kinematics(_synced(n, as_wxyz(R_enu_flu), np.ones((n, 3)), np.zeros((n, 3))), ros)
    assert kin["roll_rad"].to_numpy() == pytest.approx(rpy[:, 0], abs=1e-12)
    assert kin["pitch_rad"].to_numpy() == pytest.approx(rpy[:, 1], abs=1e-12)
    assert np.abs(np.angle(np.exp(1j * (kin["yaw_rad"].to_numpy() - rpy[:, 2])))).max() < 1e-12


def test_lever_arm_and_mounting_rotation_recover_body_velocity() -> None:
    rng = np.random.default_rng(7)
    n = 40
    v_ref = rng.normal(0, 0.5, (n, 3))
    omega = rng.normal(0, 0.3, (n, 3))
    r_dvl = np.array([0.6, -0.1, 0.25])
    mount_deg = (180.0, 0.0, 45.0)  # upside-down, turned 45 deg
    R = rpy_matrix(*np.deg2rad(mount_deg))
    v_at_dvl_body = v_ref + np.cross(omega, r_dvl)
    v_dvl = v_at_dvl_body @ R  # R^T v, row-wise
    signs = (1.0, -1.0, -1.0)  # gyro mounted FLU: q and r flipped
    raw_rates = omega * np.array(signs)
    vehicle = make_vehicle(dvl={"velocity": ["u_dvl_mps", "v_dvl_mps", "w_dvl_mps"], "position_m": r_dvl.tolist(),
                                "rotation_rpy_deg": mount_deg},
                           rates={"p": "p_gyro_radps", "q": "q_gyro_radps", "r": "r_fog_radps", "signs": signs})
    q = np.tile([1.0, 0, 0, 0], (n, 1))
    kin = body_kinematics(_synced(n, q, v_dvl, raw_rates), vehicle)
    assert kin[VELOCITY[:3]].to_numpy() == pytest.approx(v_ref, abs=1e-12)
    assert kin[VELOCITY[3:]].to_numpy() == pytest.approx(omega, abs=1e-15)
    assert kin["depth_m"].tolist() == [1.0] * n
    # without the lever arm the recovered velocity would be off by omega x r
    assert np.abs(np.cross(omega, r_dvl)).max() > 0.05


def test_an_asymmetric_dvl_mounting_is_recovered_exactly() -> None:
    """Yaw 45 deg, pitch 10 deg, a lever arm and non-zero rates: a transposed mounting rotation must not pass (the
    half-turn mounting above is a symmetric matrix, so it cannot tell R from R^T)."""
    from pipeline.sim.sensors import dvl_measurement, dvl_rotation

    rng = np.random.default_rng(11)
    n = 60
    nu = np.column_stack([rng.normal(0.8, 0.4, n), rng.normal(0, 0.3, n), rng.normal(0, 0.1, n),
                          rng.normal(0, 0.2, (n, 3))])
    r_dvl = np.array([0.45, 0.12, 0.3])
    mount_deg = (0.0, 10.0, 45.0)
    R = dvl_rotation(mount_deg)
    assert np.abs(R - R.T).max() > 0.5  # the check below can tell R from its transpose
    v_dvl = dvl_measurement(nu, r_dvl, R)
    vehicle = make_vehicle(dvl={"velocity": ["u_dvl_mps", "v_dvl_mps", "w_dvl_mps"], "position_m": r_dvl.tolist(),
                                "rotation_rpy_deg": list(mount_deg)})
    kin = body_kinematics(_synced(n, np.tile([1.0, 0, 0, 0], (n, 1)), v_dvl, nu[:, 3:]), vehicle)
    assert np.abs(kin[VELOCITY[:3]].to_numpy() - nu[:, :3]).max() < 1e-12
    assert np.abs(kin[VELOCITY[3:]].to_numpy() - nu[:, 3:]).max() < 1e-15


def test_unconfigured_rates_are_zero_and_yaw_is_unwrapped() -> None:
    n = 100
    yaw = np.linspace(0, 4 * np.pi, n)
    q = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)
    vehicle = make_vehicle(rates={"r": "r_fog_radps"})
    kin = body_kinematics(_synced(n, q, np.ones((n, 3)), np.full((n, 3), 0.7)), vehicle)
    assert (kin["p_radps"] == 0).all() and (kin["q_radps"] == 0).all()
    assert (kin["r_radps"] == 0.7).all()
    assert kin["yaw_rad"].to_numpy() == pytest.approx(yaw, abs=1e-12)


def test_missing_column_names_the_config_key() -> None:
    n = 10
    frame = _synced(n, np.tile([1.0, 0, 0, 0], (n, 1)), np.ones((n, 3)), np.zeros((n, 3))).drop(columns=["n2_rpm"])
    with pytest.raises(SchemaError, match="n2_rpm"):
        body_kinematics(frame, make_vehicle())
