"""The batched readers read each batch into their buffer at the file offset's phase in the page.

A large numpy array starts 16 bytes into a page; the kernel's copy of a page-aligned read into it (every sqlite
page read) runs ~3.5x slower than into memory at the same phase as the file offset (4K aliasing; figures in
docs/benchmarks.md). Nothing else shows it: the values are the same either way. So these tests watch the reads
themselves: every ``os.preadv`` of a batch lands at an address congruent to its file offset modulo the page.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from pipeline.io import mcap_index, sqlite_btree
from pipeline.io.base import PAGE, aligned_empty, scratch_buffer
from tests.io.helpers import trial, write_mcap
from tests.io.test_io_sqlite_btree import root_of, write_db


@pytest.mark.parametrize("phase", [0, 16, 1000, PAGE - 1, PAGE + 24, 10 * PAGE + 7])
def test_aligned_empty_and_the_scratch_buffer_start_at_the_phase_asked(phase: int) -> None:
    arr = aligned_empty(12345, phase)
    assert arr.dtype == np.uint8 and len(arr) == 12345
    assert arr.ctypes.data % PAGE == phase % PAGE
    scratch = [np.empty(0, dtype=np.uint8)]
    for size in (100, 50_000, 30):  # grown once, then reused: the phase holds each time
        buf = scratch_buffer(scratch, size, phase=phase)
        assert len(buf) == size and buf.ctypes.data % PAGE == phase % PAGE
        buf[:] = 7  # writable, and inside the scratch array
        assert np.shares_memory(buf, scratch[0])


def _watch_reads(monkeypatch: pytest.MonkeyPatch, module: object) -> list[tuple[int, int, int]]:
    """(destination address, file offset, bytes) of every ``os.preadv`` the module makes."""
    seen: list[tuple[int, int, int]] = []
    real = os.preadv

    def preadv(fd: int, buffers: list, offset: int) -> int:
        arr = np.frombuffer(buffers[0], dtype=np.uint8)
        seen.append((arr.ctypes.data, offset, len(arr)))
        return real(fd, buffers, offset)

    monkeypatch.setattr(module.os, "preadv", preadv)
    return seen


@pytest.mark.parametrize("page_size", [1024, 4096])
def test_sqlite_leaf_pages_are_read_at_their_phase(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                   page_size: int) -> None:
    rng = np.random.default_rng(11)
    path = tmp_path / "m.db3"
    truth = write_db(path, [(1 + i % 3, 1_700_000_000_000_000_000 + i, rng.bytes(int(rng.integers(0, 300))))
                            for i in range(6000)], page_size)
    seen = _watch_reads(monkeypatch, sqlite_btree)
    rows = sum(len(b.starts) for b in sqlite_btree.row_batches(path, root_of(path), limit=64 * page_size))
    assert rows == len(truth)
    assert len(seen) > 3  # several batches, each one read of its span of pages
    assert [(addr - offset) % PAGE for addr, offset, _ in seen] == [0] * len(seen)


def test_uncompressed_mcap_chunks_are_read_at_their_phase(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    path = write_mcap(tmp_path / "t.mcap", trial(400, seed=3), compression="none")
    indexed = mcap_index.index_walk(path)
    assert indexed is not None
    wanted = {cid: ch.topic for cid, ch in indexed.walk.channels.items()}
    seen = _watch_reads(monkeypatch, mcap_index)
    batches = list(mcap_index.chunk_batches(path, indexed, wanted, limit=8 << 10))
    assert len(batches) > 3 and len(seen) == len(batches)
    assert {offset % PAGE for _, offset, _ in seen} != {0}  # chunks start anywhere in a page...
    assert [(addr - offset) % PAGE for addr, offset, _ in seen] == [0] * len(seen)  # ...and land in phase
