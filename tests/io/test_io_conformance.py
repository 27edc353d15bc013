"""Conformance over real files written by other people's tools: the rosbag2 test bags shipped in tests/fixtures
(Apache-2.0), the ROS 1 bags from ../shared/fixtures (licence not stated, so not shipped; skipped without it)."""

from __future__ import annotations

import json
import sqlite3
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import IngestError
from pipeline.io import open_log
from pipeline.io.fields import leaf_paths, resolve
from pipeline.io.inspect import format_inspect, inspect_log
from tests.fixturepaths import SHIPPED, shared_fixture

ROS2 = SHIPPED / "rosbag2"


def _bags() -> list[Path]:
    """Every rosbag2 fixture: bag directories, and the loose single-file bags of rosbag2_cpp."""
    out: set[Path] = set()
    for f in ROS2.rglob("*"):
        if not f.is_file() or f.suffix not in (".db3", ".mcap", ".yaml"):
            continue
        d = f.parent
        if (d / "metadata.yaml").exists() or "reindex_test_bags" in d.parts:
            out.add(d)
        elif f.suffix != ".yaml":
            out.add(f)
    return sorted(out)


BAGS = _bags()
if len(BAGS) < 27:  # an empty (or partial) parametrization would pass silently
    raise RuntimeError(f"{ROS2}: {len(BAGS)} rosbag2 fixture bags found, expected the 27 shipped")


