"""Streamed record walks (unindexed and damaged files): batches flow while the walk goes, memory stays bounded."""

from __future__ import annotations

import threading

import pytest

from pipeline.io.base import stream_walk


def _walker(n: int, progress: list[int], fail_at: int | None = None):
    def walk(emit) -> None:
        for i in range(n):
            if i == fail_at:
                raise ValueError(f"damaged at message {i}")
            emit("/t" if i % 2 else "/u", 1000 + i, bytes([i % 256]) * 10)
            progress.append(i)
    return walk


def test_batches_come_while_the_walk_goes_and_keep_every_message_in_order() -> None:
    progress: list[int] = []
    batches = stream_walk(_walker(100, progress), limit=10, ahead=2)
    first = next(batches)
    # one message a batch: the walk is at most the queue (2), the batch being put and the one taken ahead
    assert len(progress) <= 5
    got = [first, *batches]
    assert len(progress) == 100 and len(got) == 100
    stamps = sorted(int(r.log_ns[0]) for b in got for r in b.rows.values())
    assert stamps == list(range(1000, 1100))
    assert all(b.buf.tobytes() == bytes([int(next(iter(b.rows.values())).log_ns[0]) - 1000]) * 10 for b in got)


def test_an_error_in_the_walk_is_raised_to_the_reader_after_the_batches_before_it() -> None:
    progress: list[int] = []
    seen = []
    with pytest.raises(ValueError, match="damaged at message 7"):
        for batch in stream_walk(_walker(100, progress, fail_at=7), limit=30, ahead=2):
            seen.append(batch)
    assert sum(len(r.starts) for b in seen for r in b.rows.values()) == 6  # two full batches of three


def test_a_reader_that_stops_early_stops_the_walk() -> None:
    progress: list[int] = []
    batches = stream_walk(_walker(10_000, progress), limit=10, ahead=2)
    next(batches)
    batches.close()
    assert not any(t.name == "record-walk" for t in threading.enumerate())
    assert len(progress) < 10
