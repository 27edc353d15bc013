"""A record written twice (issue 17, item 2): read once, and the duplicate reported with the salvage report.

Each test writes an intact log with the library's own writer, writes one whole record of it twice (as the fuzz
campaign's ``record`` mutation does) and checks that every message is read exactly once and that the read says
what it dropped (``ReadResult.salvage.duplicates``).
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from pipeline.io import open_log
from pipeline.io.dedup import Seen
from pipeline.io.salvage import salvage
from tests.io.helpers import (
    REQUESTS,
    expected,
    trial,
    write_mcap,
    write_rosbag1,
    write_rosbag1_unindexed,
    write_rosbag2,
)

MSGS = trial(n=10, seed=7)
WANT = expected(MSGS)


def _read(path: Path):  # noqa: ANN202
    with open_log(path) as reader:
        listed = reader.topics()
        return reader.read({t: f for t, f in REQUESTS.items() if t in listed})


def _check_once(result) -> None:  # noqa: ANN001
    for topic, data in result.topics.items():
        np.testing.assert_array_equal(data.log_ns, WANT[topic]["log_ns"])


def _mcap_records(data: bytes) -> list[tuple[int, int, int]]:
    """(opcode, offset, size) of the top-level MCAP records up to the footer."""
    out, pos = [], 8
    while pos + 9 <= len(data) - 8:
        op, length = struct.unpack_from("<BQ", data, pos)
        out.append((op, pos, 9 + length))
        if op == 0x02:
            break
        pos += 9 + length
    return out


def _bag_records(data: bytes) -> list[tuple[int, int, int]]:
    """(op, offset, size) of the top-level ROS 1 bag records."""
    out, pos = [], 13
    while pos + 4 <= len(data):
        (hlen,) = struct.unpack_from("<I", data, pos)
        head = data[pos + 4:pos + 4 + hlen]
        at = head.index(b"op=") + 3
        (dlen,) = struct.unpack_from("<I", data, pos + 4 + hlen)
        out.append((head[at], pos, 8 + hlen + dlen))
        pos += 8 + hlen + dlen
    return out


def _twice(path: Path, at: int, size: int) -> None:
    data = path.read_bytes()
    path.write_bytes(data[:at + size] + data[at:at + size] + data[at + size:])


@pytest.mark.parametrize(("kind", "op", "with_indexes"), [
    ("unchunked", 0x05, False), ("nosummary", 0x06, False), ("nosummary", 0x06, True), ("indexed", 0x06, False),
    ("indexed", 0x06, True), ("indexed", 0x07, False), ("nostats", 0x06, True), ("nostats", 0x07, False)])
def test_mcap_record_written_twice_is_read_once(tmp_path: Path, kind: str, op: int, with_indexes: bool) -> None:
    kw = {"unchunked": {"chunked": False, "summary": False, "indexes": False}, "nosummary": {"summary": False},
          "indexed": {}, "nostats": {}}[kind]
    path = write_mcap(tmp_path / "t.mcap", MSGS, **kw)
    if kind == "nostats":  # a summary with channels but no statistics record (allowed; some writers omit it)
        data = path.read_bytes()
        _, at, size = next(r for r in _mcap_records(data) if r[0] == 0x0B)
        path.write_bytes(data[:at] + data[at + size:])
    all_records = _mcap_records(path.read_bytes())
    records = [r for r in all_records if r[0] == op]
    _, at, size = records[len(records) // 2]
    if with_indexes:  # the chunk and the message-index records after it, as one region
        i = all_records.index(records[len(records) // 2]) + 1
        while all_records[i][0] == 0x07:
            size += all_records[i][2]
            i += 1
    _twice(path, at, size)
    result = _read(path)  # before: 1 message (unchunked) or a whole chunk (3-4 messages) read twice, no report
    _check_once(result)
    if op == 0x07:  # a message index twice: the record walk reads every message once; nothing was dropped
        assert result.salvage is None or result.salvage.duplicates == 0
        return
    assert result.salvage is not None and result.salvage.duplicates == 1
    assert "duplicate" in result.salvage.reason and f"byte {at + size}" in result.salvage.reason
    assert result.salvage.kept == len(MSGS)
    assert salvage(path).duplicates == 1


@pytest.mark.parametrize(("kind", "op"), [("indexed", 0x05), ("indexed", 0x06), ("unindexed", 0x05)])
def test_ros1_record_written_twice_is_read_once(tmp_path: Path, kind: str, op: int) -> None:
    writer = write_rosbag1 if kind == "indexed" else write_rosbag1_unindexed
    path = writer(tmp_path / "t.bag", MSGS, chunk_threshold=1500)
    records = [(at, size) for o, at, size in _bag_records(path.read_bytes()) if o == op]
    at, size = records[len(records) // 2]
    _twice(path, at, size)
    result = _read(path)  # before: the chunk's messages read twice (or the chunk listed twice by the index)
    _check_once(result)
    assert result.salvage is not None and result.salvage.duplicates == 1
    assert "duplicate" in result.salvage.reason


def test_ros1_message_written_twice_in_a_chunk_is_read_once(tmp_path: Path) -> None:
    path = write_rosbag1_unindexed(tmp_path / "t.bag", MSGS, chunk_threshold=1500)
    data = path.read_bytes()
    _, at, size = next(r for r in _bag_records(data) if r[0] == 0x05)
    (hlen,) = struct.unpack_from("<I", data, at)
    head = bytearray(data[at + 4:at + 4 + hlen])
    body = data[at + 8 + hlen:at + size]
    inner = _bag_records(b"#ROSBAG V2.0\n" + body)  # the chunk's records (offsets past a fake magic)
    _, mat, msize = next(r for r in inner if r[0] == 0x02)
    mat -= 13
    body = body[:mat + msize] + body[mat:mat + msize] + body[mat + msize:]
    s = head.index(b"size=") + 5
    head[s:s + 4] = struct.pack("<I", len(body))  # uncompressed size
    record = struct.pack("<I", hlen) + bytes(head) + struct.pack("<I", len(body)) + body
    path.write_bytes(data[:at] + record + data[at + size:])
    result = _read(path)
    _check_once(result)
    assert result.salvage is not None and result.salvage.duplicates == 1


def test_ros2_mcap_chunk_written_twice_is_read_once(tmp_path: Path) -> None:
    bag = write_rosbag2(tmp_path / "bag", MSGS, storage="mcap")
    storage = next(bag.glob("*.mcap"))
    chunks = [r for r in _mcap_records(storage.read_bytes()) if r[0] == 0x06]
    _, at, size = chunks[0]
    _twice(storage, at, size)
    result = _read(bag)
    _check_once(result)
    assert result.salvage is not None and result.salvage.duplicates == 1 and "duplicate" in result.salvage.reason


def test_seen_window_and_chunks() -> None:
    seen = Seen(window=3)
    buf = b"aaaabbbbccccaaaa"
    assert not seen.message(10, buf, 0, 4, 0) and not seen.message(20, buf, 4, 8, 4)
    assert seen.message(10, buf, 12, 16, 12)      # the bytes of the first, its time again: a copy
    assert not seen.message(10, buf, 8, 12, 8)    # its time again, other bytes
    other = b"aaaa"
    assert not seen.message(10, other, 0, 4, 0)   # another buffer (a chunk): a fresh window
    assert not seen.chunk("k", 70) and seen.chunk("k", 80)
    assert (seen.count, seen.first_at) == (2, 12)
    assert "2 duplicate record(s)" in seen.describe() and "byte 12" in seen.describe()
    small = Seen(window=1)
    assert not small.message(1, buf, 0, 4, 0) and not small.message(1, buf, 4, 8, 4)
    assert not small.message(1, buf, 12, 16, 12)  # the original left the window
