"""Per-trial overrides (issue 14, item 5): ``trials: {<name or glob>: {streams: {<stream>: {...}}}}`` changes a
stream's source options for the matching trials only (an offset measured per dive, a renamed topic or file, a stream
one trial lacks); validated at load, applied by ingest and sync, listed in the ingest report."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

import stages.ingest as stage
from pipeline import layout
from pipeline.config import Params, Vehicle, config_hash, load_vehicle, parse
from pipeline.config.params import SyncParams
from pipeline.errors import ConfigError
from pipeline.ingest import ingest_log
from pipeline.sync import synchronize
from tests.sync.helpers import constant_streams, vehicle_dict
from tests.sync.test_optional_streams import DEPTH_CSV, T0_MS, csv_trial, vehicle


def with_trials(trials: dict[str, Any], streams: dict[str, Any] | None = None) -> Vehicle:
    base = vehicle(streams if streams is not None else {"depth": {**DEPTH_CSV, "optional": False}})
    return parse(Vehicle, {**base.model_dump(mode="json", exclude_unset=True), "trials": trials})


def test_offset_and_file_overridden_for_one_trial_only(tmp_path: Path) -> None:
    root = tmp_path / "run"
    csv_trial(root / layout.RAW / "trial01", depth=True)
    (csv_trial(root / layout.RAW / "trial02", depth=True) / "depth_a.csv").rename(
        root / layout.RAW / "trial02" / "pressure.csv")
    v = with_trials({"trial02": {"streams": {"nav": {"offset_s": 0.25}, "depth": {"file": "pressure.csv"}}}})
    result = stage.run(root, v, Params())
    assert result.quarantined == []
    t = (T0_MS + 100 * np.arange(10)) * 1_000_000
    for trial, shift_ns in (("trial01", 0), ("trial02", 250_000_000)):
        out = ingest_log(root / layout.RAW / trial, v)
        np.testing.assert_array_equal(out.tables["nav"]["t_ns"].to_numpy(), t + shift_ns)
        np.testing.assert_array_equal(out.tables["depth"]["t_ns"].to_numpy(), t)  # depth: no override
        np.testing.assert_allclose(out.tables["depth"]["depth_m"].to_numpy(), (250 + np.arange(10)) / 100)
        assert out.report["config_hash"] == config_hash(v)  # lineage: the whole config, as every stage records it
    reports = {tr: json.loads(layout.ingest_report_path(root, tr).read_text()) for tr in ("trial01", "trial02")}
    assert reports["trial01"]["trial_overrides"] == {}
    assert reports["trial01"]["streams"]["nav"]["offset_s"] == 0.0
    assert reports["trial02"]["trial_overrides"] == {
        "trial02": {"nav": {"offset_s": 0.25}, "depth": {"file": "pressure.csv"}}}
    assert reports["trial02"]["streams"]["nav"]["offset_s"] == 0.25
    assert reports["trial02"]["streams"]["depth"]["file"] == "pressure.csv"


def test_stream_optional_in_one_trial_by_glob(tmp_path: Path) -> None:
    root = tmp_path / "run"
    csv_trial(root / layout.RAW / "shore01", depth=False)
    csv_trial(root / layout.RAW / "sea01", depth=False)
    v = with_trials({"shore*": {"streams": {"depth": {"optional": True}}}})
    result = stage.run(root, v, Params())
    assert [q["trial"] for q in result.quarantined] == ["sea01"]  # depth needed there
    report = json.loads(layout.ingest_report_path(root, "shore01").read_text())
    assert report["absent_streams"]["depth"]["signals"] == ["depth_m"]
    assert report["trial_overrides"] == {"shore*": {"depth": {"optional": True}}}


def test_later_matching_key_wins_and_sync_sees_the_trial_streams() -> None:
    doc = vehicle_dict()
    doc["trials"] = {"dive*": {"streams": {"depth": {"optional": True, "offset_s": 0.1}}},
                     "dive2": {"streams": {"depth": {"offset_s": 0.2}}}}
    v = parse(Vehicle, doc)
    assert v.for_trial("dive2").streams["depth"].offset_s == 0.2
    assert v.for_trial("dive2").streams["depth"].optional
    assert v.for_trial("dive1").streams["depth"].offset_s == 0.1
    assert v.for_trial("other") is v and not v.streams["depth"].optional
    streams = constant_streams(10.0)
    del streams["depth"]
    params = SyncParams(min_segment_s=1)
    out = synchronize(streams, v.for_trial("dive2"), params)
    assert out.attrs["absent_signals"] == {"depth_m": "depth"} and not out["depth_m__valid"].any()
    plain = synchronize(streams, v.for_trial("other"), params)  # depth not optional there: not carried as invalid
    assert not plain.attrs.get("absent_signals") and "depth_m__valid" not in plain.columns


def test_topic_renamed_in_one_recording(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from tests.io import helpers as h

    imu = {"imu": {"topic": "/ahrs/imu", "clock": "header", "signals": {"r_radps": {"field": "angular_velocity.z"}}}}
    msgs = h.trial(n=6)
    h.write_mcap(tmp_path / "dive1.mcap", msgs)
    renamed = [h.Msg("/imu/data" if m.topic == "/ahrs/imu" else m.topic, m.msgtype, m.log_ns, m.stamp_ns, m.values)
               for m in msgs]
    monkeypatch.setattr(h, "TOPICS", {("/imu/data" if t == "/ahrs/imu" else t): ty for t, ty in h.TOPICS.items()})
    h.write_mcap(tmp_path / "dive2.mcap", renamed)
    v = with_trials({"dive2": {"streams": {"imu": {"topic": "/imu/data", "offset_s": -0.5}}}},
                    {"depth": DEPTH_CSV, **imu})
    want = h.expected(msgs)["/ahrs/imu"]
    one, two = ingest_log(tmp_path / "dive1.mcap", v), ingest_log(tmp_path / "dive2.mcap", v)
    for out, shift_ns in ((one, 0), (two, -500_000_000)):
        np.testing.assert_array_equal(out.tables["imu"]["r_radps"].to_numpy(), want["angular_velocity.z"])
        np.testing.assert_array_equal(out.tables["imu"]["t_ns"].to_numpy(), np.sort(want["header_ns"]) + shift_ns)
    assert one.provenance["imu"]["topic"] == "/ahrs/imu" and two.provenance["imu"]["topic"] == "/imu/data"


@pytest.mark.parametrize(("override", "key", "says"), [
    ({"nope": {"offset_s": 1.0}}, "trials", "trials.dive2.streams.nope: no stream 'nope' to override"),
    ({"nav": {"offset": 1.0}}, "trials.dive2.streams.nav.offset", "Extra inputs are not permitted"),
    ({"nav": {"topic": "/nav"}}, "trials", "trials.dive2.streams.nav: (stream): Value error, give exactly one of"),
    ({"nav": {"signals": {"x_m": {"field": "x"}}}}, "trials", "trials.dive2.streams.nav: signals ['x_m'] are not"),
])
def test_bad_override_is_refused_at_load_with_the_key_path(tmp_path: Path, override: dict[str, Any], key: str,
                                                           says: str) -> None:
    doc = vehicle({"depth": DEPTH_CSV}).model_dump(mode="json", exclude_unset=True)
    doc["trials"] = {"dive2": {"streams": override}}
    path = tmp_path / "vehicle.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(ConfigError) as info:
        load_vehicle(path)
    assert info.value.field == key and says in str(info.value) and "vehicle.yaml" in str(info.value)


def test_overrides_that_clash_only_together_are_a_config_error_naming_both_keys() -> None:
    """Each override is valid alone; for dive2 both match and give a stream with a topic AND a file."""
    doc = vehicle_dict()
    doc["trials"] = {"dive*": {"streams": {"depth": {"topic": None, "file": "depth.csv", "clock": "column",
                                                     "csv": {"time_column": "t"}}}},
                     "dive2": {"streams": {"depth": {"topic": "/depth2"}}}}
    v = parse(Vehicle, doc)
    assert v.for_trial("dive1").streams["depth"].file == "depth.csv"
    with pytest.raises(ConfigError, match=r"trial 'dive2'.*\['dive\*', 'dive2'\].*'depth'.*exactly one of") as err:
        v.for_trial("dive2")
    assert err.value.field == "trials.dive2.streams.depth"
