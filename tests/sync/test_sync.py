from __future__ import annotations

import numpy as np
import pyarrow as pa
import pytest

from pipeline.config.params import SyncParams
from pipeline.errors import ConfigError, SchemaError, SyncError
from pipeline.sync import required_signals, resample, segments, synchronize
from tests.sync.helpers import PERIOD_NS, constant_streams, make_vehicle, stream

T0 = 1_700_000_000_000_000_000
VEHICLE = make_vehicle()


def test_grid_is_aligned_to_period_multiples_over_the_overlap() -> None:
    streams = constant_streams()
    # shift one stream's start off-grid: the grid starts at the next multiple of the period after it
    streams["fog"] = streams["fog"].iloc[3:].reset_index(drop=True)  # starts at T0 + 30 ms
    out = synchronize(streams, VEHICLE, SyncParams())
    assert out["t_ns"].dtype == np.int64
    assert np.all(out["t_ns"] % PERIOD_NS == 0)
    assert out["t_ns"].iloc[0] == T0 + PERIOD_NS
    assert out["t_ns"].iloc[-1] == T0 + 20 * 10**9
    assert np.all(np.diff(out["t_ns"]) == PERIOD_NS)
    assert set(out["segment"]) == {0}
    assert out["segment"].dtype == np.int32


def test_pyarrow_tables_are_accepted_and_give_the_same_result() -> None:
    streams = constant_streams(5.0)
    a = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1))
    b = synchronize({k: pa.Table.from_pandas(v, preserve_index=False) for k, v in streams.items()}, VEHICLE,
                    SyncParams(min_segment_s=1))
    assert a.equals(b)


def test_linear_zoh_nearest_semantics() -> None:
    t = np.array([0, 100, 200], dtype=np.int64) * 1_000_000  # 0, 100, 200 ms
    grid = np.array([0, 25, 50, 75, 100, 160, 200], dtype=np.int64) * 1_000_000
    x = np.array([0.0, 1.0, 3.0])
    ok = np.ones(3, dtype=bool)
    lin, v = resample(t, x, ok, grid, "linear", 10**9)
    assert v.all()
    assert lin == pytest.approx([0, 0.25, 0.5, 0.75, 1.0, 2.2, 3.0], abs=1e-15)
    zoh, _ = resample(t, x, ok, grid, "zoh", 10**9)
    assert zoh.tolist() == [0, 0, 0, 0, 1, 1, 3]
    near, _ = resample(t, x, ok, grid, "nearest", 10**9)
    assert near.tolist() == [0, 0, 0, 1, 1, 3, 3]  # ties (50 ms) take the earlier sample


def test_kinds_by_suffix_and_override() -> None:
    streams = constant_streams(10.0)
    t = streams["thrusters"]["t_ns"].to_numpy()
    step = np.where(np.arange(len(t)) % 2 == 0, 0.0, 1000.0)  # 10 Hz square wave
    streams["thrusters"]["n3_rpm"] = step
    out = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1))
    # 20 Hz grid on 10 Hz commands: zero-order hold repeats each command, no ramps
    held = out["n3_rpm"].to_numpy()
    assert set(np.unique(held)) == {0.0, 1000.0}
    assert held[1] == held[0] and held[3] == held[2]
    lin = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1, interpolation={"n3_rpm": "linear"}))
    assert lin["n3_rpm"].iloc[1] == pytest.approx(500.0)


def test_no_grid_sample_inside_a_gap_is_made_up() -> None:
    streams = constant_streams(20.0)
    dvl = streams["dvl"]
    t = dvl["t_ns"].to_numpy()
    gap = (t > T0 + 5 * 10**9) & (t < T0 + 7 * 10**9)  # removes the DVL samples at 5.2 .. 6.8 s
    streams["dvl"] = dvl[~gap].reset_index(drop=True)
    out = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1))
    ts = out["t_ns"].to_numpy()
    inside = (ts > T0 + 5 * 10**9) & (ts < T0 + 7 * 10**9)
    assert inside.sum() == 39
    for col in ("u_dvl_mps", "v_dvl_mps", "w_dvl_mps"):
        assert np.isnan(out.loc[inside, col]).all()
        assert not out.loc[inside, col + "__valid"].any()
        assert out.loc[~inside, col + "__valid"].all()  # the samples at 5 s and 7 s are measured: valid
    assert (out.loc[inside, "segment"] == -1).all()
    assert sorted(set(out["segment"])) == [-1, 0, 1]
    # a gap shorter than max_gap is bridged: 0.2 s DVL spacing with max_gap 0.25 s
    bridged = synchronize(constant_streams(5.0), VEHICLE, SyncParams(min_segment_s=1, max_gap_s={"default": 0.25}))
    assert bridged["u_dvl_mps__valid"].all()
    cut = synchronize(constant_streams(5.0), VEHICLE,
                      SyncParams(min_segment_s=0, max_gap_s={"default": 0.25, "u_dvl_mps": 0.15}))
    assert cut["u_dvl_mps__valid"].sum() == 26  # only the grid samples at DVL sample times (5 s at 5 Hz + 1)


