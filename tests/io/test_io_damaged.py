"""Files cut short or corrupted: salvage keeps exactly the complete messages before the damage."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from pipeline.io import open_log
from pipeline.io.salvage import open_salvaged, salvage
from tests.io.helpers import REQUESTS, build, expected, ros1_store, ros2_store, trial, write_mcap, write_rosbag1

MSGS = trial(n=10, seed=7)


def _payload_ends(data: bytes, *, ros1: bool) -> list[int]:
    """Byte offset just past each message's serialized payload, found verbatim in an uncompressed file."""
    store = ros1_store() if ros1 else ros2_store()
    ends = []
    for m in MSGS:
        obj = build(store, m, ros1=ros1)
        raw = bytes(store.serialize_ros1(obj, m.msgtype) if ros1 else store.serialize_cdr(obj, m.msgtype))
        at = data.find(raw)
        assert at > 0 and data.find(raw, at + 1) < 0
        ends.append(at + len(raw))
    return ends


def _read(path: Path):  # noqa: ANN202
    reader = open_log(path)
    return reader.read({t: f for t, f in REQUESTS.items() if t in reader.topics()})


def _check_prefix(result, kept_msgs: list) -> None:  # noqa: ANN001
    want = expected(kept_msgs) if kept_msgs else {}
    assert set(want) <= set(result.topics)
    for topic in result.topics:
        data = result.topics[topic]
        w = want.get(topic, {"log_ns": np.zeros(0, np.int64)})
        np.testing.assert_array_equal(data.log_ns, w["log_ns"])
        assert data.read == data.expected == len(w["log_ns"])
        for field, col in data.columns.items():
            np.testing.assert_array_equal(col, w.get(field, np.zeros(0)))


def _write(kind: str, path: Path) -> Path:
    if kind == "mcap-unchunked":
        return write_mcap(path / "t.mcap", MSGS, chunked=False, summary=False, indexes=False)
    if kind == "mcap-plain-chunks":
        return write_mcap(path / "t.mcap", MSGS, compression="none")
    return write_rosbag1(path / "t.bag", MSGS, chunk_threshold=1500)


@pytest.mark.parametrize("kind", ["mcap-unchunked", "mcap-plain-chunks", "ros1-plain-chunks"])
@pytest.mark.parametrize("fraction", [0.23, 0.37, 0.5, 0.73, 0.96])
def test_cut_keeps_exactly_the_complete_messages(
    tmp_path: Path, kind: str, fraction: float, caplog: pytest.LogCaptureFixture
) -> None:
    src = _write(kind, tmp_path)
    data = src.read_bytes()
    ends = _payload_ends(data, ros1=kind.startswith("ros1"))
    cut = int(len(data) * fraction)
    path = tmp_path / ("cut" + src.suffix)
    path.write_bytes(data[:cut])
    kept = [m for m, end in zip(MSGS, ends, strict=True) if end <= cut]
    assert len(kept) <= len(MSGS)

    with caplog.at_level(logging.WARNING):
        result = _read(path)
    assert "salvage" in caplog.text
    assert result.salvage is not None and result.salvage.kept == len(kept)
    assert result.salvage.stopped_at_byte is not None and result.salvage.stopped_at_byte <= cut
    if kind == "mcap-unchunked" and kept:
        assert result.salvage.stopped_at_byte >= max(e for e in ends if e <= cut)
    _check_prefix(result, kept)
    info = salvage(path)
    assert (info.kept, info.stopped_at_byte) == (result.salvage.kept, result.salvage.stopped_at_byte)


@pytest.mark.parametrize("kind", ["mcap-zstd", "mcap-lz4", "ros1-bz2", "ros1-lz4"])
def test_cut_compressed_keeps_a_prefix(tmp_path: Path, kind: str) -> None:
    if kind.startswith("mcap"):
        src = write_mcap(tmp_path / "t.mcap", MSGS, compression=kind.split("-")[1])
    else:
        src = write_rosbag1(tmp_path / "t.bag", MSGS, compression=kind.split("-")[1], chunk_threshold=1500)
    data = src.read_bytes()
    previous = -1
    for fraction in (0.3, 0.6, 0.9):
        path = tmp_path / f"cut{fraction}{src.suffix}"
        path.write_bytes(data[:int(len(data) * fraction)])
        result = _read(path)
        assert result.salvage is not None
        kept = result.salvage.kept
        assert previous <= kept <= len(MSGS)
        previous = kept
        # what was kept is the first `kept` messages of the file, in order
        _check_prefix(result, MSGS[:kept])


@pytest.mark.parametrize("kind", ["mcap-zstd", "ros1-bz2", "ros1-lz4"])
def test_corrupt_chunk_stops_there(tmp_path: Path, kind: str) -> None:
    if kind == "mcap-zstd":
        src = write_mcap(tmp_path / "t.mcap", MSGS)
    else:
        src = write_rosbag1(tmp_path / "t.bag", MSGS, compression=kind.split("-")[1], chunk_threshold=1500)
    data = bytearray(src.read_bytes())
    at = len(data) // 2
    data[at:at + 16] = bytes(b ^ 0xFF for b in data[at:at + 16])
    path = tmp_path / ("bad" + src.suffix)
    path.write_bytes(bytes(data))
    result = _read(path)
    assert result.salvage is not None and result.salvage.stopped_at_byte is not None
    assert result.salvage.stopped_at_byte <= at
    assert 0 < result.salvage.kept < len(MSGS)
    _check_prefix(result, MSGS[:result.salvage.kept])


def test_intact_file_salvage_finds_no_damage(tmp_path: Path) -> None:
    path = write_mcap(tmp_path / "t.mcap", MSGS)
    info = salvage(path)
    assert info.kept == len(MSGS) and info.stopped_at_byte is None and info.reason == "no damage found"
    result = open_salvaged(path).read(REQUESTS)
    _check_prefix(result, MSGS)


def test_header_only_files(tmp_path: Path) -> None:
    for name, head in (("t.mcap", b"\x89MCAP0\r\n"), ("t.bag", b"#ROSBAG V2.0\n")):
        path = tmp_path / name
        path.write_bytes(head)
        reader = open_log(path)
        assert reader.topics() == {}
        assert reader.read({}).salvage is not None
