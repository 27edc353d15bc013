"""Claimed sizes never drive allocation (issue 36, item 4): a chunk's uncompressed size beyond the cap, or beyond
what its bytes inflate to, is damage found before any buffer is grown for it."""

from __future__ import annotations

import bz2
import tracemalloc
from pathlib import Path

import pytest

from pipeline.io.errors import MAX_CHUNK_BYTES, Damaged
from pipeline.io.mcap_records import implausible_chunk
from pipeline.io.rosbag1_index import chunk_batches, index_walk
from pipeline.io.rosbag1_records import decompress
from tests.io.helpers import trial, write_rosbag1


def _peak_bytes_reading(path: Path, claimed: int, compression: str | None) -> tuple[Damaged, int]:
    bag = index_walk(path)
    assert bag is not None
    bag.chunks[0].size = claimed  # the chunk-info / chunk header's size= field, damaged
    topics = {c: conn.topic for c, conn in bag.walk.connections.items()}
    tracemalloc.start()
    try:
        with pytest.raises(Damaged) as info:
            list(chunk_batches(path, bag, topics))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    return info.value, peak


@pytest.mark.parametrize("compression", [None, "bz2", "lz4"])
def test_a_ros1_chunk_claiming_more_than_the_cap_is_damage_without_allocating(tmp_path: Path,
                                                                               compression: str | None) -> None:
    path = write_rosbag1(tmp_path / "t.bag", trial(n=40, seed=2), compression=compression, chunk_threshold=4000)
    err, peak = _peak_bytes_reading(path, 1 << 30, compression)  # 1 GiB claimed by an 8 kB bag
    assert "more than the 256 MiB" in err.reason
    assert peak < 32 << 20, f"{peak} bytes allocated for a claim"


@pytest.mark.parametrize("compression", ["bz2", "lz4"])
def test_a_ros1_chunk_claiming_more_than_it_inflates_to_is_damage_without_allocating(
        tmp_path: Path, compression: str) -> None:
    path = write_rosbag1(tmp_path / "t.bag", trial(n=40, seed=2), compression=compression, chunk_threshold=4000)
    err, peak = _peak_bytes_reading(path, MAX_CHUNK_BYTES, compression)  # under the cap, far beyond its bytes
    assert "size mismatch" in err.reason
    assert peak < 32 << 20, f"{peak} bytes allocated for a claim"


def test_ros1_inflation_stops_at_the_claim() -> None:
    bomb = bz2.compress(bytes(64 << 20))  # 64 MiB of zeros in a few hundred bytes
    assert len(decompress("bz2", bomb, partial=False, limit=1 << 20)) == (1 << 20) + 1


@pytest.mark.parametrize("compression", ["zstd", "lz4"])
def test_an_mcap_chunk_claiming_more_than_the_cap_is_implausible(compression: str) -> None:
    """Eight 0.5-GiB zstd chunks in a 132-kB file passed the ratio check (zstd inflates up to 32768x)."""
    assert implausible_chunk(compression, 16_500, 512 << 20) is not None
    assert "256 MiB" in str(implausible_chunk(compression, 16_500, 512 << 20))
    assert implausible_chunk(compression, 1 << 20, 4 << 20) is None  # a 4 MiB chunk (rosbag2's size) is fine
