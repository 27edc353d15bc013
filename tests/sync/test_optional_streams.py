"""Optional streams (issue 14, item 5): a trial without one goes on, its signals invalid; a needed one quarantines.

Ingest lists the absent stream (source, reason, signals) under ``absent_streams`` and logs a warning; sync gives its
signals as NaN with ``__valid`` False; differentiate goes on with them NaN and everything else unchanged.
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
from pipeline.config import Params, Vehicle, parse
from pipeline.config.params import DifferentiateParams, SyncParams
from pipeline.errors import IngestError, SchemaError
from pipeline.estimation.differentiate import differentiate
from pipeline.ingest import ingest_log
from pipeline.sync import synchronize
from tests.sync.helpers import constant_streams, vehicle_dict

T0_MS = 1_700_000_000_000
NAV = {"file": "nav.csv", "clock": "column", "csv": {"time_column": "t", "time_unit": "ms"},
       "signals": {"u_mps": {"field": "u"}, "v_mps": {"field": "v"}, "w_mps": {"field": "w"},
                   "yaw_rad": {"field": "yaw"}, "n1_rpm": {"field": "n1"}}}
DEPTH_CSV = {"file": "depth*.csv", "clock": "column", "optional": True,
             "csv": {"time_column": "t", "time_unit": "ms"}, "signals": {"depth_m": {"field": "d", "unit": "cm"}}}


def vehicle(streams: dict[str, Any]) -> Vehicle:
    return Vehicle.model_validate({
        "name": "testbot",
        "rigid_body": {"mass_kg": 10, "inertia_kgm2": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]},
        "added_mass": [[0.0] * 6 for _ in range(6)],
        "thrusters": [{"name": "t1", "speed_signal": "n1_rpm", "position_m": [0, 0, 0], "direction": [1, 0, 0],
                       "thrust": {"k_fwd_N_per_rpm2": 1e-5}}],
        "sensors": {"dvl": {"velocity": ["u_mps", "v_mps", "w_mps"]}, "attitude": {"yaw": "yaw_rad"},
                    "depth": "depth_m"},
        "streams": {"nav": NAV, **streams},
    })


def csv_trial(directory: Path, *, depth: bool, n: int = 10) -> Path:
    directory.mkdir(parents=True)
    t = T0_MS + 100 * np.arange(n)
    (directory / "nav.csv").write_text("t,u,v,w,yaw,n1\n" + "".join(f"{x},0.5,0,0,0.1,900\n" for x in t))
    if depth:
        (directory / "depth_a.csv").write_text("t,d\n" + "".join(f"{x},{250 + i}\n" for i, x in enumerate(t)))
    return directory


def test_optional_csv_file_absent_goes_on_and_is_reported(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    v = vehicle({"depth": DEPTH_CSV})
    with_depth = ingest_log(csv_trial(tmp_path / "trial01", depth=True), v)
    assert set(with_depth.tables) == {"nav", "depth"} and with_depth.report["absent_streams"] == {}
    np.testing.assert_allclose(with_depth.tables["depth"]["depth_m"].to_numpy(), (250 + np.arange(10)) / 100)

    with caplog.at_level(logging.WARNING, logger="pipeline.ingest"):
        out = ingest_log(csv_trial(tmp_path / "trial02", depth=False), v)
    assert not out.quarantine and set(out.tables) == {"nav"}
    absent = out.report["absent_streams"]["depth"]
    assert absent["file"] == "depth*.csv" and absent["signals"] == ["depth_m"]
    assert "no CSV file matches 'depth*.csv'" in absent["reason"] and "nav.csv" in absent["reason"]
    assert any("optional stream 'depth'" in r.getMessage() and "trial02" in r.getMessage() for r in caplog.records)

    required = vehicle({"depth": {**DEPTH_CSV, "optional": False}})
    with pytest.raises(IngestError, match=r"no CSV file matches 'depth\*.csv'"):
        ingest_log(tmp_path / "trial02", required)


def test_stage_writes_the_trial_without_the_optional_stream(tmp_path: Path) -> None:
    root = tmp_path / "run"
    csv_trial(root / layout.RAW / "trial01", depth=True)
    csv_trial(root / layout.RAW / "trial02", depth=False)
    result = stage.run(root, vehicle({"depth": DEPTH_CSV}), Params())
    assert result.quarantined == []
    assert sorted(p.name for p in layout.signals_dir(root, "trial02").iterdir()) == ["ingest_report.json",
                                                                                    "nav.parquet"]
    report = json.loads(layout.ingest_report_path(root, "trial02").read_text())
    assert report["absent_streams"]["depth"]["signals"] == ["depth_m"]

    result = stage.run(root, vehicle({"depth": {**DEPTH_CSV, "optional": False}}), Params())
    assert [q["trial"] for q in result.quarantined] == ["trial02"]
    assert "depth*.csv" in result.quarantined[0]["reason"]
    assert not layout.signals_dir(root, "trial02").exists()


ROS_STREAMS: dict[str, Any] = {
    "imu": {"topic": "/ahrs/imu", "clock": "header", "signals": {"r_radps": {"field": "angular_velocity.z"}}},
    "depth": {"topic": "/depth", "clock": "log", "optional": True, "signals": {"depth_m": {"field": "data"}}},
}


def test_optional_topic_absent_from_a_bag(tmp_path: Path) -> None:
    from tests.io import helpers as h

    msgs = h.trial(n=6)
    path = h.write_mcap(tmp_path / "dive1.mcap", msgs)
    out = ingest_log(path, vehicle(ROS_STREAMS))
    assert not out.quarantine and set(out.tables) == {"imu"}
    np.testing.assert_array_equal(out.tables["imu"]["r_radps"].to_numpy(),
                                  h.expected(msgs)["/ahrs/imu"]["angular_velocity.z"])
    assert out.report["absent_streams"]["depth"]["topic"] == "/depth"
    assert "topic not in dive1.mcap; available: ['/ahrs/imu'" in out.report["absent_streams"]["depth"]["reason"]
    assert out.report["skipped_streams"] == {"nav": "reads a CSV file; this log is mcap"}

    streams = json.loads(json.dumps(ROS_STREAMS))
    streams["depth"]["optional"] = False
    with pytest.raises(IngestError, match=r"'/depth' not in dive1.mcap") as info:
        ingest_log(path, vehicle(streams))
    assert info.value.topic == "/depth"


def test_optional_stream_without_a_definition_is_absent_with_the_reason(tmp_path: Path) -> None:
    from tests.io.test_io_msgdefs import RC, write_bag

    bag = write_bag(tmp_path / "dive03", definitions="none")
    streams = {"rc": {"topic": "/mavros/rc/override", "clock": "log", "optional": True,
                      "signals": {"pwm1_1": {"field": "channels[0]"}}},
               "depth": {"topic": "/bluerov/depth", "clock": "log", "signals": {"depth_m": {"field": "data"}}}}
    out = ingest_log(bag, vehicle(streams))
    assert not out.quarantine and set(out.tables) == {"depth"}
    reason = out.report["absent_streams"]["rc"]["reason"]
    assert RC in reason and "`message_definitions`" in reason


def _synced(optional: bool, drop: str) -> tuple[Vehicle, dict[str, Any], Any]:
    doc = vehicle_dict()
    doc["streams"][drop]["optional"] = optional
    v = parse(Vehicle, doc)
    streams = constant_streams(10.0)
    del streams[drop]
    return v, streams, SyncParams(min_segment_s=1)


def test_sync_and_differentiate_carry_an_absent_optional_signal_as_invalid() -> None:
    v, streams, params = _synced(True, "depth")
    full = synchronize(constant_streams(10.0), v, params)
    out = synchronize(streams, v, params)
    assert out.attrs["absent_signals"] == {"depth_m": "depth"}
    assert np.isnan(out["depth_m"]).all() and not out["depth_m__valid"].any()
    assert out.columns.tolist() == full.columns.tolist()
    np.testing.assert_array_equal(out["segment"], full["segment"])  # depth is not required: segments unchanged
    noise = {n: 0.01 for n in v.signal_names()}
    for method in ("kalman", "gaussian"):
        p = DifferentiateParams(method=method, noise_sd=noise, sigma_s=0.2)
        kin, _ = differentiate(out, v, p, streams)
        ref, _ = differentiate(full, v, p, constant_streams(10.0))
        assert np.isnan(kin["depth_m"]).all() and len(kin) == len(ref) > 0
        rest = [c for c in ref.columns if not c.startswith("depth")]
        np.testing.assert_allclose(kin[rest].to_numpy(float), ref[rest].to_numpy(float), equal_nan=True)


def test_sync_names_a_required_signal_of_an_absent_optional_stream() -> None:
    v, streams, params = _synced(True, "thrusters")
    with pytest.raises(SchemaError, match=r"stream\(s\) \['thrusters'\] are optional and absent from this trial, "
                                          r"but carry the required signal\(s\) \['n1_rpm', 'n2_rpm', 'n3_rpm'\]"):
        synchronize(streams, v, params)
