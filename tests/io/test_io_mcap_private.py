"""A private record (opcode 0x80-0xff, user-defined) inside an MCAP chunk: the spec tells readers to skip unknown
opcodes, so every message is kept, and the skipped record is counted in the salvage report, by the chunk-index
path as by the record walk (issue 36, item 4).

The files are written by the mcap library (and rosbags, for a ROS 2 bag), then one chunk is rebuilt with a private
record inserted among its records: its lengths, uncompressed size and CRC fixed, and the message indexes that
follow it moved by the record's length, so the file is valid MCAP and the right answer is the trial itself.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
import zstandard

from pipeline.io import open_log
from tests.io.helpers import REQUESTS, expected, trial, write_mcap, write_rosbag2

MSGS = trial(n=10, seed=7)
PRIVATE = struct.pack("<BQ", 0x81, 5) + b"hello"


def _records(data: bytes, start: int = 8) -> list[tuple[int, int, int]]:
    """(opcode, record offset, body length) of the records from ``start`` up to the footer."""
    out, pos = [], start
    while pos + 9 <= len(data):
        op, length = struct.unpack_from("<BQ", data, pos)
        out.append((op, pos, length))
        if op == 0x02:
            break
        pos += 9 + length
    return out


def insert_private(path: Path, where: str) -> None:
    """Insert :data:`PRIVATE` into the second chunk (the only one, in a small bag), at the start of its records,
    before its middle record or at its end."""
    data = path.read_bytes()
    chunks = [r for r in _records(data) if r[0] == 0x06]
    _, at, length = chunks[min(1, len(chunks) - 1)]
    body = at + 9
    start, end, usize, _ = struct.unpack_from("<QQQI", data, body)
    (clen,) = struct.unpack_from("<I", data, body + 28)
    compression = data[body + 32:body + 32 + clen].decode()
    rstart = body + 32 + clen + 8
    (rlen,) = struct.unpack_from("<Q", data, rstart - 8)
    raw = data[rstart:rstart + rlen]
    inner = zstandard.ZstdDecompressor().decompress(raw, max_output_size=usize) if compression == "zstd" else raw
    assert compression in ("", "zstd") and len(inner) == usize
    x = {"start": 0, "middle": _records(inner, 0)[len(_records(inner, 0)) // 2][1], "end": len(inner)}[where]
    inner = inner[:x] + PRIVATE + inner[x:]
    raw = zstandard.ZstdCompressor().compress(inner) if compression == "zstd" else inner
    chunk = (struct.pack("<QQQI", start, end, len(inner), zlib.crc32(inner)) + data[body + 28:rstart - 8]
             + struct.pack("<Q", len(raw)) + raw)
    out = bytearray(data[:at] + struct.pack("<BQ", 0x06, len(chunk)) + chunk)
    rest, pos = data[at + 9 + length:], 0
    while pos < len(rest) and rest[pos] == 0x07:  # this chunk's message indexes: offsets after x move
        (n,) = struct.unpack_from("<Q", rest, pos + 1)
        (size,) = struct.unpack_from("<I", rest, pos + 11)
        record = bytearray(rest[pos:pos + 9 + n])
        for k in range(size // 16):
            (offset,) = struct.unpack_from("<Q", record, 15 + 16 * k + 8)
            struct.pack_into("<Q", record, 15 + 16 * k + 8, offset + len(PRIVATE) * (offset >= x))
        out += record
        pos += 9 + n
    path.write_bytes(bytes(out + rest[pos:]))


def _read_all(path: Path):  # noqa: ANN202
    with open_log(path) as reader:
        listed = reader.topics()
        assert set(listed) == set(REQUESTS)
        return reader.read(REQUESTS)


LAYOUTS = {
    "indexed-none": lambda p: write_mcap(p / "t.mcap", MSGS, compression="none"),
    "indexed-zstd": lambda p: write_mcap(p / "t.mcap", MSGS, compression="zstd"),
    "no-indexes": lambda p: write_mcap(p / "t.mcap", MSGS, compression="zstd", indexes=False),
    "no-summary": lambda p: write_mcap(p / "t.mcap", MSGS, compression="none", summary=False, indexes=False),
    "ros2-mcap-bag": lambda p: write_rosbag2(p / "bag", MSGS, storage="mcap"),
}


@pytest.mark.parametrize("where", ["start", "middle", "end"])
@pytest.mark.parametrize("layout", list(LAYOUTS))
def test_a_private_record_in_a_chunk_is_skipped_counted_and_every_message_kept(tmp_path: Path, layout: str,
                                                                               where: str) -> None:
    log = LAYOUTS[layout](tmp_path)
    target = log if log.is_file() else next(log.glob("*.mcap"))
    insert_private(target, where)
    result = _read_all(log)
    want = expected(MSGS)
    assert not result.failed
    for topic, data in result.topics.items():
        np.testing.assert_array_equal(data.log_ns, want[topic]["log_ns"])
        for field, column in data.columns.items():
            np.testing.assert_array_equal(column, want[topic][field], err_msg=f"{layout} {where} {topic} {field}")
    assert sum(d.read for d in result.topics.values()) == len(MSGS)
    assert result.salvage is not None and "1 record(s) with a private opcode" in result.salvage.reason
    assert result.salvage.stopped_at_byte is None  # nothing was cut: the record was skipped, not damage


def test_a_message_its_chunk_index_does_not_list_is_read_by_the_record_walk(tmp_path: Path) -> None:
    """A message index that misses a message (its last entry dropped) in a file without statistics to compare
    counts with: the chunk-index path finds the unlisted record between the listed ones and leaves the file to
    the record walk, which keeps it."""
    path = write_mcap(tmp_path / "t.mcap", MSGS, compression="none")
    data = bytearray(path.read_bytes())
    stats = next((at, 9 + n) for op, at, n in _records(bytes(data)) if op == 0x0B)
    del data[stats[0]:stats[0] + stats[1]]  # the summary's statistics record
    index = next(at for op, at, _ in _records(bytes(data)) if op == 0x07
                 and struct.unpack_from("<I", data, at + 11)[0] >= 32)
    (size,) = struct.unpack_from("<I", data, index + 11)
    del data[index + 15 + size - 16:index + 15 + size]
    struct.pack_into("<Q", data, index + 1, struct.unpack_from("<Q", data, index + 1)[0] - 16)
    struct.pack_into("<I", data, index + 11, size - 16)
    path.write_bytes(bytes(data))
    result = _read_all(path)
    assert sum(d.read for d in result.topics.values()) == len(MSGS)
