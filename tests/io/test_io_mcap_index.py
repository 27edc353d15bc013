"""The indexed MCAP path: payloads located from each chunk's message indexes, in storage order, checked.

Files written by the mcap library index each chunk's messages in the order they were written; other writers
index them by log time, and a topic may have several channels. Either way the rows must come in storage order,
the order the record walk (and rosbags) gives; an index entry that points outside its chunk is damage, reported
at that chunk.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from pipeline.io import mcap_index, mcap_records, open_log
from pipeline.io.errors import Damaged
from tests.io.helpers import DVL, Msg, build, ros2_store

TOPIC = "/dvl"
FIELD = "velocity.x"


def _messages(n: int) -> list[tuple[int, int, float]]:
    """(channel 0 or 1, log time, velocity.x): log times that go back and forth, values that say the order."""
    t0 = 1_700_000_000_000_000_000
    rng = np.random.default_rng(5)
    return [(i % 2 if i % 5 else 1, t0 + int(rng.integers(0, 10**9)), float(i)) for i in range(n)]


def _write(path: Path, msgs: list[tuple[int, int, float]], *, compression: str) -> Path:
    """One topic on two channels (as a recorder that restarted mid-trial writes it), big chunks."""
    from mcap.writer import CompressionType, Writer

    store = ros2_store()
    comp = {"zstd": CompressionType.ZSTD, "none": CompressionType.NONE}[compression]
    text, _ = store.generate_msgdef(DVL, ros_version=2)
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=16 << 10, compression=comp)
        w.start(profile="ros2", library="auvid-tests")
        sid = w.register_schema(name=DVL, encoding="ros2msg", data=text.encode())
        channels = [w.register_channel(topic=TOPIC, message_encoding="cdr", schema_id=sid) for _ in range(2)]
        for seq, (ch, log_ns, x) in enumerate(msgs):
            m = Msg(TOPIC, DVL, log_ns, log_ns, {"velocity.x": x, "velocity.y": 0.0, "velocity.z": 0.0,
                                                  "bottom_lock": 1.0, "altitude": 3.0})
            data = bytes(store.serialize_cdr(build(store, m, ros1=False), DVL))
            w.add_message(channels[ch], log_time=log_ns, data=data, publish_time=log_ns, sequence=seq)
        w.finish()
    return path


def _message_indexes(raw: bytes) -> list[tuple[int, int]]:
    """(offset of the entries, their count) of every top-level message-index record of an MCAP file."""
    out, pos = [], 8
    while pos + 9 <= len(raw) - 8:
        op, length = struct.unpack_from("<BQ", raw, pos)
        if op == mcap_records.OP_MESSAGE_INDEX:
            (n,) = struct.unpack_from("<I", raw, pos + 9 + 2)
            out.append((pos + 9 + 6, n // 16))
        pos += 9 + length
    return out


def _by_log_time(path: Path) -> Path:
    """The same file with each message index's entries sorted by log time (as other writers order them), so
    that their offsets no longer ascend; the records and chunks are untouched."""
    raw = bytearray(path.read_bytes())
    for at, n in _message_indexes(bytes(raw)):
        entries = np.frombuffer(bytes(raw[at:at + 16 * n]), dtype=mcap_index._ENTRY)  # noqa: SLF001
        raw[at:at + 16 * n] = entries[np.argsort(entries["t"], kind="stable")].tobytes()
    out = path.with_name(path.stem + "-by-time.mcap")
    out.write_bytes(bytes(raw))
    return out


def _read(path: Path) -> tuple[np.ndarray, np.ndarray, str]:
    with open_log(path) as reader:
        got = reader.read({TOPIC: [FIELD]}).topics[TOPIC]
    return got.columns[FIELD], got.log_ns, got.path


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_a_topic_on_two_channels_comes_in_storage_order(tmp_path: Path, compression: str) -> None:
    msgs = _messages(3000)
    path = _write(tmp_path / "two.mcap", msgs, compression=compression)
    indexed = mcap_index.index_walk(path)
    assert indexed is not None and len(indexed.chunks) > 3
    assert all(len(c.index) == 2 for c in indexed.chunks)  # both channels in every chunk: a merge per chunk
    values, log_ns, decode_path = _read(path)
    assert decode_path == "fast"
    np.testing.assert_array_equal(values, [x for _, _, x in msgs])
    np.testing.assert_array_equal(log_ns, [t for _, t, _ in msgs])


@pytest.mark.parametrize("compression", ["none", "zstd"])
def test_indexes_in_log_time_order_still_give_storage_order(tmp_path: Path, compression: str) -> None:
    msgs = _messages(3000)
    path = _by_log_time(_write(tmp_path / "two.mcap", msgs, compression=compression))
    indexed = mcap_index.index_walk(path)
    assert indexed is not None
    first = indexed.chunks[0].index
    assert any((np.diff(offs.astype(np.int64)) < 0).any() for offs in first.values())  # really out of order
    values, log_ns, _ = _read(path)
    np.testing.assert_array_equal(values, [x for _, _, x in msgs])
    np.testing.assert_array_equal(log_ns, [t for _, t, _ in msgs])


def test_an_index_entry_outside_its_chunk_is_damage_at_that_chunk(tmp_path: Path) -> None:
    path = _write(tmp_path / "two.mcap", _messages(3000), compression="none")
    indexed = mcap_index.index_walk(path)
    assert indexed is not None
    bad = indexed.chunks[2]
    cid = sorted(bad.index)[1]
    bad.index[cid] = bad.index[cid].copy()
    bad.index[cid][-1] = bad.usize - 30  # a record header there would run past the chunk's end
    wanted = {c: TOPIC for c in indexed.walk.channels}
    with pytest.raises(Damaged, match="message index points outside its chunk") as err:
        list(mcap_index.chunk_batches(path, indexed, wanted, limit=4 << 10))
    assert err.value.at == bad.at
    bad.index[cid][-1] = bad.usize - 31  # the last place a record's header fits: not this check's business
    with pytest.raises(Damaged, match="not a message|another channel|overruns"):
        list(mcap_index.chunk_batches(path, indexed, wanted, limit=4 << 10))


@pytest.mark.parametrize("window", [16, 200, 5000])
def test_the_index_walk_reads_the_same_through_any_window(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                         window: int) -> None:
    """The walk reads the records between chunks through one window: records that straddle its end, or are
    larger than it, give what one read of each gives."""
    path = _write(tmp_path / "two.mcap", _messages(3000), compression="zstd")
    whole = mcap_index.index_walk(path)
    init = mcap_index._Window.__init__  # noqa: SLF001
    monkeypatch.setattr(mcap_index._Window, "__init__", lambda self, fd: init(self, fd, window))  # noqa: SLF001
    small = mcap_index.index_walk(path)
    assert whole is not None and small is not None
    assert [(c.body, c.length, c.usize, c.crc, c.at) for c in small.chunks] == \
        [(c.body, c.length, c.usize, c.crc, c.at) for c in whole.chunks]
    for a, b in zip(small.chunks, whole.chunks, strict=True):
        assert a.index.keys() == b.index.keys()
        for cid in a.index:
            np.testing.assert_array_equal(a.index[cid], b.index[cid])
    assert (small.walk.counts, small.walk.first, small.walk.last, small.walk.schemas) == \
        (whole.walk.counts, whole.walk.first, whole.walk.last, whole.walk.schemas)
    assert sum(small.walk.counts.values()) == 3000