@pytest.mark.parametrize("how", ["flag", "zero"])
def test_dvl_lost_lock_is_invalid_not_zero(how: str) -> None:
    streams = constant_streams(20.0)
    dvl = streams["dvl"]
    lost = (dvl["t_ns"] >= T0 + 8 * 10**9) & (dvl["t_ns"] <= T0 + 9 * 10**9)
    if how == "flag":
        dvl.loc[lost, "dvl_lock_flag"] = 0.0
    else:
        dvl.loc[lost, ["u_dvl_mps", "v_dvl_mps", "w_dvl_mps"]] = 0.0
    out = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1))
    ts = out["t_ns"].to_numpy()
    bad = (ts > T0 + 7_800_000_000) & (ts < T0 + 9_200_000_000)  # between the neighbouring locked samples
    assert not out.loc[bad, "u_dvl_mps__valid"].any()
    assert np.isnan(out.loc[bad, "u_dvl_mps"]).all()
    assert (out.loc[~bad, "u_dvl_mps"] == 0.5).all()
    assert (out.loc[bad, "segment"] == -1).all()


def test_quaternions_are_sign_continuous_and_normalized() -> None:
    streams = constant_streams(5.0)
    ahrs = streams["ahrs"]
    n = len(ahrs)
    yaw = np.linspace(0.0, 1.0, n)
    q = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)
    q[1::2] *= -1.0  # the same rotations, every other one with the opposite sign
    for j, part in enumerate("wxyz"):
        ahrs[f"ahrs_quat_{part}"] = q[:, j]
    out = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1))
    qo = out[[f"ahrs_quat_{p}" for p in "wxyz"]].to_numpy()
    assert np.linalg.norm(qo, axis=1) == pytest.approx(1.0, abs=1e-12)
    yaw_out = 2 * np.arctan2(qo[:, 3], qo[:, 0])
    yaw_true = (out["t_ns"].to_numpy() - T0) / 5e9
    # nlerp between samples 20 ms apart: error far below 1e-6 rad at these rates
    assert np.abs(np.angle(np.exp(1j * (yaw_out - yaw_true)))).max() < 1e-6
    assert out["ahrs_quat__valid"].all()


def test_segments_shorter_than_minimum_get_minus_one() -> None:
    valid = np.array([1, 1, 0, 1, 1, 1, 0, 0, 1, 1, 1, 1], dtype=bool)
    assert segments(valid, 3).tolist() == [-1, -1, -1, 0, 0, 0, -1, -1, 1, 1, 1, 1]


def test_no_overlap_and_no_segment_are_sync_errors() -> None:
    streams = constant_streams(5.0)
    streams["fog"] = stream(streams["fog"]["t_ns"] + 10 * 10**9, r_fog_radps=streams["fog"]["r_fog_radps"])
    with pytest.raises(SyncError, match="do not overlap"):
        synchronize(streams, VEHICLE, SyncParams())
    with pytest.raises(SyncError, match="no stretch"):
        synchronize(constant_streams(3.0), VEHICLE, SyncParams(min_segment_s=5.0))


def test_missing_required_signal_names_it() -> None:
    streams = constant_streams(5.0)
    streams["thrusters"] = streams["thrusters"].drop(columns=["n2_rpm"])
    with pytest.raises(SchemaError, match="n2_rpm") as info:
        synchronize(streams, VEHICLE, SyncParams())
    assert info.value.field == "n2_rpm"


def test_required_signals_follow_the_sensor_config() -> None:
    assert required_signals(VEHICLE) == ["u_dvl_mps", "v_dvl_mps", "w_dvl_mps", "ahrs_quat", "p_gyro_radps",
                                         "q_gyro_radps", "r_fog_radps", "n1_rpm", "n2_rpm", "n3_rpm"]
    three_dof = make_vehicle(rates={"r": "r_fog_radps"})
    assert "p_gyro_radps" not in required_signals(three_dof)


def test_per_signal_params_must_name_configured_signals() -> None:
    with pytest.raises(ConfigError, match="n9_rpm") as info:
        synchronize(constant_streams(5.0), VEHICLE, SyncParams(interpolation={"n9_rpm": "zoh"}))
    assert info.value.field == "sync.interpolation.n9_rpm"


