from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from pipeline import physics
from pipeline.config import load_vehicle
from pipeline.derive import derive, derived_columns
from pipeline.errors import SchemaError
from pipeline.vocabulary import ACCELERATION, SMOOTH, VELOCITY, force_columns
from tests.sync.helpers import make_vehicle, vehicle_dict


def _kin(n: int = 5, **cols: float | np.ndarray) -> pd.DataFrame:
    frame = pd.DataFrame({"t_ns": np.arange(n, dtype=np.int64) * 50_000_000, "segment": np.zeros(n, np.int32)})
    for name in (*VELOCITY, *SMOOTH, *ACCELERATION, "roll_rad", "pitch_rad", "yaw_rad", "n1_rpm", "n2_rpm", "n3_rpm"):
        frame[name] = 0.0
    for name, value in cols.items():
        frame[name] = value
    return frame


def test_thrust_tau_and_damping_target_by_hand() -> None:
    vehicle = make_vehicle()
    kin = _kin(n1_rpm=1000.0, n2_rpm=-1000.0, n3_rpm=500.0, udot_mps2=0.1)
    out = derive(kin, vehicle)
    t1, t2, t3 = 2e-5 * 1000**2, -1e-5 * 1000**2, 1e-5 * 500**2  # k_fwd / k_bwd n|n|
    assert out["T_left_N"].iloc[0] == pytest.approx(t1, rel=1e-12)
    assert out["T_right_N"].iloc[0] == pytest.approx(t2, rel=1e-12)
    assert out["T_lateral_N"].iloc[0] == pytest.approx(t3, rel=1e-12)
    # left at y=-0.2 pushing forward turns to starboard (+N); right at y=+0.2 to port; lateral at x=0.3 -> +N
    tau = [t1 + t2, t3, 0.0, 0.0, 0.0, 0.2 * t1 - 0.2 * t2 + 0.3 * t3]
    got = out[force_columns("tau")].iloc[0].to_numpy()
    assert got == pytest.approx(tau, abs=1e-12)
    # at rest, level, neutral: C(nu) nu = 0, g = 0; M nu_dot = (m + X_udot) u_dot in surge,
    # and m z_g u_dot in pitch (M_RB couples surge and pitch through the CG height)
    assert out["Mnudot_u_N"].iloc[0] == pytest.approx(35.0 * 0.1, rel=1e-12)
    assert out["Mnudot_q_Nm"].iloc[0] == pytest.approx(30.0 * 0.02 * 0.1, rel=1e-12)
    assert out["d_u_N"].iloc[0] == pytest.approx(t1 + t2 - 3.5, rel=1e-12)
    assert out["d_r_Nm"].iloc[0] == pytest.approx(tau[5], rel=1e-12)
    assert list(out.columns) == list(kin.columns) + derived_columns(vehicle)


def test_terms_add_up_and_coriolis_uses_smoothed_velocity() -> None:
    rng = np.random.default_rng(1)
    n = 50
    cols: dict[str, np.ndarray] = {c: rng.normal(0, 0.3, n) for c in (*VELOCITY, *SMOOTH, *ACCELERATION)}
    cols.update(roll_rad=rng.normal(0, 0.2, n), pitch_rad=rng.normal(0, 0.2, n),
                n1_rpm=rng.normal(0, 800, n), n2_rpm=rng.normal(0, 800, n), n3_rpm=rng.normal(0, 800, n))
    vehicle = make_vehicle()
    out = derive(_kin(n, **cols), vehicle)
    total = sum(out[force_columns(p)].to_numpy() for p in ("d", "Mnudot", "Cnu", "g"))
    assert total == pytest.approx(out[force_columns("tau")].to_numpy(), abs=1e-12)
    M = physics.mass_matrix(vehicle)
    smooth = np.stack([cols[c] for c in SMOOTH], axis=1)
    assert out[force_columns("Cnu")].to_numpy() == pytest.approx(physics.coriolis_force(M, smooth),
                                                                         abs=1e-12)


def test_thrust_from_a_table_is_interpolated(tmp_path: Path) -> None:
    (tmp_path / "t200.csv").write_text("rpm, thrust_kgf\n-2000,-3.0\n0,0\n1000,1.0\n2000,5.0\n")
    data = vehicle_dict()
    data["thrusters"][0]["thrust"] = {"table": "t200.csv", "table_speed_column": "rpm",
                                      "table_thrust_column": "thrust_kgf", "table_thrust_unit": "kgf"}
    (tmp_path / "v.yaml").write_text(yaml.safe_dump(data))
    vehicle = load_vehicle(tmp_path / "v.yaml")
    speeds = np.array([1500.0, -1000.0, 250.0, 2000.0])
    out = derive(_kin(4, n1_rpm=speeds), vehicle)
    kgf = 9.80665
    assert out["T_left_N"].to_numpy() == pytest.approx(np.array([3.0, -1.5, 0.25, 5.0]) * kgf, rel=1e-12)
    assert out["tau_u_N"].to_numpy() == pytest.approx(out["T_left_N"].to_numpy(), rel=1e-12)


def test_missing_signal_names_the_column() -> None:
    with pytest.raises(SchemaError, match="n2_rpm") as info:
        derive(_kin().drop(columns=["n2_rpm"]), make_vehicle())
    assert info.value.field == "n2_rpm"
    with pytest.raises(SchemaError, match="rdot_radps2"):
        derive(_kin().drop(columns=["rdot_radps2"]), make_vehicle())
    with pytest.raises(SchemaError, match="pitch_rad"):
        derive(_kin().drop(columns=["pitch_rad"]), make_vehicle())
