"""The indexed path through a ROS 1 bag locates a batch's messages at once, per connection and header layout: the
payloads and times are those of the record walk in batches of any size, and an index entry that does not point
at a message record of its connection is damage (the read then walks the bag record by record)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pipeline.io import open_log, rosbag1_index
from pipeline.io.errors import Damaged
from pipeline.io.rosbag1 import Rosbag1Reader, walk
from pipeline.io.rosbag1_index import chunk_batches, index_walk
from tests.io.helpers import REQUESTS, expected, trial, write_rosbag1


def _walked(path: Path) -> dict[int, list[tuple[int, bytes]]]:
    """connection -> (log time, payload) of every message, by the record walk."""
    out: dict[int, list[tuple[int, bytes]]] = {}
    walk(path, lambda cid, t, payload: out.setdefault(cid, []).append((t, payload)))
    return out


@pytest.mark.parametrize("limit", [1, 3000, 16 << 20])
@pytest.mark.parametrize("compression", [None, "lz4"])
def test_batches_of_any_size_give_the_walks_messages(tmp_path: Path, limit: int, compression: str | None) -> None:
    path = write_rosbag1(tmp_path / "t.bag", trial(n=60, seed=2), compression=compression, chunk_threshold=700)
    bag = index_walk(path)
    assert bag is not None and len(bag.chunks) > 5
    topics = {cid: c.topic for cid, c in bag.walk.connections.items()}
    got: dict[str, list[tuple[int, bytes]]] = {}
    for batch in chunk_batches(path, bag, topics, limit=limit):
        for topic, rows in batch.rows.items():
            got.setdefault(topic, []).extend(
                (int(t), batch.buf[s:s + n].tobytes())
                for s, n, t in zip(rows.starts, rows.lengths, rows.log_ns, strict=True))
    want = {topics[cid]: msgs for cid, msgs in _walked(path).items()}
    assert got == want


@pytest.mark.parametrize("shift", [1, -4, 10**6])
def test_an_index_entry_off_its_record_is_damage_and_the_read_walks_the_bag(
        tmp_path: Path, shift: int, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture) -> None:
    msgs = trial(n=60, seed=3)
    path = write_rosbag1(tmp_path / "t.bag", msgs, chunk_threshold=700)
    bag = index_walk(path)
    assert bag is not None
    chunk = bag.chunks[len(bag.chunks) // 2]
    cid, offs = next((c, o) for c, o in chunk.index.items() if len(o) > 1)
    offs = offs.astype(np.int64)
    offs[-1] += shift
    chunk.index[cid] = offs
    topics = {c: conn.topic for c, conn in bag.walk.connections.items()}
    with pytest.raises(Damaged) as info:
        list(chunk_batches(path, bag, topics))
    assert info.value.at == chunk.at  # the damaged chunk is named

    monkeypatch.setattr(rosbag1_index, "index_walk", lambda p: bag)  # the reader meets the same bad index
    with open_log(path) as reader, caplog.at_level("WARNING"):
        assert isinstance(reader, Rosbag1Reader)
        topics_read = reader.read(REQUESTS).topics
    assert f"at byte {chunk.at}; reading it record by record" in caplog.text
    want = expected(msgs)
    assert {t: d.read for t, d in topics_read.items()} == {t: len(c["log_ns"]) for t, c in want.items()}
    for topic, cols in want.items():
        np.testing.assert_array_equal(topics_read[topic].log_ns, cols["log_ns"])


def _chunk_records(path: Path, chunk: rosbag1_index.ChunkRef) -> list[tuple[int, int]]:
    """(offset in the chunk, op) of every record of an uncompressed chunk."""
    data = path.read_bytes()[chunk.data:chunk.data + chunk.size]
    out, pos = [], 0
    while pos < len(data):
        hlen = int.from_bytes(data[pos:pos + 4], "little")
        header = data[pos + 4:pos + 4 + hlen]
        op = header[header.index(b"op=") + 3]
        out.append((pos, op))
        pos += 8 + hlen + int.from_bytes(data[pos + 4 + hlen:pos + 8 + hlen], "little")
    return out


def _damaged(path: Path, bag: rosbag1_index.IndexedBag) -> Damaged:
    topics = {c: conn.topic for c, conn in bag.walk.connections.items()}
    with pytest.raises(Damaged) as info:
        list(chunk_batches(path, bag, topics))
    return info.value


def test_an_index_entry_at_another_connections_message_is_damage(tmp_path: Path) -> None:
    """Every message record has the same header layout: only its ``conn`` field tells whose it is."""
    path = write_rosbag1(tmp_path / "t.bag", trial(n=60, seed=4), chunk_threshold=700)
    bag = index_walk(path)
    assert bag is not None
    chunk = next(c for c in bag.chunks[1:] if len(c.index) >= 2 and all(len(o) for o in c.index.values()))
    (a, offs_a), (_, offs_b) = sorted(chunk.index.items())[:2]
    offs = offs_a.astype(np.int64)
    offs[-1] = int(offs_b[0])
    chunk.index[a] = offs
    err = _damaged(path, bag)
    assert err.reason == "bag index points at a record that is not a message of its connection"
    assert err.at == chunk.at


def test_a_message_record_with_another_header_length_is_damage(tmp_path: Path) -> None:
    """A record whose header length is not its connection's (its op and conn fields still where the layout
    says): its data length and payload would be read from the wrong bytes."""
    path = write_rosbag1(tmp_path / "t.bag", trial(n=60, seed=4), chunk_threshold=700)
    bag = index_walk(path)
    assert bag is not None
    chunk = bag.chunks[len(bag.chunks) // 2]
    cid, offs = next((c, o) for c, o in chunk.index.items() if len(o) > 1)
    raw = bytearray(path.read_bytes())
    at = chunk.data + int(offs[-1])  # not the first: the connection's layout is read from that one
    hlen = int.from_bytes(raw[at:at + 4], "little")
    raw[at:at + 4] = (hlen + 4).to_bytes(4, "little")
    path.write_bytes(bytes(raw))
    err = _damaged(path, bag)
    assert err.reason == "message records of one connection differ in header layout"
    assert err.at == chunk.at


def test_a_message_whose_data_runs_past_its_chunk_is_damage(tmp_path: Path) -> None:
    path = write_rosbag1(tmp_path / "t.bag", trial(n=60, seed=4), chunk_threshold=700)
    bag = index_walk(path)
    assert bag is not None
    chunk = bag.chunks[len(bag.chunks) // 2]
    pos = next(p for p, op in _chunk_records(path, chunk) if op == 2)  # the chunk's first message record
    raw = bytearray(path.read_bytes())
    at = chunk.data + pos
    hlen = int.from_bytes(raw[at:at + 4], "little")
    raw[at + 4 + hlen:at + 8 + hlen] = (chunk.size + 1).to_bytes(4, "little")  # its data length
    path.write_bytes(bytes(raw))
    err = _damaged(path, bag)
    assert err.reason == "message record overruns its chunk"
    assert err.at == chunk.at


def test_a_topic_on_two_connections_comes_in_file_order(tmp_path: Path) -> None:
    """Two publishers of one topic (two connections, as two nodes or a restarted node record): each chunk indexes
    them apart, a batch locates each connection's records apart, and the read must still give the messages in the
    order they were written."""
    from rosbags.rosbag1 import Writer

    from tests.io.helpers import DVL, ros1_store

    store = ros1_store()
    types = store.types
    path = tmp_path / "two.bag"
    bag = Writer(path)
    bag.chunk_threshold = 900
    with bag:
        conns = [bag.add_connection("/dvl", DVL, typestore=store, callerid=f"/node{k}") for k in range(2)]
        for i in range(40):
            t = 1_700_000_000_000_000_000 + i * 100_000_000
            sec, nsec = divmod(t, 1_000_000_000)
            header = types["std_msgs/msg/Header"](seq=i, stamp=types["builtin_interfaces/msg/Time"](sec=sec,
                                                                                                  nanosec=nsec),
                                                  frame_id="dvl")
            msg = types[DVL](header=header, velocity=types["geometry_msgs/msg/Vector3"](x=float(i), y=0.0, z=0.0),
                             bottom_lock=True, altitude=1.0)
            bag.write(conns[(i * 7) % 3 % 2], t, bytes(store.serialize_ros1(msg, DVL)))
    bag_index = index_walk(path)
    assert bag_index is not None and len(bag_index.walk.connections) == 2 and len(bag_index.chunks) > 3
    with open_log(path) as reader:
        got = reader.read({"/dvl": ["velocity.x"]}).topics["/dvl"]
    assert got.columns["velocity.x"].tolist() == [float(i) for i in range(40)]
    assert (np.diff(got.log_ns) > 0).all()
