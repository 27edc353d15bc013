"""Ingest core and stage: clocks, offsets, units, provenance, determinism, quarantine, all-or-nothing writes."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq
import pytest
import yaml

import pipeline.ingest as ingest_mod
import stages.ingest as stage
from pipeline import cli, layout
from pipeline.config import Params, Vehicle, config_hash
from pipeline.errors import IngestError
from pipeline.ingest import ingest_log, trial_id
from pipeline.io.base import ReadResult, TopicData, TopicInfo
from pipeline.tableio import file_sha256, read_parquet

N = 20
T0_NS = 1_700_000_000_000_000_000
DT_NS = 50_000_000


def make_vehicle(streams: dict[str, Any]) -> Vehicle:
    # The sensors' and thruster's signals that ``streams`` lacks come from a stream of the other kind (a CSV file
    # for a bag, a topic for a CSV directory), which this log skips: the config is valid, the log reads ``streams``.
    defined = {sig for st in streams.values() for sig in st["signals"]}
    filler = {n: {"field": n} for n in ("u_mps", "v_mps", "w_mps", "yaw_rad", "n1_rpm") if n not in defined}
    if filler:
        csv = any("file" in st for st in streams.values())
        other = {"topic": "/filler", "clock": "log"} if csv else \
            {"file": "filler.csv", "clock": "column", "csv": {"time_column": "t"}}
        streams = {**streams, "filler": {**other, "signals": filler}}
    return Vehicle.model_validate({
        "name": "testbot",
        "rigid_body": {"mass_kg": 10, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": "t1", "speed_signal": "n1_rpm", "position_m": [0, 0, 0],
                       "direction": [1, 0, 0], "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
        "sensors": {"dvl": {"velocity": ["u_mps", "v_mps", "w_mps"]}, "attitude": {"yaw": "yaw_rad"}},
        "streams": streams,
    })


CSV_STREAMS = {
    "fog": {"file": "fog.csv", "clock": "column", "offset_s": 0.25,
            "csv": {"time_column": "t", "time_unit": "ms"},
            "signals": {"r_fog_radps": {"field": "rate", "unit": "deg/s"},
                        "n1_rpm": {"field": "n1", "unit": "rad/s"}}},
}


def write_csv_trial(directory: Path, n: int = N, extra: str = "") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    directory.mkdir(parents=True, exist_ok=True)
    t_ms = T0_NS // 1_000_000 + np.arange(n) * 50
    rate = np.linspace(-90.0, 90.0, n)
    n1 = np.linspace(0.0, 2 * math.pi, n)
    rows = [f"{t},{float(r)!r},{float(w)!r}" for t, r, w in zip(t_ms, rate, n1, strict=True)]
    (directory / "fog.csv").write_text("t,rate,n1\n" + "\n".join(rows) + "\n" + extra)
    return t_ms, rate, n1


# -- core, CSV ------------------------------------------------------------------------------------------------
def test_csv_trial_units_offset_provenance_report(tmp_path: Path) -> None:
    t_ms, rate, n1 = write_csv_trial(tmp_path / "trial07")
    vehicle = make_vehicle(CSV_STREAMS)
    out = ingest_log(tmp_path / "trial07", vehicle)
    assert out.trial == "trial07" and not out.quarantine
    table = out.tables["fog"]
    assert table.column_names == ["t_ns", "r_fog_radps", "n1_rpm"]
    np.testing.assert_array_equal(table["t_ns"].to_numpy(), t_ms * 1_000_000 + 250_000_000)
    np.testing.assert_array_equal(table["r_fog_radps"].to_numpy(), rate * (math.pi / 180.0))
    np.testing.assert_array_equal(table["n1_rpm"].to_numpy(), n1 * (60.0 / (2.0 * math.pi)))
    assert table["n1_rpm"].to_numpy()[-1] == pytest.approx(60.0, rel=1e-15)
    prov = out.provenance["fog"]
    assert prov["trial"] == "trial07" and prov["stream"] == "fog" and prov["file"] == "fog.csv"
    assert prov["source_sha256"] == file_sha256(tmp_path / "trial07")
    assert prov["config_hash"] == config_hash(vehicle)
    assert prov["clock"] == "column" and prov["offset_s"] == 0.25 and prov["message_type"] == "csv"
    assert prov["fields"]["r_fog_radps"] == {"signal": "r_fog_radps", "field": "rate", "unit": "deg/s"}
    topic = out.report["topics"]["fog.csv"]
    assert topic["messages_read"] == topic["messages_in_storage"] == N and topic["lost"] == 0
    stream = out.report["streams"]["fog"]
    assert stream["largest_gap_s"] == pytest.approx(0.05) and stream["mean_rate_hz"] == pytest.approx(20.0)
    json.dumps(out.report)  # JSON-able


def test_csv_unparseable_rows_are_reported_not_lost_silently(tmp_path: Path) -> None:
    write_csv_trial(tmp_path / "tr", extra=f"{T0_NS // 1_000_000 + 5000},bad,1.0\n")
    out = ingest_log(tmp_path / "tr", make_vehicle(CSV_STREAMS))
    assert out.tables["fog"].num_rows == N
    assert out.report["topics"]["fog.csv"]["rows_dropped"] == 1
    assert out.report["topics"]["fog.csv"]["rows_dropped_lines"] == [N + 2]


def test_missing_csv_column_and_file_name_them(tmp_path: Path) -> None:
    write_csv_trial(tmp_path / "tr")
    streams = json.loads(json.dumps(CSV_STREAMS))
    streams["fog"]["signals"]["r_fog_radps"]["field"] = "yaw_rate"
    with pytest.raises(IngestError, match=r"no column 'yaw_rate' in fog.csv; available: \['t', 'rate', 'n1'\]") as e:
        ingest_log(tmp_path / "tr", make_vehicle(streams))
    assert e.value.field == "yaw_rate" and e.value.topic == "fog.csv" and "tr" in str(e.value.file)
    streams["fog"]["file"] = "gyro*.csv"
    with pytest.raises(IngestError, match=r"no CSV file matches 'gyro\*.csv'; available: \['fog.csv'\]"):
        ingest_log(tmp_path / "tr", make_vehicle(streams))


def test_trial_id_strips_log_extensions() -> None:
    assert trial_id("a/trial01.mcap") == "trial01"
    assert trial_id("trial01.csv.gz") == "trial01"
    assert trial_id("bags/run_3") == "run_3"
    assert trial_id("x.bag") == "x"


# -- core, with a stand-in reader (clocks, offsets, quaternions, failures) ---------------------------------------
class FakeReader:
    format = "mcap"

    def __init__(self, path: Path, result: ReadResult, infos: dict[str, TopicInfo]) -> None:
        self.path, self._result, self._infos = path, result, infos
        self.requests: dict[str, list[str]] | None = None

    def __enter__(self) -> FakeReader:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def close(self) -> None:
        pass

    def topics(self) -> dict[str, TopicInfo]:
        return dict(self._infos)

    def read(self, requests: dict[str, list[str]]) -> ReadResult:
        self.requests = requests
        return self._result


ROS_STREAMS = {
    "imu": {"topic": "/imu", "clock": "header", "offset_s": -0.1,
            "signals": {"att_quat": {"field": "orientation"},
                        "r_radps": {"field": "angular_velocity.z", "unit": "deg/s"}}},
    "thr": {"topic": "/thr", "clock": "log", "offset_s": 0.002,
            "signals": {"n1_rpm": {"field": "velocity[name=th1]", "unit": "rad/s"}}},
}


def fake_setup(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, *, fail_thr: bool = False,
               has_header: bool = True) -> FakeReader:
    log_ns = T0_NS + np.arange(N, dtype=np.int64) * DT_NS
    header_ns = log_ns - 3_000_000 + np.array([0, 60_000_000] + [0] * (N - 2), dtype=np.int64)  # one out of order
    q = {f"orientation.{c}": np.full(N, v) for c, v in zip("wxyz", (1.0, 0.0, 0.0, 0.0), strict=True)}
    imu = TopicData("/imu", "sensor_msgs/msg/Imu", log_ns, header_ns,
                    {**q, "angular_velocity.z": np.arange(N, dtype=np.float64)}, "fast", N, N)
    thr = TopicData("/thr", "sensor_msgs/msg/JointState", log_ns, header_ns,
                    {"velocity[name=th1]": np.full(N, 2 * math.pi)}, "per-message", N, N)
    topics = {"/imu": imu} if fail_thr else {"/imu": imu, "/thr": thr}
    failed = {"/thr": "decoding failed: struct.error"} if fail_thr else {}
    infos = {t: TopicInfo(t, d.msgtype, N, int(log_ns[0]), int(log_ns[-1]), has_header)
             for t, d in (("/imu", imu), ("/thr", thr))}
    infos["/other"] = TopicInfo("/other", "std_msgs/msg/Float64", 3, None, None, False)
    log_file = tmp_path / "run1.mcap"
    log_file.write_bytes(b"stand-in")
    reader = FakeReader(log_file, ReadResult(topics=topics, failed=failed), infos)
    monkeypatch.setattr(ingest_mod, "_open", lambda path, definitions=None, text_limits=None: reader)
    return reader


def test_header_and_log_clocks_offsets_quaternion_exact(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    reader = fake_setup(tmp_path, monkeypatch)
    out = ingest_log(tmp_path / "run1.mcap", make_vehicle(ROS_STREAMS))
    assert reader.requests == {"/imu": ["orientation.w", "orientation.x", "orientation.y", "orientation.z",
                                        "angular_velocity.z"], "/thr": ["velocity[name=th1]"]}
    imu = out.tables["imu"]
    assert imu.column_names == ["t_ns", "att_quat_w", "att_quat_x", "att_quat_y", "att_quat_z", "r_radps"]
    log_ns = T0_NS + np.arange(N, dtype=np.int64) * DT_NS
    header = log_ns - 3_000_000
    header[1] += 60_000_000
    order = np.argsort(header, kind="stable")
    np.testing.assert_array_equal(imu["t_ns"].to_numpy(), header[order] - 100_000_000)
    np.testing.assert_array_equal(imu["r_radps"].to_numpy(), np.arange(N)[order] * (math.pi / 180.0))
    assert np.all(np.diff(imu["t_ns"].to_numpy()) >= 0)
    thr = out.tables["thr"]
    np.testing.assert_array_equal(thr["t_ns"].to_numpy(), log_ns + 2_000_000)
    np.testing.assert_array_equal(thr["n1_rpm"].to_numpy(), np.full(N, 60.0))
    assert out.provenance["imu"]["topic"] == "/imu" and out.provenance["imu"]["clock"] == "header"
    assert out.provenance["imu"]["decode_path"] == "fast"
    assert out.provenance["thr"]["decode_path"] == "per-message"
    assert out.provenance["imu"]["fields"]["att_quat_x"]["field"] == "orientation.x"
    assert out.report["streams"]["imu"]["steps_back"] == 1


def test_header_clock_without_header_names_topic(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake_setup(tmp_path, monkeypatch, has_header=False)
    with pytest.raises(IngestError, match="has no header") as info:
        ingest_log(tmp_path / "run1.mcap", make_vehicle(ROS_STREAMS))
    assert info.value.topic == "/imu"


def test_missing_topic_lists_available(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake_setup(tmp_path, monkeypatch)
    streams = json.loads(json.dumps(ROS_STREAMS))
    streams["thr"]["topic"] = "/thrusters"
    with pytest.raises(IngestError, match=r"'/thrusters' not in run1.mcap; available: \['/imu', '/other', '/thr'\]"):
        ingest_log(tmp_path / "run1.mcap", make_vehicle(streams))


def test_failed_topic_makes_quarantine_reason(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    fake_setup(tmp_path, monkeypatch, fail_thr=True)
    out = ingest_log(tmp_path / "run1.mcap", make_vehicle(ROS_STREAMS))
    assert [q["stream"] for q in out.quarantine] == ["thr"]
    assert "struct.error" in out.quarantine[0]["reason"]
    assert out.report["failed_topics"] == {"/thr": "decoding failed: struct.error"}


# -- stage -------------------------------------------------------------------------------------------------------
def raw_root(tmp_path: Path) -> Path:
    root = tmp_path / "run"
    write_csv_trial(root / layout.RAW / "trial01")
    write_csv_trial(root / layout.RAW / "trial02", n=N + 5)
    return root


def test_stage_writes_trials_byte_identical_on_rerun(tmp_path: Path) -> None:
    root = raw_root(tmp_path)
    vehicle = make_vehicle(CSV_STREAMS)
    seen: list[str] = []
    result = stage.run(root, vehicle, Params(), progress=seen.append)
    assert result.exit_code == 0 and not result.quarantined and len(seen) == 2
    first = layout.stream_path(root, "trial01", "fog")
    table, meta = read_parquet(first)
    assert table.num_rows == N and meta["source_file"] == "data/raw/trial01" and meta["schema_version"]
    assert json.loads(layout.ingest_report_path(root, "trial02").read_text())["streams"]["fog"]["count"] == N + 5
    before = first.read_bytes()
    stage.run(root, vehicle, Params())
    assert first.read_bytes() == before
    other = tmp_path / "elsewhere"  # a copy of the run directory gives the same bytes
    write_csv_trial(other / layout.RAW / "trial01")
    stage.run(other, vehicle, Params(), logs=[other / layout.RAW / "trial01"])
    assert layout.stream_path(other, "trial01", "fog").read_bytes() == before
    assert pq.read_table(first).schema.field("t_ns").type == "int64"


def test_batch_quarantines_bad_file_and_goes_on(tmp_path: Path) -> None:
    root = raw_root(tmp_path)
    bad = root / layout.RAW / "trial03"
    bad.mkdir()
    (bad / "fog.csv").write_text("t,rate\n1,2\n")  # no n1 column
    empty = root / layout.RAW / "trial04"
    empty.mkdir()
    (empty / "fog.csv").write_text("")
    raw_before = {p: p.read_bytes() for p in (root / layout.RAW).rglob("*") if p.is_file()}
    result = stage.run(root, make_vehicle(CSV_STREAMS), Params())
    assert result.exit_code == 1
    by_trial = {e["trial"]: e for e in result.quarantined}
    assert set(by_trial) == {"trial03", "trial04"}
    assert by_trial["trial03"]["field"] == "n1" and by_trial["trial03"]["error"] == "IngestError"
    assert by_trial["trial03"]["file"] == "data/raw/trial03" and "no column 'n1'" in by_trial["trial03"]["reason"]
    assert "empty" in by_trial["trial04"]["reason"]
    assert layout.stream_path(root, "trial01", "fog").exists() and layout.stream_path(root, "trial02", "fog").exists()
    assert not layout.signals_dir(root, "trial03").exists()
    summary = json.loads((root / layout.SIGNALS / "quarantine.json").read_text())
    assert [e["trial"] for e in summary["quarantined"]] == ["trial03", "trial04"]
    assert summary["trials_written"] == ["trial01", "trial02"]
    assert {p: p.read_bytes() for p in (root / layout.RAW).rglob("*") if p.is_file()} == raw_before


def test_crash_mid_trial_leaves_no_half_written_directory(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    root = raw_root(tmp_path)
    streams = {**CSV_STREAMS, "fog2": {**CSV_STREAMS["fog"], "signals": {"r2_radps": {"field": "rate"}}}}
    vehicle = make_vehicle(streams)
    stage.run(root, vehicle, Params(), logs=[root / layout.RAW / "trial01"])
    old = {p.name: p.read_bytes() for p in layout.signals_dir(root, "trial01").iterdir()}
    calls = {"n": 0}
    real = stage.write_parquet

    def crashing(*args: Any, **kwargs: Any) -> Path:
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt("power cut")
        return real(*args, **kwargs)

    monkeypatch.setattr(stage, "write_parquet", crashing)
    with pytest.raises(KeyboardInterrupt):
        stage.run(root, vehicle, Params(), logs=[root / layout.RAW / "trial02"])
    with pytest.raises(KeyboardInterrupt):
        calls["n"] = 0
        stage.run(root, vehicle, Params(), logs=[root / layout.RAW / "trial01"])
    signals = root / layout.SIGNALS
    assert not (signals / "trial02").exists()
    assert {p.name: p.read_bytes() for p in layout.signals_dir(root, "trial01").iterdir()} == old
    assert sorted(p.name for p in signals.iterdir()) == ["quarantine.json", "trial01"]


def test_main_cli_with_logs(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = raw_root(tmp_path)
    vfile = tmp_path / "vehicle.yaml"
    vfile.write_text(yaml.safe_dump(make_vehicle(CSV_STREAMS).model_dump(mode="json"), allow_unicode=True))
    code = stage.main(["--root", str(root), "--vehicle", str(vfile), "--logs", str(root / layout.RAW / "trial02")])
    assert code == 0
    assert "1 quarantined" not in capsys.readouterr().out
    assert layout.stream_path(root, "trial02", "fog").exists() and not layout.signals_dir(root, "trial01").exists()


# -- end to end through open_log on real logs written by rosbags / mcap (tests/io/helpers.py) ----------------------
LOG_STREAMS = {
    "dvl": {"topic": "/dvl/data", "clock": "header", "offset_s": 0.5,
            "signals": {"u_dvl_mps": {"field": "velocity.x"}, "alt_m": {"field": "altitude", "unit": "cm"},
                        "dvl_lock_flag": {"field": "bottom_lock"}}},
    "imu": {"topic": "/ahrs/imu", "clock": "log", "offset_s": -0.001,
            "signals": {"att_quat": {"field": "orientation"}, "r_radps": {"field": "angular_velocity.z",
                                                                           "unit": "deg/s"}}},
    "thr": {"topic": "/thrusters/joint_states", "clock": "header",
            "signals": {"n1_rpm": {"field": "velocity[name=th1]", "unit": "rad/s"},
                        "n3_rpm": {"field": "velocity[name=th3]", "unit": "rev/s"}}},
}


def _write_log(kind: str, directory: Path) -> Path:
    from tests.io import helpers as h

    msgs = h.trial(n=12)
    if kind == "mcap":
        return h.write_mcap(directory / "trial5.mcap", msgs)
    if kind == "ros2-sqlite3":
        return h.write_rosbag2(directory / "trial5", msgs, storage="sqlite3")
    return h.write_rosbag1(directory / "trial5.bag", msgs)


@pytest.mark.parametrize("kind", ["mcap", "ros2-sqlite3", "ros1"])
def test_real_logs_clocks_offsets_units_exact(tmp_path: Path, kind: str) -> None:
    from tests.io import helpers as h

    exp = h.expected(h.trial(n=12))
    out = ingest_log(_write_log(kind, tmp_path), make_vehicle(LOG_STREAMS))
    assert out.trial == "trial5" and not out.quarantine
    dvl, imu, thr = out.tables["dvl"], out.tables["imu"], out.tables["thr"]
    e = exp["/dvl/data"]
    np.testing.assert_array_equal(dvl["t_ns"].to_numpy(), e["header_ns"] + 500_000_000)
    np.testing.assert_array_equal(dvl["u_dvl_mps"].to_numpy(), e["velocity.x"])
    np.testing.assert_array_equal(dvl["alt_m"].to_numpy(), e["altitude"] * 1e-2)
    np.testing.assert_array_equal(dvl["dvl_lock_flag"].to_numpy(), e["bottom_lock"])
    e = exp["/ahrs/imu"]
    np.testing.assert_array_equal(imu["t_ns"].to_numpy(), e["log_ns"] - 1_000_000)
    np.testing.assert_array_equal(imu["att_quat_w"].to_numpy(), e["orientation.w"])
    np.testing.assert_array_equal(imu["att_quat_x"].to_numpy(), np.zeros(12))
    np.testing.assert_array_equal(imu["r_radps"].to_numpy(), e["angular_velocity.z"] * (math.pi / 180.0))
    e = exp["/thrusters/joint_states"]
    np.testing.assert_array_equal(thr["t_ns"].to_numpy(), e["header_ns"])
    np.testing.assert_array_equal(thr["n1_rpm"].to_numpy(), e["velocity[name=th1]"] * (60.0 / (2.0 * math.pi)))
    np.testing.assert_array_equal(thr["n3_rpm"].to_numpy(), e["velocity[name=th3]"] * 60.0)
    report = out.report["topics"]["/dvl/data"]
    assert report["messages_read"] == report["messages_in_storage"] == 12
    assert out.provenance["thr"]["message_type"].endswith("JointState")


@pytest.mark.parametrize("kind", ["mcap", "ros1"])
def test_stream_files_hold_required_columns_with_the_logs_values(tmp_path: Path, kind: str) -> None:
    """A stream has no nulls (a missing value is NaN), so its Parquet columns are REQUIRED: no definition level
    is stored per value (15-30 % of the write's CPU), and every reader sees the columns as not null."""
    from tests.io import helpers as h

    exp = h.expected(h.trial(n=12))
    root = tmp_path / "run"
    log = _write_log(kind, tmp_path)
    result = stage.run(root, make_vehicle(LOG_STREAMS), Params(), logs=[log])
    assert result.exit_code == 0 and not result.quarantined
    for stream in ("dvl", "imu", "thr"):
        path = layout.stream_path(root, "trial5", stream)
        schema = pq.ParquetFile(path).schema
        assert [schema.column(i).max_definition_level for i in range(len(schema))] == [0] * len(schema), stream
        assert not any(f.nullable for f in pq.read_schema(path)), stream
    table, _ = read_parquet(layout.stream_path(root, "trial5", "dvl"))
    np.testing.assert_array_equal(table["t_ns"].to_numpy(), exp["/dvl/data"]["header_ns"] + 500_000_000)
    np.testing.assert_array_equal(table["u_dvl_mps"].to_numpy(), exp["/dvl/data"]["velocity.x"])


def test_real_log_missing_field_and_topic_name_them(tmp_path: Path) -> None:
    path = _write_log("mcap", tmp_path)
    streams = json.loads(json.dumps(LOG_STREAMS))
    streams["dvl"]["signals"]["u_dvl_mps"]["field"] = "velocity.q"
    with pytest.raises(IngestError) as info:
        ingest_log(path, make_vehicle(streams))
    assert info.value.topic == "/dvl/data" and "velocity.q" in str(info.value) and "trial5.mcap" in str(info.value)
    streams = json.loads(json.dumps(LOG_STREAMS))
    streams["dvl"]["topic"] = "/dvl"
    with pytest.raises(IngestError, match=r"'/dvl' not in trial5.mcap; available: \['/ahrs/imu', '/dvl/data'"):
        ingest_log(path, make_vehicle(streams))


def test_stage_quarantines_garbage_and_empty_logs_among_good_ones(tmp_path: Path) -> None:
    root = tmp_path / "run"
    raw = root / layout.RAW
    raw.mkdir(parents=True)
    _write_log("mcap", raw)
    (raw / "garbage.mcap").write_bytes(b"this is not a log at all")
    (raw / "empty.bag").write_bytes(b"")
    result = stage.run(root, make_vehicle(LOG_STREAMS), Params())
    assert sorted(e["trial"] for e in result.quarantined) == ["empty", "garbage"]
    assert all(e["error"] == "IngestError" and e["file"].startswith("data/raw/") for e in result.quarantined)
    assert sorted(p.name for p in layout.signals_dir(root, "trial5").iterdir()) == [
        "dvl.parquet", "imu.parquet", "ingest_report.json", "thr.parquet"]


def test_a_log_whose_name_gives_an_unsafe_trial_id_is_quarantined_not_written_outside(tmp_path: Path) -> None:
    """'...mcap' would be trial '..': its tables would land in data/ instead of data/signals/<trial>/."""
    root = raw_root(tmp_path)
    odd = root / layout.RAW / "...csv"
    odd.write_text("t,rate\n1,2\n")
    result = stage.run(root, make_vehicle(CSV_STREAMS), Params(), logs=[odd, root / layout.RAW / "trial01"])
    assert result.exit_code == 1
    [entry] = result.quarantined
    assert entry["file"] == "data/raw/...csv" and "'..'" in entry["reason"] and "safe name" in entry["reason"]
    assert layout.stream_path(root, "trial01", "fog").exists()
    assert sorted(p.name for p in (root / layout.SIGNALS).iterdir()) == ["quarantine.json", "trial01"]


def test_two_logs_with_unsafe_names_are_quarantined_by_file_and_the_batch_goes_on(tmp_path: Path) -> None:
    """'trial 01.csv' and 'trial 02.csv' (a space is enough): both quarantined, each naming its file and the rule,
    the good trial written, exit 1; a later ingest of one of them keeps the other's entry (keyed by file)."""
    root = raw_root(tmp_path)
    for name in ("trial 01", "trial 02"):
        write_csv_trial(root / layout.RAW / name)
    vehicle = make_vehicle(CSV_STREAMS)
    result = stage.run(root, vehicle, Params())
    assert result.exit_code == 1
    by_file = {e["file"]: e for e in result.quarantined}
    assert set(by_file) == {"data/raw/trial 01", "data/raw/trial 02"}
    for name, entry in by_file.items():
        assert entry["trial"] is None and f"{name.split('/')[-1]!r}" in entry["reason"]
        assert "safe name" in entry["reason"] and "letters, digits" in entry["reason"]
    assert result.summary["quarantined"] == ["data/raw/trial 01", "data/raw/trial 02"]
    assert result.summary["trials_written"] == ["trial01", "trial02"]
    summary = json.loads((root / layout.SIGNALS / "quarantine.json").read_text())
    assert [e["file"] for e in summary["quarantined"]] == ["data/raw/trial 01", "data/raw/trial 02"]
    again = stage.run(root, vehicle, Params(), logs=[root / layout.RAW / "trial 02", root / layout.RAW / "trial01"])
    assert again.exit_code == 1
    summary = json.loads((root / layout.SIGNALS / "quarantine.json").read_text())
    assert [e["file"] for e in summary["quarantined"]] == ["data/raw/trial 01", "data/raw/trial 02"]
    vfile = tmp_path / "vehicle.yaml"
    vfile.write_text(yaml.safe_dump(vehicle.model_dump(mode="json"), allow_unicode=True))
    assert cli.main(["ingest", "--root", str(root), "--vehicle", str(vfile), "-q"]) == 1  # `auvid ingest`
