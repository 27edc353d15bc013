"""The targets' spectral check and the band limit (pipeline.estimation.spectral) on synthetic trials with a known
answer: the 3-DOF plant of pipeline.sim.synthetic, its measured surge velocity with a 2.3-Hz ringing added (a
towing carriage's vibration), smoothed by the default smoother (white jerk, process noise by maximum likelihood).

Seeds: 0-2 are the tests' own; 100-119 served to choose SHARE_LIMIT (docs/estimation.md) and are not used here.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pandas as pd
import pytest

from pipeline.config.params import DifferentiateParams
from pipeline.errors import ConfigError
from pipeline.estimation.smoother import Measurements, smooth
from pipeline.estimation.spectral import (
    PEAK_LIMIT,
    SHARE_LIMIT,
    band_limit,
    check_targets,
    remove_disturbances,
    spectrum,
)
from pipeline.sim.synthetic import SyntheticPlant, synthetic_trial
from pipeline.vocabulary import ACCELERATION, DAMPING_COLUMNS, DOFS, SMOOTH, TAU_COLUMNS, VELOCITY

RING_HZ = 2.3
MASS = {"u": 80.0, "v": 120.0, "r": 20.0}  # SyntheticPlant's diagonal M
NOISE = {"u": 0.005, "v": 0.005, "r": 0.002}  # synthetic_trial's velocity noise


def _with_damping(table: pd.DataFrame) -> pd.DataFrame:
    """The damping target as derive forms it, without Coriolis (the plant's is small): d = tau - M nu_dot."""
    out = table.copy()
    for dof, m in MASS.items():
        out[DAMPING_COLUMNS[dof]] = out[TAU_COLUMNS[dof]] - m * out[ACCELERATION[DOFS.index(dof)]]
    return out


def _trial(seed: int, amp_mps: float, ring_hz: float = RING_HZ) -> tuple[pd.DataFrame, float]:
    """The derived-like table of a 300-s trial with ``amp_mps`` of 2.3-Hz ringing on the measured surge, and the
    ringing's known share of the u̇ target's variance (the smoother is linear at its process noise, ungated)."""
    df = synthetic_trial(SyntheticPlant(), 300.0, 20.0, seed=seed)
    t = df["t_ns"].to_numpy()
    ring = amp_mps * np.sin(2 * np.pi * ring_hz * t / 1e9 + 0.3)
    out = df[["t_ns", "segment", "n1_rpm", "roll_rad", "pitch_rad", "yaw_rad", *(TAU_COLUMNS[d] for d in DOFS)]].copy()
    for j in range(len(DOFS)):
        out[VELOCITY[j]] = out[SMOOTH[j]] = out[ACCELERATION[j]] = 0.0
    known = 0.0
    for dof, sd in NOISE.items():
        j = DOFS.index(dof)
        y = df[VELOCITY[j]].to_numpy() + (ring if dof == "u" else 0.0)
        res = smooth(t, Measurements(t, y, sd**2), gate=0)
        out[VELOCITY[j]] = out[SMOOTH[j]] = res.x
        out[ACCELERATION[j]] = res.xdot
        if dof == "u" and amp_mps > 0:
            alone = smooth(t, Measurements(t, ring, sd**2), q=res.q, gate=0)
            known = float(np.var(alone.xdot) / np.var(res.xdot))
    return _with_damping(out), known


def peak_share_over(target: dict, limit: float) -> bool:
    return bool(target["peaks"]) and target["peaks"][0]["share"] > limit


@pytest.fixture(scope="module")
def ringing() -> tuple[pd.DataFrame, float]:
    return _trial(0, 0.01)


@pytest.mark.parametrize("amp_mps", [0.007, 0.01])  # 0.007: under SHARE_LIMIT, flagged by its peak alone
def test_the_check_names_a_2_3_hz_ringing_on_surge(amp_mps: float) -> None:
    table, known = _trial(0, amp_mps)
    rep = check_targets(table, "zigzag1", ["n1_rpm"])
    udot = rep["dofs"]["u"]["targets"]["udot_mps2"]
    assert udot["flagged"] and peak_share_over(udot, PEAK_LIMIT)
    peak = udot["peaks"][0]
    assert peak["frequency_hz"] == pytest.approx(RING_HZ, abs=0.02)  # on a bin: the interpolation stays there
    assert peak["share"] == pytest.approx(known, abs=0.03)  # the ringing's share of u̇'s variance
    assert 0.05 < known < 0.4
    [warning, *rest] = [w for w in rep["warnings"] if w["target"] == "udot_mps2"]
    assert not rest and warning["peak_hz"] == pytest.approx(RING_HZ, abs=0.1)
    text = warning["text"]
    assert re.match(r"zigzag1: u̇ carries \d+ % of its variance above 0\.\d+ Hz where the actuators put [0-2] % ", text)
    assert "narrow-band disturbance at 2.3" in text and "`differentiate.notch_hz: [2.3" in text
    assert "`differentiate.max_hz: " in text
    # sway and yaw carry no ringing: nothing said about them
    assert not any(w["target"].startswith(("v", "r", "d_v", "d_r")) for w in rep["warnings"])
    assert rep["dofs"]["u"]["input_share_above"] <= 0.03


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_clean_trial_raises_nothing(seed: int) -> None:
    table, _ = _trial(seed, 0.0)
    rep = check_targets(table, "clean")
    assert rep["warnings"] == []
    for entry in rep["dofs"].values():
        for target in entry["targets"].values():
            assert not target["flagged"] and target["peaks"] == []
    assert set(rep["dofs"]) == {"u", "v", "r"}  # w, p, q: no sensor, not checked


@pytest.mark.parametrize("params", [DifferentiateParams(notch_hz=[RING_HZ]), DifferentiateParams(max_hz=0.8)],
                         ids=["notch", "max_hz"])
def test_the_band_limit_removes_the_ringing_and_keeps_the_low_frequencies(ringing, params) -> None:
    table, _ = ringing
    limited, applied = band_limit(table, params)
    assert applied["notch_hz"] == list(params.notch_hz) and applied["max_hz"] == params.max_hz
    limited = _with_damping(limited)
    rep = check_targets(limited, "zigzag1")
    assert rep["warnings"] == []
    udot = rep["dofs"]["u"]["targets"]["udot_mps2"]
    assert udot["unexplained_above_band"] < SHARE_LIMIT and udot["peaks"] == []
    # the motion the actuators drive is kept: u̇'s spectrum below 0.5 Hz within 2 %, and u̇ against the clean
    # trial's (same seed, no ringing) as close as before the ringing was added
    rows = [np.arange(len(table))]
    freq, before = spectrum(table["udot_mps2"].to_numpy(), rows, 0.05)
    _, after = spectrum(limited["udot_mps2"].to_numpy(), rows, 0.05)
    low = (freq > 0) & (freq < 0.5)
    assert after[low].sum() == pytest.approx(before[low].sum(), rel=0.02)
    clean, _ = _trial(0, 0.0)
    mid = slice(200, -200)  # segment edges: the zero-phase filter's padding
    err = limited["udot_mps2"].to_numpy()[mid] - clean["udot_mps2"].to_numpy()[mid]
    assert 1 - np.var(err) / np.var(clean["udot_mps2"].to_numpy()[mid]) > 0.95
    # velocity and acceleration filtered alike; the other DOFs' targets hardly move
    assert np.array_equal(limited["u_mps"], limited["u_smooth_mps"])
    r = table["r_radps"].to_numpy()[mid]
    assert np.var(limited["r_radps"].to_numpy()[mid] - r) < 1e-4 * np.var(r)


def test_the_band_limit_is_off_by_default_and_deterministic(ringing) -> None:
    table, _ = ringing
    same, applied = band_limit(table, DifferentiateParams())
    assert same is table and applied == {}
    params = DifferentiateParams(notch_hz=[RING_HZ], max_hz=1.0)
    one, _ = band_limit(table, params)
    two, _ = band_limit(table.copy(), params)
    assert one.equals(two)


def test_a_notch_above_the_grids_nyquist_frequency_is_a_config_error(ringing) -> None:
    table, _ = ringing
    with pytest.raises(ConfigError, match="notch_hz: 12 Hz .* Nyquist frequency 10 Hz") as err:
        band_limit(table, DifferentiateParams(notch_hz=[12.0]))
    assert err.value.field == "notch_hz"


def test_differentiate_applies_the_band_limit_after_any_method(ringing, monkeypatch) -> None:
    from pipeline.estimation import differentiate as dispatch

    table, _ = ringing
    monkeypatch.setattr(dispatch, "method_function", lambda method: lambda *a: (table.copy(), {"method": method}))
    out, report = dispatch.differentiate(table, None, DifferentiateParams(method="gaussian", notch_hz=[RING_HZ]))
    assert report["band_limit"]["notch_hz"] == [RING_HZ]
    assert out.equals(band_limit(table, DifferentiateParams(notch_hz=[RING_HZ]))[0])
    _, plain = dispatch.differentiate(table, None, DifferentiateParams(method="gaussian"))
    assert "band_limit" not in plain


def test_the_derive_stage_writes_the_check_beside_the_derived_table(ringing, tmp_path) -> None:
    from pipeline import layout
    from pipeline.config import Params, load_vehicle
    from pipeline.estimation.spectral import report_path
    from pipeline.tableio import write_parquet
    from stages import derive as stage
    from stages._pertrial import to_arrow
    from tests.cli.helpers import VEHICLE_YAML

    (tmp_path / "vehicle.yaml").write_text(VEHICLE_YAML)  # one surge thruster on n1_rpm
    vehicle = load_vehicle(tmp_path / "vehicle.yaml")
    table, _ = ringing
    kin = table.drop(columns=[*TAU_COLUMNS.values(), *(DAMPING_COLUMNS[d] for d in MASS)])
    layout.kinematics_path(tmp_path, "zigzag1").parent.mkdir(parents=True)
    write_parquet(to_arrow(kin), layout.kinematics_path(tmp_path, "zigzag1"), {"stage": "differentiate"})
    result = stage.run(tmp_path, vehicle, Params())
    assert result.summary["zigzag1"]["spectral_warnings"] >= 1
    doc = json.loads(report_path(tmp_path, "zigzag1").read_text())
    assert doc["dofs"]["u"]["inputs"] == ["tau_u_N", "T_th1_N", "n1_rpm"]  # tau and every actuator
    [udot] = [w for w in doc["warnings"] if w["target"] == "udot_mps2"]
    assert udot["peak_hz"] == pytest.approx(RING_HZ, abs=0.1) and "notch_hz" in udot["text"]
    assert doc["dofs"]["r"]["inputs"] == ["T_th1_N", "n1_rpm"]  # no yaw moment: the actuators alone
    first = report_path(tmp_path, "zigzag1").read_bytes()
    stage.run(tmp_path, vehicle, Params())
    assert report_path(tmp_path, "zigzag1").read_bytes() == first


def test_disturbances_are_removed_by_default_from_the_dof_that_carries_them(ringing) -> None:
    """differentiate.disturbances: remove (the default): the ringing found in u̇ against the actuators is named
    and removed from u alone by the check's low-pass (it lies well below 2.3 Hz); sway and yaw are untouched."""
    table, known = ringing
    params = DifferentiateParams()
    assert params.disturbances == "remove"
    cleaned, removed = remove_disturbances(table, params, ["n1_rpm"])
    [found] = removed
    assert found["dof"] == "u" and found["target"] == "udot_mps2"
    assert found["frequency_hz"] == pytest.approx(RING_HZ, abs=0.02)
    assert found["share"] == pytest.approx(known, abs=0.03)
    assert found["max_hz"] is not None and found["max_hz"] < 0.8 * RING_HZ and found["notch_hz"] == []
    assert "u̇ carried a narrow-band disturbance at 2.30 Hz" in found["text"]
    assert found["columns"] == ["u_mps", "u_smooth_mps", "udot_mps2"]
    for col in ("v_mps", "vdot_mps2", "r_radps", "rdot_radps2"):
        assert np.array_equal(cleaned[col], table[col]), col
    rep = check_targets(_with_damping(cleaned), "zigzag1", ["n1_rpm"])
    assert rep["warnings"] == []
    clean, _ = _trial(0, 0.0)
    mid = slice(200, -200)
    err = cleaned["udot_mps2"].to_numpy()[mid] - clean["udot_mps2"].to_numpy()[mid]
    assert 1 - np.var(err) / np.var(clean["udot_mps2"].to_numpy()[mid]) > 0.95


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_clean_trial_loses_nothing_to_the_disturbance_removal(seed: int) -> None:
    table, _ = _trial(seed, 0.0)
    same, removed = remove_disturbances(table, DifferentiateParams(), ["n1_rpm"])
    assert removed == [] and same is table


def test_a_disturbance_next_to_the_band_is_notched_not_low_passed() -> None:
    """At 0.8 Hz, just above the check's band (0.6 Hz here), the low-pass (1.25 times the band) would not clear the
    peak: the remedy is a notch there, and u̇ ends no longer flagged and closer to the clean trial's."""
    table, _ = _trial(0, 0.03, ring_hz=0.8)
    cleaned, [found] = remove_disturbances(table, DifferentiateParams(), ["n1_rpm"])
    assert found["max_hz"] is None and found["notch_hz"] == [pytest.approx(0.8, abs=0.02)]
    assert "removed from u by notches at [0.8" in found["text"]
    after = check_targets(cleaned, "zigzag1", ["n1_rpm"], targets="accelerations", log_warnings=False)
    assert not after["dofs"]["u"]["targets"]["udot_mps2"]["flagged"]
    clean = _trial(0, 0.0)[0]["udot_mps2"].to_numpy()[200:-200]
    before_err = np.var(table["udot_mps2"].to_numpy()[200:-200] - clean)
    after_err = np.var(cleaned["udot_mps2"].to_numpy()[200:-200] - clean)
    assert after_err < 0.2 * before_err
