"""Every format gives the same values and stamps for the same trial; both decoding paths agree bit for bit."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from pipeline.errors import IngestError
from pipeline.io import open_log
from pipeline.io.inspect import format_inspect, inspect_log
from tests.io.helpers import (
    REQUESTS,
    expected,
    trial,
    write_mcap,
    write_rosbag1,
    write_rosbag1_unindexed,
    write_rosbag2,
)

WRITERS = {
    "mcap-zstd": ("mcap", lambda p, m: write_mcap(p / "t.mcap", m)),
    "mcap-lz4": ("mcap", lambda p, m: write_mcap(p / "t.mcap", m, compression="lz4")),
    "mcap-plain-chunks": ("mcap", lambda p, m: write_mcap(p / "t.mcap", m, compression="none")),
    "mcap-unchunked-bare": ("mcap", lambda p, m: write_mcap(p / "t.mcap", m, chunked=False, summary=False,
                                                           indexes=False)),
    "ros2-sqlite3": ("ros2-sqlite3", lambda p, m: write_rosbag2(p / "bag", m)),
    "ros2-sqlite3-v8": ("ros2-sqlite3", lambda p, m: write_rosbag2(p / "bag", m, version=8)),
    "ros2-sqlite3-file-zstd": ("ros2-sqlite3", lambda p, m: write_rosbag2(p / "bag", m, compression="file")),
    "ros2-sqlite3-message-zstd": ("ros2-sqlite3", lambda p, m: write_rosbag2(p / "bag", m, compression="message")),
    "ros2-mcap": ("ros2-mcap", lambda p, m: write_rosbag2(p / "bag", m, storage="mcap")),
    "ros2-mcap-file-zstd": ("ros2-mcap", lambda p, m: write_rosbag2(p / "bag", m, storage="mcap", compression="file")),
    "ros1": ("ros1", lambda p, m: write_rosbag1(p / "t.bag", m)),
    "ros1-bz2": ("ros1", lambda p, m: write_rosbag1(p / "t.bag", m, compression="bz2")),
    "ros1-lz4": ("ros1", lambda p, m: write_rosbag1(p / "t.bag", m, compression="lz4")),
    "ros1-unindexed": ("ros1", lambda p, m: write_rosbag1_unindexed(p / "t.bag", m, compression="bz2")),
}


@pytest.fixture(scope="module")
def msgs() -> list:
    return trial(n=15, seed=3)


@pytest.mark.parametrize("kind", list(WRITERS))
@pytest.mark.parametrize("fast", [True, False], ids=["fast", "per-message"])
def test_every_format_gives_the_trial(tmp_path: Path, msgs: list, kind: str, fast: bool) -> None:
    fmt, write = WRITERS[kind]
    path = write(tmp_path, msgs)
    want = expected(msgs)
    with open_log(path) as reader:
        assert reader.format == fmt
        infos = reader.topics()
        assert {t: i.count for t, i in infos.items()} == {t: len(c["log_ns"]) for t, c in want.items()}
        assert infos["/dvl/data"].msgtype == "auv_msgs/msg/DVL" and infos["/dvl/data"].has_header
        assert infos["/dvl/data"].first_ns == want["/dvl/data"]["log_ns"][0]
        reader.allow_fast = fast
        result = reader.read(REQUESTS)
    assert not result.failed
    if kind == "ros1-unindexed":  # never indexed: the recorder was stopped; every message kept, and it is said
        assert result.salvage is not None and "no index" in result.salvage.reason
        assert result.salvage.kept == len(msgs)
    else:
        assert result.salvage is None
    for topic, data in result.topics.items():
        assert data.read == data.expected == len(want[topic]["log_ns"])
        assert data.log_ns.dtype == np.int64
        np.testing.assert_array_equal(data.log_ns, want[topic]["log_ns"])
        np.testing.assert_array_equal(data.header_ns, want[topic]["header_ns"])
        for field, column in data.columns.items():
            assert column.dtype == np.float64
            np.testing.assert_array_equal(column, want[topic][field], err_msg=f"{kind} {topic} {field}")
    paths = {t: d.path for t, d in result.topics.items()}
    if fast:
        assert paths["/dvl/data"] == paths["/ahrs/imu"] == "fast"
    else:
        assert set(paths.values()) == {"per-message"}


def test_fast_and_per_message_bit_identical(tmp_path: Path, msgs: list) -> None:
    path = write_mcap(tmp_path / "t.mcap", msgs)
    out = []
    for fast in (True, False):
        reader = open_log(path)
        reader.allow_fast = fast
        out.append(reader.read({"/dvl/data": REQUESTS["/dvl/data"], "/ahrs/imu": REQUESTS["/ahrs/imu"]}))
    for topic, a in out[0].topics.items():
        b = out[1].topics[topic]
        assert (a.path, b.path) == ("fast", "per-message")
        for field in a.columns:
            assert a.columns[field].tobytes() == b.columns[field].tobytes()
        assert a.header_ns.tobytes() == b.header_ns.tobytes()


def test_only_requested_topics_are_decoded(tmp_path: Path, msgs: list) -> None:
    reader = open_log(write_rosbag2(tmp_path / "bag", msgs))
    result = reader.read({"/dvl/data": ["velocity.x"]})
    assert list(result.topics) == ["/dvl/data"]
    assert list(result.topics["/dvl/data"].columns) == ["velocity.x"]


def test_unknown_topic_lists_available(tmp_path: Path, msgs: list) -> None:
    path = write_mcap(tmp_path / "trial3.mcap", msgs)
    with pytest.raises(IngestError, match=r"topic '/dvl' not in trial3.mcap; available: \['/ahrs/imu'") as err:
        open_log(path).read({"/dvl": ["velocity.x"]})
    assert err.value.topic == "/dvl" and err.value.file == str(path)


@pytest.mark.parametrize("field,why", [
    ("velocity.q", "has no field 'q'"),
    ("velocity", "not a numeric or bool scalar"),
    ("altitude[0]", "not an array"),
    ("header.frame_id", "not a numeric"),
])
def test_bad_field_lists_fields(tmp_path: Path, msgs: list, field: str, why: str) -> None:
    reader = open_log(write_rosbag1(tmp_path / "t.bag", msgs))
    with pytest.raises(IngestError, match=why) as err:
        reader.read({"/dvl/data": [field]})
    assert err.value.field == field and "velocity.x" in str(err.value)


def test_selection_needs_a_name_list(tmp_path: Path, msgs: list) -> None:
    reader = open_log(write_mcap(tmp_path / "t.mcap", msgs))
    with pytest.raises(IngestError, match="string list field 'label'"):
        reader.read({"/thrusters/joint_states": ["velocity[label=th1]"]})
    result = reader.read({"/thrusters/joint_states": ["velocity[name=th9]", "velocity[7]"]})
    assert np.isnan(result.topics["/thrusters/joint_states"].columns["velocity[name=th9]"]).all()
    assert np.isnan(result.topics["/thrusters/joint_states"].columns["velocity[7]"]).all()


@pytest.mark.parametrize("content,match", [
    (b"", "empty file"),
    (b"hello, this is not a log", "unknown format.*MCAP"),
    (bytes(range(64)), "unknown format"),
])
def test_not_a_log(tmp_path: Path, content: bytes, match: str) -> None:
    path = tmp_path / "trial.mcap"
    path.write_bytes(content)
    with pytest.raises(IngestError, match=match) as err:
        open_log(path)
    assert err.value.file == str(path)


def test_missing_and_empty_directory(tmp_path: Path) -> None:
    with pytest.raises(IngestError, match="no such file"):
        open_log(tmp_path / "nope.bag")
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "notes.md").write_text("x")
    with pytest.raises(IngestError, match="nothing readable"):
        open_log(tmp_path / "d")


def test_content_not_extension(tmp_path: Path, msgs: list) -> None:
    path = write_rosbag1(tmp_path / "t.bag", msgs)
    renamed = path.rename(tmp_path / "t.mcap")
    assert open_log(renamed).format == "ros1"
    db3 = next((write_rosbag2(tmp_path / "bag", msgs)).glob("*.db3"))
    single = open_log(db3)
    assert single.format == "ros2-sqlite3" and single.topics()["/ahrs/imu"].count == 15


def test_bag_without_metadata(tmp_path: Path, msgs: list) -> None:
    bag = write_rosbag2(tmp_path / "bag", msgs, storage="mcap")
    (bag / "metadata.yaml").unlink()
    result = open_log(bag).read(REQUESTS)
    assert result.topics["/dvl/data"].read == 15


def test_csv_directory_dispatches_to_text_reader(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import types

    seen = []
    fake = types.ModuleType("pipeline.io.text")
    fake.open_text = lambda p: seen.append(p) or "reader"  # type: ignore[attr-defined]
    monkeypatch.setitem(sys.modules, "pipeline.io.text", fake)
    (tmp_path / "fog.csv").write_text("t,rate\n0,1\n")
    assert open_log(tmp_path) == "reader" and seen == [tmp_path]


def test_inspect(tmp_path: Path, msgs: list) -> None:
    info = inspect_log(write_rosbag1(tmp_path / "t.bag", msgs))
    dvl = info["topics"]["/dvl/data"]
    assert info["format"] == "ros1" and dvl["count"] == 15 and dvl["msgtype"] == "auv_msgs/msg/DVL"
    assert dvl["rate_hz"] == pytest.approx(14 / (dvl["duration_s"]), rel=1e-9)
    assert dvl["first_iso"].startswith("2023-11-14T22:13:20")
    text = format_inspect(info)
    assert "/thrusters/joint_states" in text and "sensor_msgs/msg/JointState" in text


@pytest.mark.parametrize("kind", ["mcap", "ros1"])
def test_fewer_messages_read_than_the_storage_holds_is_an_error_naming_the_topic(tmp_path: Path, kind: str) -> None:
    """The storage-count cross-check: where the storage says a topic holds one message more than the read yields
    (a reader bug, or a loss no salvage saw), the read fails naming file and topic instead of returning less."""
    import dataclasses

    msgs = trial()
    path = {"mcap": lambda: write_mcap(tmp_path / "t.mcap", msgs),
            "ros1": lambda: write_rosbag1(tmp_path / "t.bag", msgs)}[kind]()
    with open_log(path) as reader:
        topic = next(iter(REQUESTS))
        info = reader.catalog()[topic]
        reader._infos[topic] = dataclasses.replace(info, count=info.count + 1)
        holds = f"read {info.count} messages but the storage holds {info.count + 1}"
        with pytest.raises(IngestError, match=holds) as err:
            reader.read({topic: REQUESTS[topic]})
    assert err.value.topic == topic


def test_a_bag_whose_metadata_points_outside_it_is_refused(tmp_path: Path) -> None:
    """metadata.yaml's relative_file_paths may not reach outside the bag directory (a crafted '../other.db3')."""
    import shutil

    import yaml

    bag = write_rosbag2(tmp_path / "bag", trial())
    outside = tmp_path / "elsewhere.db3"
    [db3] = sorted(bag.glob("*.db3"))
    shutil.copy(db3, outside)
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    meta["rosbag2_bagfile_information"]["relative_file_paths"] = ["../elsewhere.db3"]
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    with pytest.raises(IngestError, match="outside the bag directory"):
        with open_log(bag) as reader:
            reader.read({t: f for t, f in REQUESTS.items() if t in reader.topics()})