def test_duplicate_stamps_are_averaged_per_signal_and_reported(caplog: pytest.LogCaptureFixture) -> None:
    streams = constant_streams(5.0)
    fog = streams["fog"]  # 100 Hz on a 20 Hz grid: grid points fall on source samples
    t = fog["t_ns"].to_numpy().copy()
    r = np.zeros(len(t))
    t[11] = t[10]  # three samples stamped alike, the middle one missing: mean of the finite two
    t[12] = t[10]
    r[10], r[11], r[12] = 1.0, np.nan, 4.0
    t[21] = t[20]
    r[20], r[21] = 0.3, 0.3  # equal values stay exact
    streams["fog"] = stream(t, r_fog_radps=r)
    with caplog.at_level("WARNING", logger="pipeline.sync"):
        out = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1))
    at = {int(k): i for i, k in enumerate(out["t_ns"])}
    assert out["r_fog_radps"].iloc[at[int(t[10])]] == 2.5  # not 4.0, the last of the run
    assert out["r_fog_radps"].iloc[at[int(t[20])]] == 0.3
    assert out.attrs["duplicate_stamps"] == {"fog": {"samples": len(t), "merged_away": 3, "kept": len(t) - 3}}
    (line,) = [r.getMessage() for r in caplog.records]
    assert line.startswith(f"stream 'fog': 3 of {len(t)} samples share a time stamp") and "averaged" in line


def test_merge_duplicates_flags_take_the_minimum_and_quaternions_align_sign() -> None:
    from pipeline.sync import merge_duplicates

    cols = {"t_ns": np.array([0, 5, 5, 9], dtype=np.int64),
            "dvl_lock_flag": np.array([1.0, 1.0, 0.0, 1.0]),
            "u_mps": np.array([1.0, 2.0, np.inf, 3.0]),
            "q_quat_w": np.array([1.0, 0.6, -0.6, 1.0]), "q_quat_x": np.array([0.0, 0.8, -0.8, 0.0])}
    out, merged = merge_duplicates(cols, [("q_quat_w", "q_quat_x")])
    assert merged == 1 and out["t_ns"].tolist() == [0, 5, 9]
    assert out["dvl_lock_flag"].tolist() == [1.0, 0.0, 1.0]  # one unlocked sample makes the merged one unlocked
    assert out["u_mps"].tolist() == [1.0, 2.0, 3.0]
    assert out["q_quat_w"].tolist() == [1.0, 0.6, 1.0] and out["q_quat_x"].tolist() == [0.0, 0.8, 0.0]
    same, none = merge_duplicates({"t_ns": np.array([1, 2], dtype=np.int64), "a": np.array([1.0, 2.0])})
    assert none == 0 and same["a"].tolist() == [1.0, 2.0]


def test_no_overlap_names_the_streams_their_spans_and_the_remedy() -> None:
    streams = constant_streams(5.0)
    n = len(streams["thrusters"])
    streams["thrusters"] = stream(np.zeros(n, dtype=np.int64), **{c: streams["thrusters"][c]
                                                                  for c in ("n1_rpm", "n2_rpm", "n3_rpm")})
    with pytest.raises(SyncError) as info:
        synchronize(streams, VEHICLE, SyncParams())
    message = str(info.value)
    assert f"'thrusters': 0.000 s to 0.000 s (all {n} stamps equal) <- overlaps none of the others" in message
    assert "'dvl': 2023-11-14T22:13:20.000Z to 2023-11-14T22:13:25.000Z;" in message  # not marked
    assert "stamp_warnings" in message and "ingest_report.json" in message and "`clock: log`" in message


def test_a_gap_of_exactly_max_gap_is_bridged_and_a_nanosecond_less_max_gap_cuts_it() -> None:
    """The boundary is inclusive (``b - a <= max_gap_s``): a 4-Hz DVL, pings 250 ms apart, with ``max_gap_s: 0.25``
    is bridged on every grid sample; one nanosecond less and only the grid samples at its pings stay valid."""
    t = np.arange(5, dtype=np.int64) * 250_000_000
    grid = np.arange(21, dtype=np.int64) * 50_000_000
    x = np.arange(5, dtype=float)
    ok = np.ones(5, dtype=bool)
    for kind in ("linear", "zoh", "nearest"):
        _, valid = resample(t, x, ok, grid, kind, 250_000_000)
        assert valid.all(), kind
        _, valid = resample(t, x, ok, grid, kind, 250_000_000 - 1)
        assert valid.tolist() == [g % 250_000_000 == 0 for g in grid], kind
    streams = constant_streams(10.0)
    td = T0 + np.arange(41, dtype=np.int64) * 250_000_000
    streams["dvl"] = stream(td, u_dvl_mps=np.full(41, 0.5), v_dvl_mps=np.full(41, 0.1), w_dvl_mps=np.zeros(41),
                            dvl_lock_flag=np.ones(41))
    out = synchronize(streams, VEHICLE, SyncParams(min_segment_s=1, max_gap_s={"default": 0.25}))
    assert out["u_dvl_mps__valid"].all() and len(out) == 201 and set(out["segment"]) == {0}
    cut = synchronize(streams, VEHICLE, SyncParams(min_segment_s=0, max_gap_s={"default": 0.25,
                                                                               "u_dvl_mps": 0.2499}))
    assert cut["u_dvl_mps__valid"].sum() == 41
