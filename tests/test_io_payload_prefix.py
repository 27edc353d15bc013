"""Indexed readers gather the first bytes of each payload with its record header, once a topic's decoder has said
how many it reads (``RawReader.prefix``, ``Rows.head``): one gather per message instead of two.

What a user relies on: the values are those of the per-message path whatever the batches, the prefix is really
used (or this is dead code), and a prefix learnt on long messages is never gathered past the end of a batch nor
read past the end of a shorter message.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from io_helpers import DVL, REQUESTS, expected, ros1_store, ros2_store, trial, write_mcap, write_rosbag1

from pipeline.io import base, cdr, mcap_index, open_log, rosbag1_index
from pipeline.io.cdr import Columnar

T0 = 1_700_000_000_000_000_000


def _read(path: Path, requests: dict[str, list[str]], *, fast: bool = True) -> tuple[dict, list[int], dict]:
    """Columns per topic, how many rows of each batch came with a payload prefix, and the reader's prefixes."""
    heads: list[int] = []
    with open_log(path) as reader:
        reader.allow_fast = fast
        batches = reader._batches  # noqa: SLF001

        def spy(topics: list[str]):  # noqa: ANN202
            for batch in batches(topics):
                heads.append(sum(len(r.starts) for r in batch.rows.values() if r.head is not None))
                yield batch

        reader._batches = spy  # type: ignore[method-assign]  # noqa: SLF001
        got = reader.read(requests)
        prefix = dict(reader.prefix)
    cols = {t: {"log_ns": d.log_ns, "header_ns": d.header_ns, **d.columns} for t, d in got.topics.items()}
    return cols, heads, prefix


def _small_batches(monkeypatch: pytest.MonkeyPatch) -> None:
    """A batch per chunk or two, so that the decoders' prefixes reach the batches after the first."""
    monkeypatch.setattr(mcap_index, "BATCH_BYTES", 3000)
    monkeypatch.setattr(rosbag1_index, "BATCH_BYTES", 3000)


@pytest.mark.parametrize("kind", ["mcap-none", "mcap-zstd", "ros1", "ros1-lz4"])
def test_values_with_the_prefix_are_those_written(tmp_path: Path, kind: str, monkeypatch: pytest.MonkeyPatch) -> None:
    msgs = trial(n=80, seed=4)
    if kind.startswith("mcap"):
        path = write_mcap(tmp_path / "t.mcap", msgs, compression=kind.split("-")[1])
    else:
        path = write_rosbag1(tmp_path / "t.bag", msgs, compression="lz4" if kind.endswith("lz4") else None,
                             chunk_threshold=2048)
    _small_batches(monkeypatch)
    # Every message of a topic has the same layout here: each batch is read from the prefix (or, before the
    # decoder has seen one, by its own gathers), never by the general walk over each message's bytes.
    general = []
    def walk(buf: np.ndarray, starts: np.ndarray, *a: object, **k: object) -> Columnar:
        if len(starts) > 1:  # (a layout is worked out on one message by the same walk)
            general.append(len(starts))
        return Columnar(buf, starts, *a, **k)

    monkeypatch.setattr(cdr, "Columnar", walk)
    got, heads, prefix = _read(path, REQUESTS)
    assert not general
    slow, slow_heads, _ = _read(path, REQUESTS, fast=False)
    want = expected(msgs)
    assert len(heads) > 10 and sum(heads) > 0.8 * len(msgs)  # every batch after the first topics' first
    assert heads[0] == 0 and not any(slow_heads)  # nothing asked before a decoder has seen a layout
    assert set(prefix) == set(REQUESTS) and min(prefix.values()) > 0
    for topic, cols in want.items():
        for name, values in cols.items():
            assert got[topic][name].tobytes() == values.tobytes(), (topic, name)
            assert slow[topic][name].tobytes() == values.tobytes(), (topic, name)


def _dvl_payloads(ros1: bool, frames: list[str]) -> list[tuple[int, bytes, float]]:
    """(log time, payload, velocity.x) of DVL messages whose frame ids (hence lengths) are ``frames``."""
    store = ros1_store() if ros1 else ros2_store()
    types = store.types
    out = []
    for i, frame in enumerate(frames):
        t = T0 + i * 250_000_000
        sec, nsec = divmod(t, 1_000_000_000)
        hkw = {"seq": i} if ros1 else {}
        header = types["std_msgs/msg/Header"](**hkw, stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                              frame_id=frame)
        vx = 0.5 * i - 7.25
        msg = types[DVL](header=header, velocity=types["geometry_msgs/msg/Vector3"](x=vx, y=-1.0, z=2.0),
                         bottom_lock=True, altitude=3.5)
        raw = store.serialize_ros1(msg, DVL) if ros1 else store.serialize_cdr(msg, DVL)
        out.append((t, bytes(raw), vx))
    return out


def _write_dvl(path: Path, msgs: list[tuple[int, bytes, float]], ros1: bool) -> Path:
    if ros1:
        from rosbags.rosbag1 import Writer as Bag1

        store = ros1_store()
        bag = Bag1(path)
        bag.chunk_threshold = 600
        with bag:
            conn = bag.add_connection("/dvl", DVL, typestore=store)
            for t, raw, _ in msgs:
                bag.write(conn, t, raw)
        return path
    from mcap.writer import CompressionType, Writer

    store = ros2_store()
    text, _ = store.generate_msgdef(DVL, ros_version=2)
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=600, compression=CompressionType.NONE)
        w.start(profile="ros2", library="auvid-tests")
        cid = w.register_channel(topic="/dvl", message_encoding="cdr",
                                 schema_id=w.register_schema(name=DVL, encoding="ros2msg", data=text.encode()))
        for seq, (t, raw, _) in enumerate(msgs):
            w.add_message(cid, log_time=t, data=raw, publish_time=t, sequence=seq)
        w.finish()
    return path


@pytest.mark.parametrize("ros1", [False, True])
def test_a_prefix_learnt_on_long_messages_stays_inside_the_batch_and_the_message(
        tmp_path: Path, ros1: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    """Long messages first (the decoder asks for their whole width), then short ones: the batches of short
    messages end with a record shorter than the prefix, at the very end of the buffer (a one-topic file), and
    the bytes after a short payload belong to the next record."""
    frames = ["a_frame_name_of_forty_characters_exactly"] * 30 + ["b"] * 30 + ["c" * 12, "d"] * 15
    msgs = _dvl_payloads(ros1, frames)
    path = _write_dvl(tmp_path / ("t.bag" if ros1 else "t.mcap"), msgs, ros1)
    monkeypatch.setattr(mcap_index, "BATCH_BYTES", 1)  # a batch per chunk
    monkeypatch.setattr(rosbag1_index, "BATCH_BYTES", 1)
    long = len(msgs[0][1])
    seen: list[int] = []
    locate = base.take_rows

    def spy(buf: np.ndarray, at: np.ndarray, width: int) -> np.ndarray:
        seen.append(width)
        return locate(buf, at, width)

    monkeypatch.setattr(mcap_index if not ros1 else rosbag1_index, "take_rows", spy)
    got, heads, _ = _read(path, {"/dvl": ["velocity.x", "header.stamp.sec"]})
    assert sum(heads) > 0
    assert max(seen) >= long  # the long messages' prefix was asked for (and refused where it did not fit)
    want = np.array([vx for _, _, vx in msgs])
    assert got["/dvl"]["velocity.x"].tobytes() == want.tobytes()
    assert got["/dvl"]["header_ns"].tolist() == [t for t, _, _ in msgs]