def _storage_counts(bag: Path) -> Counter[str]:
    """Messages per topic as the storage itself holds them (sqlite rows; MCAP message records)."""
    from mcap.reader import make_reader

    files = [bag] if bag.is_file() else sorted(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    counts: Counter[str] = Counter()
    for f in files:
        if f.suffix == ".db3":
            con = sqlite3.connect(f"file:{f}?mode=ro&immutable=1", uri=True)
            counts.update({t: 0 for (t,) in con.execute("SELECT name FROM topics")})
            for name, n in con.execute(
                    "SELECT t.name, COUNT(m.id) FROM topics t JOIN messages m ON m.topic_id = t.id GROUP BY t.name"):
                counts[name] += n
            con.close()
        else:
            with open(f, "rb") as fh:
                reader = make_reader(fh)
                summary = reader.get_summary()
                if summary is not None:
                    counts.update({c.topic: 0 for c in summary.channels.values()})
                for _schema, channel, _msg in reader.iter_messages(log_time_order=False):
                    counts[channel.topic] += 1
    return counts


def _numeric_fields(reader, topic: str, msgtype: str) -> list[str]:  # noqa: ANN001
    fields = []
    for p in leaf_paths(reader._types.defs, msgtype):  # noqa: SLF001
        try:
            resolve(reader._types, msgtype, p, file=reader.path, topic=topic)  # noqa: SLF001
        except IngestError:
            continue
        fields.append(p)
    return fields


@pytest.mark.parametrize("bag", BAGS, ids=lambda p: str(p.relative_to(ROS2)))
def test_rosbag2_counts_match_storage(bag: Path) -> None:
    want = _storage_counts(bag)
    with open_log(bag) as reader:
        infos = reader.topics()
        assert {t: i.count for t, i in infos.items()} == dict(want)
        requests = {}
        for t, i in infos.items():
            if reader._undecodable(t, i.msgtype) is None:  # noqa: SLF001
                requests[t] = _numeric_fields(reader, t, i.msgtype)
            else:
                requests[t] = []
        fast = reader.read(requests)
        reader.allow_fast = False
        slow = reader.read(requests)
    assert set(fast.topics) | set(fast.failed) == set(infos)
    for topic, data in fast.topics.items():
        assert data.read == data.expected == want[topic], topic
        assert len(data.log_ns) == want[topic]
        other = slow.topics[topic]
        np.testing.assert_array_equal(data.log_ns, other.log_ns)
        for field, col in data.columns.items():
            assert col.tobytes() == other.columns[field].tobytes(), (topic, field)
    for why in fast.failed.values():
        assert why
    info = inspect_log(bag)
    json.dumps(info)
    assert info["messages"] == sum(want.values())
    assert "topics:" in format_inspect(info)


def test_cdr_test_values() -> None:
    result = open_log(ROS2 / "rosbag2_tests/resources/mcap/cdr_test").read(
        {"/test_topic": ["int32_value", "bool_value"], "/array_topic": ["float32_values[1]", "int8_values[2]"]})
    assert result.topics["/test_topic"].read == 3 and result.topics["/array_topic"].read == 4
    assert not result.failed


def test_empty_bag() -> None:
    bag = ROS2 / "ros2bag/test/resources/empty_bag"
    reader = open_log(bag)
    assert all(i.count == 0 and i.first_ns is None for i in reader.topics().values())
    result = reader.read({t: [] for t in reader.topics()})
    assert all(d.read == 0 and len(d.log_ns) == 0 for d in result.topics.values())
    info = inspect_log(bag)
    assert info["messages"] == 0 and info["duration_s"] == 0.0
    assert "no messages" in format_inspect(info)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_wrong_rmw_reports_failed_topics(storage: str) -> None:
    reader = open_log(ROS2 / f"rosbag2_tests/resources/{storage}/wrong_rmw_test")
    result = reader.read({"/test_topic": [], "/array_topic": []})
    assert set(result.failed) == {"/test_topic", "/array_topic"} and not result.topics
    if storage == "mcap":
        assert "wrong_format" in result.failed["/test_topic"]


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_split_bag_is_one_recording(storage: str) -> None:
    reader = open_log(ROS2 / f"rosbag2_py/test/resources/{storage}/wbag")
    infos = reader.topics()
    assert sorted(infos) == ["AAA", "BBB", "CCC", "DDD", "EEE", "FFF", "GGG", "HHH"]
    assert sum(i.count for i in infos.values()) == 6074
    result = reader.read({"AAA": []})
    assert result.topics["AAA"].read == 804


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_reindex_bag_without_metadata(storage: str) -> None:
    reader = open_log(ROS2 / f"rosbag2_py/test/resources/{storage}/reindex_test_bags/multiple_files")
    assert reader.format == f"ros2-{storage}"
    assert reader.read({"/chatter": []}).topics["/chatter"].read == 3177


def test_service_events_decode() -> None:
    bag = ROS2 / "rosbag2_tests/resources/mcap/bag_with_topics_and_service_events"
    result = open_log(bag).read({"/test_service1/_service_event": ["info.event_type", "info.sequence_number"],
                                 "/test_topic1": []})
    data = result.topics["/test_service1/_service_event"]
    assert data.read == 4 and set(data.columns["info.event_type"]) <= {0.0, 1.0, 2.0, 3.0}


def _ros1_counts(path: Path) -> Counter:
    """Messages per topic as the bag's own connection records count them (rosbags)."""
    from rosbags.rosbag1 import Reader

    own: Counter = Counter()
    with Reader(path) as bag:
        for c in bag.connections:
            own[c.topic] += c.msgcount
    return own


def test_ros1_waterlinked_custom_types() -> None:
    path = shared_fixture("ros1/dtu_bluerov2_waterlinked.bag")
    own = _ros1_counts(path)
    reader = open_log(path)
    infos = reader.topics()
    assert {t: i.count for t, i in infos.items()} == dict(own)
    topic = "/waterlinked/position/acoustic/filtered"
    assert infos[topic].has_header and infos[topic].msgtype.startswith("waterlinked_gps_msgs/msg/")
    fields = ["x", "y", "z", "std", "temp"]
    fast = reader.read({topic: fields}).topics[topic]
    reader.allow_fast = False
    slow = reader.read({topic: fields}).topics[topic]
    assert fast.path == "fast" and slow.path == "per-message" and fast.read == own[topic]
    for f in fields:
        assert fast.columns[f].tobytes() == slow.columns[f].tobytes()
    assert (np.diff(fast.header_ns) >= 0).all() and fast.header_ns[0] > 1.5e18


def test_ros1_headerless_float64() -> None:
    path = shared_fixture("ros1/usv_sim_trialnu_sines.bag")
    own = _ros1_counts(path)
    reader = open_log(path)
    infos = reader.topics()
    assert {t: i.count for t, i in infos.items()} == dict(own)
    assert infos["u_speed"].msgtype == "std_msgs/msg/Float64" and not infos["u_speed"].has_header
    result = reader.read({"u_speed": ["data"], "position": ["x", "theta"]})
    data = result.topics["u_speed"]
    assert data.header_ns is None and data.read == 2000 and np.isfinite(data.columns["data"]).all()
    assert (np.diff(data.log_ns) > 0).all()
    info = inspect_log(path)
    assert info["topics"]["u_speed"]["rate_hz"] == pytest.approx(100, rel=0.01)
