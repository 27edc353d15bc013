"""Time-stamp sanity at ingest: zero, constant, sim-time, duplicate, quantized stamps and steps back each give
the named warning (report and log, with trial, file, stream and remedy), and the remedy works.

Logs are written by the libraries' own writers (tests/io/helpers.py) or as small CSV trials.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import stages.ingest as stage
from pipeline import layout
from pipeline.config import Params
from pipeline.ingest import ingest_log
from pipeline.stamps import _steps, check_stamps, time_stats, uniform_times
from tests.io import helpers as h
from tests.io.test_ingest_stage import LOG_STREAMS, T0_NS, make_vehicle

THR = "/thrusters/joint_states"


def checks(report: dict[str, Any], stream: str) -> list[str]:
    return [w["check"] for w in report["streams"][stream]["stamp_warnings"]]


def warning_lines(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]


def streams_with(**changes: dict[str, Any]) -> dict[str, Any]:
    streams = json.loads(json.dumps(LOG_STREAMS))
    for name, change in changes.items():
        streams[name].update(change)
    return streams


# -- ROS logs: header stamps -----------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", ["mcap", "ros1"])
def test_zero_header_stamps_warn_by_name_and_clock_log_fixes_them(tmp_path: Path, kind: str,
                                                                   caplog: pytest.LogCaptureFixture) -> None:
    msgs = h.trial(n=12)
    for m in msgs:
        if m.topic == THR:
            m.stamp_ns = 0  # a simulator that never fills the header
    path = (h.write_mcap(tmp_path / "sim3.mcap", msgs) if kind == "mcap"
            else h.write_rosbag1(tmp_path / "sim3.bag", msgs))
    with caplog.at_level(logging.WARNING, logger="pipeline.ingest"):
        out = ingest_log(path, make_vehicle(LOG_STREAMS))
    assert checks(out.report, "thr") == ["zero"]
    assert checks(out.report, "dvl") == [] and checks(out.report, "imu") == []
    warning = out.report["streams"]["thr"]["stamp_warnings"][0]
    assert warning["count"] == 12 and "all 12 header stamps are 0" in warning["message"]
    assert "`clock: log`" in warning["remedy"] and "rate_hz: 10" in warning["remedy"]  # rate from the log time
    assert out.report["streams"]["thr"]["stamps"]["zeros"] == 12
    (line,) = warning_lines(caplog)
    assert line.startswith(f"sim3 ({path.name}): stream 'thr' ({THR}): all 12 header stamps are 0")
    assert "logged at 2023-11-14T22:13:20" in line and "Remedy: set `clock: log`" in line
    json.dumps(out.report)

    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="pipeline.ingest"):
        fixed = ingest_log(path, make_vehicle(streams_with(thr={"clock": "log"})))
    assert checks(fixed.report, "thr") == [] and warning_lines(caplog) == []
    log_ns = h.expected(msgs)[THR]["log_ns"]
    np.testing.assert_array_equal(fixed.tables["thr"]["t_ns"].to_numpy(), log_ns)


def test_sim_time_header_stamps_warn_and_clock_log_fixes_them(tmp_path: Path,
                                                              caplog: pytest.LogCaptureFixture) -> None:
    msgs = h.trial(n=12)
    for m in msgs:
        if m.topic == "/dvl/data":
            m.stamp_ns = m.log_ns - T0_NS + 500_000_000_000  # simulation time, ~500 s, while logged in 2023
    path = h.write_rosbag2(tmp_path / "sim4", msgs)
    with caplog.at_level(logging.WARNING, logger="pipeline.ingest"):
        out = ingest_log(path, make_vehicle(LOG_STREAMS))
    assert checks(out.report, "dvl") == ["far_from_log"] and checks(out.report, "thr") == []
    message = out.report["streams"]["dvl"]["stamp_warnings"][0]["message"]
    assert "header stamps span 500.000 s to 501.1" in message and "(simulation time?)" in message
    assert "log time spans 2023-11-14T22:13:20" in message
    assert out.report["streams"]["dvl"]["stamps"]["header_minus_log_s"] == pytest.approx(500 - T0_NS / 1e9,
                                                                                          abs=1e-3)
    assert any("stream 'dvl' (/dvl/data)" in line and "`clock: log`" in line for line in warning_lines(caplog))
    fixed = ingest_log(path, make_vehicle(streams_with(dvl={"clock": "log"})))
    assert checks(fixed.report, "dvl") == []


def test_clean_logs_raise_no_stamp_warning(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="pipeline.ingest"):
        out = ingest_log(h.write_mcap(tmp_path / "ok.mcap", h.trial(n=12)), make_vehicle(LOG_STREAMS))
    assert all(s["stamp_warnings"] == [] for s in out.report["streams"].values())
    assert warning_lines(caplog) == []
    assert "time_rate_hz" not in out.provenance["dvl"]


def test_time_rate_on_a_topic_rebuilds_from_the_first_stamp(tmp_path: Path) -> None:
    msgs = h.trial(n=12)
    path = h.write_mcap(tmp_path / "r.mcap", msgs)
    out = ingest_log(path, make_vehicle(streams_with(thr={"clock": "log", "time": {"rate_hz": 10},
                                                          "offset_s": 0.25})))
    first = int(h.expected(msgs)[THR]["log_ns"][0])
    np.testing.assert_array_equal(out.tables["thr"]["t_ns"].to_numpy(),
                                  first + 250_000_000 + np.arange(12, dtype=np.int64) * 100_000_000)
    assert out.report["streams"]["thr"]["time_rate_hz"] == 10 and out.provenance["thr"]["time_rate_hz"] == 10


# -- CSV tables: the time column -------------------------------------------------------------------------------
TANK_STREAMS = {
    "tank": {"file": "run.dat", "clock": "column",
             "csv": {"time_column": "t", "delimiter": " ", "header": False, "columns": ["t", "x", "r"],
                     "skip_rows": 2},
             "signals": {"u_mps": {"field": "x"}, "n1_rpm": {"field": "r"}}},
}
N_TANK = 600


def write_tank(directory: Path, times_s: list[str], extra_rows: str = "") -> Path:
    """A whitespace table with a preamble, no header: t, x, r; x is the row index."""
    directory.mkdir(parents=True, exist_ok=True)
    rows = [f"{t} {i}.0 {2 * i}.0" for i, t in enumerate(times_s)]
    (directory / "run.dat").write_text("tank run 7\nsampled at 20 Hz\n" + "\n".join(rows) + "\n" + extra_rows)
    return directory


def three_digits(n: int = N_TANK, rate_hz: float = 20.0) -> list[str]:
    return [f"{float(f'{k / rate_hz + 0.05:.3g}')}" for k in range(n)]


def tank_vehicle(time: dict[str, Any] | None = None) -> Any:
    streams = json.loads(json.dumps(TANK_STREAMS))
    if time is not None:
        streams["tank"]["time"] = time
    return make_vehicle(streams)


def test_quantized_time_column_warns_and_time_rate_fixes_it(tmp_path: Path,
                                                            caplog: pytest.LogCaptureFixture) -> None:
    trial = write_tank(tmp_path / "zigzag2", three_digits())
    with caplog.at_level(logging.WARNING, logger="pipeline.ingest"):
        out = ingest_log(trial, tank_vehicle())
    assert checks(out.report, "tank") == ["duplicates", "quantized"]
    stamps = out.report["streams"]["tank"]["stamps"]
    t_ns = out.tables["tank"]["t_ns"].to_numpy()
    # 0.05 .. 9.95 s keep their 0.05 s steps; the 400 samples from 10.0 s on fall on 200 values 0.1 s apart
    assert stamps["duplicates"] == int((np.diff(t_ns) == 0).sum()) == 200
    assert stamps["distinct"] == len(np.unique(t_ns)) and stamps["count"] == N_TANK
    dup, quant = out.report["streams"]["tank"]["stamp_warnings"]
    assert f"{stamps['duplicates']} of {N_TANK} stamps of time column 't' repeat" in dup["message"]
    assert dup["examples"][0] == "10.200 s x3"  # the longest runs, earliest first
    assert "typically 0.1 s apart while the samples come every 0.05 s" in quant["message"]
    assert quant["remedy"].startswith("`time: {rate_hz: 20}`")
    lines = warning_lines(caplog)
    assert len(lines) == 2 and all(line.startswith("zigzag2 (zigzag2): stream 'tank' (run.dat)") for line in lines)

    fixed = ingest_log(trial, tank_vehicle({"rate_hz": 20}))
    assert checks(fixed.report, "tank") == []
    t_fixed = fixed.tables["tank"]["t_ns"].to_numpy()
    np.testing.assert_array_equal(t_fixed, 50_000_000 + np.arange(N_TANK, dtype=np.int64) * 50_000_000)
    np.testing.assert_array_equal(fixed.tables["tank"]["u_mps"].to_numpy(), np.arange(N_TANK))


def test_time_rate_counts_dropped_rows(tmp_path: Path) -> None:
    times = three_digits(10)
    trial = write_tank(tmp_path / "t", times, extra_rows="")
    text = (trial / "run.dat").read_text().replace(f"{times[3]} 3.0 6.0", f"{times[3]} bad 6.0")
    (trial / "run.dat").write_text(text)
    out = ingest_log(trial, tank_vehicle({"rate_hz": 20}))
    assert out.report["topics"]["run.dat"]["rows_dropped"] == 1
    np.testing.assert_array_equal(out.tables["tank"]["t_ns"].to_numpy(),
                                  50_000_000 + np.array([0, 1, 2, 4, 5, 6, 7, 8, 9]) * 50_000_000)
    text = (trial / "run.dat").read_text().replace(f"{times[0]} 0.0 0.0", f"{times[0]} 0.0 ?")
    (trial / "run.dat").write_text(text)  # the first row dropped too: time starts at the first kept stamp
    out = ingest_log(trial, tank_vehicle({"rate_hz": 20}))
    np.testing.assert_array_equal(out.tables["tank"]["t_ns"].to_numpy(),
                                  100_000_000 + np.array([0, 1, 3, 4, 5, 6, 7, 8]) * 50_000_000)


def test_constant_and_backwards_time_columns_warn(tmp_path: Path) -> None:
    out = ingest_log(write_tank(tmp_path / "c", ["12.5"] * 20), tank_vehicle())
    assert checks(out.report, "tank") == ["constant"]
    assert "all 20 stamps of time column 't' are 12.500 s" in out.report["streams"]["tank"]["stamp_warnings"][0][
        "message"]
    times = [f"{k / 20:.2f}" for k in range(40)]
    times[10], times[11] = times[11], times[10]
    out = ingest_log(write_tank(tmp_path / "b", times), tank_vehicle())
    assert checks(out.report, "tank") == ["steps_back"]
    back = out.report["streams"]["tank"]["stamp_warnings"][0]
    assert back["count"] == 1 and back["examples"] == ["message 11: 0.550 s -> 0.500 s"]
    assert "ingest sorts" in back["message"] and "rate_hz: 20" in back["remedy"]


def test_stage_writes_the_stamp_warnings_into_the_ingest_report(tmp_path: Path) -> None:
    root = tmp_path / "run"
    write_tank(root / layout.RAW / "zigzag2", three_digits())
    result = stage.run(root, tank_vehicle(), Params())
    assert result.exit_code == 0
    report = json.loads(layout.ingest_report_path(root, "zigzag2").read_text())
    assert [w["check"] for w in report["streams"]["tank"]["stamp_warnings"]] == ["duplicates", "quantized"]


# -- the checks themselves --------------------------------------------------------------------------------------
def test_check_stamps_is_quiet_on_good_stamps() -> None:
    rng = np.random.default_rng(3)
    t0 = 1_700_000_000_000_000_000
    uniform_ms = t0 + np.arange(1000, dtype=np.int64) * 50_000_000  # 20 Hz, stamps exact to the ms
    jitter = uniform_ms + rng.integers(0, 2_000_000, 1000)  # ROS log time with jitter
    dropouts = np.delete(uniform_ms, np.r_[100:180, 500:700])  # a DVL losing bottom lock
    for t in (uniform_ms, jitter, dropouts):
        assert check_stamps(t, clock="log").warnings == []
        assert check_stamps(t, clock="header", log_ns=t + 3_000_000).warnings == []
    few = np.r_[uniform_ms[:500], uniform_ms[499:]]  # one duplicate in 1000: counted, not warned
    result = check_stamps(few, clock="column")
    assert result.duplicates == 1 and result.warnings == []


def test_distinct_stamps_are_counted_in_and_out_of_order() -> None:
    # 7 stamps, 5 distinct values: a repeat next to its twin (30, 30), and a value that comes back after a step
    # back (20 again after 40), which only sorting shows to be a repeat.
    t = np.array([10, 20, 30, 30, 40, 20, 50], dtype=np.int64)
    result = check_stamps(t, clock="log")
    assert (result.count, result.distinct, result.duplicates, result.steps_back) == (7, 5, 1, 1)
    in_order = np.sort(t)  # 10 20 20 30 30 40 50: two repeats of the one before, none back
    result = check_stamps(in_order, clock="log")
    assert (result.distinct, result.duplicates, result.steps_back) == (5, 2, 0)
    assert check_stamps(np.array([7], dtype=np.int64), clock="log").distinct == 1
    assert check_stamps(np.empty(0, dtype=np.int64), clock="log").distinct == 0


def test_median_step_and_header_minus_log_are_exact() -> None:
    ms = 1_000_000
    t = np.array([0, 10, 30, 60, 100], dtype=np.int64) * ms  # intervals 10 20 30 40: median 25 ms
    log = t - np.array([3, 1, 2, 5, 4], dtype=np.int64) * ms  # header - log: median 3 ms
    result = check_stamps(t, clock="header", log_ns=log)
    assert (result.median_step_s, result.header_minus_log_s) == (0.025, 0.003)
    assert t.tolist() == [0, 10 * ms, 30 * ms, 60 * ms, 100 * ms]  # the caller's stamps are left as they were
    # a repeat and a step back: the median is of the positive intervals only (10 20 30 90 -> 25 ms)
    t = np.array([0, 10, 30, 30, 0, 90, 120], dtype=np.int64) * ms
    result = check_stamps(t, clock="header", log_ns=t - 2 * ms)
    assert (result.median_step_s, result.header_minus_log_s, result.steps_back) == (0.025, 0.002, 1)


def test_time_stats_count_steps_back_and_the_largest_gap_across_blocks() -> None:
    ms = 1_000_000
    t = np.array([0, 10, 20, 5, 30, 100, 110, 90, 200], dtype=np.int64) * ms
    # intervals 10 10 -15 25 70 10 -20 110: two steps back, the largest interval 110 ms; in time order the stamps are
    # 0 5 10 20 30 90 100 110 200, whose largest gap is 90 ms (what the report calls the largest gap)
    for block in (1, 2, 3, 4, 5, 8, 64):
        assert _steps(t, block) == (2, 110 * ms)
        assert _steps(np.sort(t), block) == (0, 90 * ms)
    stats = time_stats(t)
    assert (stats["count"], stats["steps_back"], stats["largest_gap_s"]) == (9, 2, 0.09)
    assert (stats["first_ns"], stats["last_ns"], stats["span_s"]) == (0, 200 * ms, 0.2)
    # 10 ms steps with one 120 ms drop-out late in a long stream (past the first blocks of 65,536 intervals)
    long = np.r_[np.arange(100_000), 100_011 + np.arange(50_000)].astype(np.int64) * 10 * ms
    stats = time_stats(long)
    assert (stats["steps_back"], stats["largest_gap_s"]) == (0, 0.12)
    assert stats["mean_rate_hz"] == pytest.approx(149_999 / 1500.10)  # intervals / span in s
    assert time_stats(long[:1])["largest_gap_s"] is None and time_stats(long[:0])["count"] == 0
    as_float = time_stats(t.astype(np.float64))  # stamps of another dtype: the same figures, no casting error
    assert (as_float["steps_back"], as_float["largest_gap_s"]) == (2, 0.09)


def test_uniform_times_do_not_drift() -> None:
    t = uniform_times(7, np.arange(3_000_001), 3.0)
    assert t[0] == 7 and t[3] == 7 + 1_000_000_000 and t[-1] == 7 + 1_000_000 * 1_000_000_000


# -- end to end on a simulated trial: zero header stamps, the warning, the sync error, the fix --------------------
def test_simulator_bag_with_zero_thruster_stamps_from_warning_to_fix(tmp_path: Path,
                                                                    caplog: pytest.LogCaptureFixture) -> None:
    from dataclasses import replace

    from pipeline.errors import SyncError
    from pipeline.sim import generate_trial, load_example_vehicle, write_trial
    from pipeline.sync import synchronize

    vehicle = load_example_vehicle()
    trial = generate_trial(vehicle, duration_s=8.0, seed=1)
    thr = trial.streams["thrusters"]
    trial.streams["thrusters"] = replace(thr, header_ns=np.zeros_like(thr.header_ns))
    path = write_trial(trial, "mcap", tmp_path / "simbag.mcap")
    with caplog.at_level(logging.WARNING, logger="pipeline.ingest"):
        out = ingest_log(path, vehicle)
    assert checks(out.report, "thrusters") == ["zero"]
    assert all(checks(out.report, s) == [] for s in out.report["streams"] if s != "thrusters")
    assert any("stream 'thrusters'" in line and "are 0" in line for line in warning_lines(caplog))
    with pytest.raises(SyncError, match=r"'thrusters': 0.000 s to 0.000 s \(all \d+ stamps equal\) <- overlaps none"):
        synchronize(out.tables, vehicle, Params().sync)

    streams = {**vehicle.streams, "thrusters": vehicle.streams["thrusters"].model_copy(update={"clock": "log"})}
    fixed_vehicle = vehicle.model_copy(update={"streams": streams})
    fixed = ingest_log(path, fixed_vehicle)
    assert checks(fixed.report, "thrusters") == []
    frame = synchronize(fixed.tables, fixed_vehicle, Params().sync)
    assert (frame["segment"] >= 0).mean() > 0.8
