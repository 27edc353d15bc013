"""`auvid inspect`: text files (one or a directory), gaps, stamp warnings, serialization, --fields and user
message definitions, on logs written here with known stamps."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from pipeline import cli
from pipeline.io.inspect import format_inspect, inspect_log, topic_fields
from pipeline.io.msgdefs import load_user_types
from pipeline.sim import generate_trial, load_example_vehicle, write_trial
from tests.io.test_io_msgdefs import write_bag, write_msg_tree

T0_S = 1_700_000_000


def test_text_directory_lists_columns_span_rate_and_gap(tmp_path: Path) -> None:
    trial = generate_trial(load_example_vehicle(), duration_s=4.0, seed=0)
    log = write_trial(trial, "csv", tmp_path / "trial")
    info = inspect_log(log)
    dvl = info["topics"]["dvl.csv"]
    assert info["storage"] == "text" and info["messages"] == sum(len(s) for s in trial.streams.values())
    assert dvl["columns"][:3] == ["stamp_ns", "log_ns", "velocity.x"] and dvl["time_column"] == "stamp_ns"
    stamps = trial.streams["dvl"].header_ns
    assert dvl["first_ns"] == stamps[0] and dvl["last_ns"] == stamps[-1]
    assert dvl["largest_gap_s"] == pytest.approx(np.diff(stamps).max() / 1e9, abs=1e-12)
    assert info["topics"]["fog.csv"]["rate_hz"] == pytest.approx(100.0)
    assert info["duration_s"] == pytest.approx((max(s.header_ns[-1] for s in trial.streams.values())
                                                 - min(s.header_ns[0] for s in trial.streams.values())) / 1e9)
    text = format_inspect(info)
    assert "no messages" not in text and "max gap s" in text


def _tank_file(path: Path, n: int = 200) -> Path:
    """A towing-tank table: 4 preamble lines with a cp1252 degree sign, no header, whitespace, time rounded to
    3 significant digits of a 20 Hz run (stamps repeat)."""
    t = np.arange(n) / 20.0 + 100.0
    lines = ["Run 7 zig-zag 20/20", "heading in \N{DEGREE SIGN}", "x y psi delta", "-----"]
    lines += [f"  {float(f'{v:.3g}'):8.3f}  {np.sin(v):.5f}  {np.cos(v):.5f}" for v in t]
    path.write_bytes(("\r\n".join(lines) + "\r\n").encode("cp1252"))
    return path


def test_one_text_file_sniffed_with_the_stamp_warnings(tmp_path: Path) -> None:
    info = inspect_log(_tank_file(tmp_path / "run07.dat"))
    item = info["topics"]["run07.dat"]
    assert item["csv"] == {"time_column": "col1", "time_origin": "relative", "delimiter": " ", "skip_rows": 4,
                           "header": False, "columns": ["col1", "col2", "col3"], "encoding": "cp1252"}
    assert item["count"] == 200 and item["columns"] == ["col1", "col2", "col3"]
    checks = {w["check"]: w for w in item["stamp_warnings"]}
    assert {"duplicates", "quantized"} <= set(checks)
    assert "time: {rate_hz: 19.9}" in checks["quantized"]["remedy"]  # from the rounded span
    assert "WARNING quantized" in format_inspect(info)


@pytest.mark.parametrize("content", [b"", b"\n\n  \n"], ids=["no byte", "blank lines"])
def test_an_empty_text_file_is_an_empty_stream_named(tmp_path: Path, content: bytes,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "trial").mkdir()
    (tmp_path / "trial" / "dvl.csv").write_bytes(content)
    info = inspect_log(tmp_path / "trial")
    entry = info["topics"]["dvl.csv"]
    assert entry["count"] == 0 and entry["columns"] == [] and entry["csv"] is None and info["messages"] == 0
    assert "dvl.csv: columns []\n  empty file (no header or data lines)" in format_inspect(info)
    assert cli.main(["inspect", str(tmp_path / "trial")]) == 0
    out = capsys.readouterr().out
    assert "dvl.csv" in out and "empty file" in out


def test_vehicle_csv_options_win_over_the_sniffed_ones(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    (tmp_path / "log").mkdir()
    _tank_file(tmp_path / "log" / "run07.dat")
    vehicle = {
        "name": "ship", "rigid_body": {"mass_kg": 1.0, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": "p", "thrust_signal": "T_N", "position_m": [0, 0, 0], "direction": [1, 0, 0]}],
        "sensors": {"velocity": {"frame": "body", "signals": ["u_mps", "v_mps"]}, "attitude": {"yaw": "yaw_rad"}},
        "streams": {"tank": {"file": "run*.dat", "clock": "column", "time": {"rate_hz": 20},
                             "csv": {"time_column": "t", "header": False, "columns": ["t", "u", "v"],
                                     "skip_rows": 4, "encoding": "cp1252", "time_origin": "relative"},
                             "signals": {"u_mps": {"field": "u"}, "v_mps": {"field": "v"}, "yaw_rad": {"field": "u"},
                                         "T_N": {"field": "v"}}}},
    }
    path = tmp_path / "ship.yaml"
    path.write_text(json.dumps(vehicle))
    assert cli.main(["inspect", str(tmp_path / "log"), "--vehicle", str(path), "--json"]) == 0
    item = json.loads(capsys.readouterr().out)["topics"]["run07.dat"]
    assert item["options_from"] == "vehicle config" and item["columns"] == ["t", "u", "v"]
    assert item["first_ns"] == 100 * 1_000_000_000 and item["count"] == 200


def test_zero_header_stamps_warn_and_suggest_log_clock(tmp_path: Path) -> None:
    trial = generate_trial(load_example_vehicle(), duration_s=3.0, seed=0)
    trial.streams["fog"].header_ns[:] = 0
    info = inspect_log(write_trial(trial, "mcap", tmp_path / "t.mcap"))
    fog, dvl = info["topics"]["/fog/rate"], info["topics"]["/dvl/data"]
    assert info["storage"] == "mcap" and info["serialization"] == ["cdr"]
    assert [w["check"] for w in fog["stamp_warnings"]] == ["zero"] and fog["suggested_clock"] == "log"
    assert dvl["stamp_warnings"] == [] and dvl["suggested_clock"] == "header"
    log_ns = trial.streams["dvl"].log_ns
    assert dvl["largest_gap_s"] == pytest.approx(np.diff(log_ns).max() / 1e9, abs=1e-12)
    assert "/fog/rate: WARNING zero" in format_inspect(info)


def test_ros1_bag_reports_its_serialization(tmp_path: Path) -> None:
    trial = generate_trial(load_example_vehicle(), duration_s=2.0, seed=0)
    info = inspect_log(write_trial(trial, "ros1", tmp_path / "t.bag"))
    assert info["storage"] == "ros1 bag" and info["serialization"] == ["ros1"]
    assert all(t["suggested_clock"] == "header" for t in info["topics"].values())


def test_user_definitions_make_an_undecodable_type_inspectable(tmp_path: Path,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    bag = write_bag(tmp_path / "bag", definitions="none")
    bare = inspect_log(bag)["topics"]["/mavros/rc/override"]
    assert not bare["decodable"] and "message_definitions" in bare["undecodable_reason"]
    assert bare["count"] > 0 and bare["rate_hz"] == pytest.approx(20.0)  # log times need no definition
    msgs = write_msg_tree(tmp_path / "msgs")
    info = inspect_log(bag, definitions=load_user_types([msgs]))
    assert info["topics"]["/mavros/rc/override"]["decodable"]
    assert "channels[i]" in topic_fields(bag, "/mavros/rc/override", definitions=load_user_types([msgs]))["fields"]
    assert cli.main(["inspect", str(bag), "--msgs", str(msgs), "--fields", "/mavros/rc/override"]) == 0
    assert "channels[i]" in capsys.readouterr().out
