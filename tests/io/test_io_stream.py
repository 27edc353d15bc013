"""Streamed record walks (unindexed and damaged files): batches flow while the walk goes, memory stays bounded."""

from __future__ import annotations

import mmap
import sys
import threading
from pathlib import Path

import pytest

from pipeline.io import base, mcap_reader, open_log, rosbag1
from pipeline.io.base import release_behind, stream_walk
from tests.io.helpers import REQUESTS, expected, trial, write_mcap, write_rosbag1_unindexed


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


def _mapped_kib(path: Path) -> int:
    """Resident KiB of this process's mappings of ``path`` (/proc/self/smaps)."""
    total, mine = 0, False
    for line in Path("/proc/self/smaps").read_text().splitlines():
        if line[:1].isdigit() or line[:1] in "abcdef" and "-" in line.split()[0]:
            mine = line.rstrip().endswith(str(path))
        elif mine and line.startswith("Rss:"):
            total += int(line.split()[1])
    return total


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc/self/smaps")
def test_release_behind_gives_the_walked_pages_back(tmp_path: Path) -> None:
    path = tmp_path / "log.bin"
    path.write_bytes(bytes(range(256)) * (8 << 12))  # 8 MiB
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        assert sum(mm[i] for i in range(0, len(mm), mmap.PAGESIZE)) >= 0  # every page touched
        assert _mapped_kib(path) >= 8000
        done = release_behind(mm, 0, len(mm) - 5000)
        assert done == len(mm) - mmap.PAGESIZE * 2 and _mapped_kib(path) <= 8
        assert release_behind(mm, done, done + 1) == done  # less than a page further: nothing to give back
    assert release_behind(b"not a mapping", 0, 1 << 20) == 0


@pytest.mark.parametrize("kind", ["mcap", "ros1"])
def test_unindexed_walks_give_back_the_file_behind_them(tmp_path: Path, kind: str,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    """An unindexed MCAP and a ROS 1 bag with no index are read by their record walks: every message is kept,
    and the pages behind each walk are given back as it goes (every 64 KiB here), up to the last stretch."""
    msgs = trial(n=400)
    if kind == "mcap":
        path = write_mcap(tmp_path / "t.mcap", msgs, compression="none", chunked=False, summary=False,
                          indexes=False)
    else:
        path = write_rosbag1_unindexed(tmp_path / "t.bag", msgs)
    module = mcap_reader if kind == "mcap" else rosbag1
    given: list[tuple[int, int]] = []

    def spy(buf: object, done: int, pos: int) -> int:
        new = release_behind(buf, done, pos)  # type: ignore[arg-type]
        if isinstance(buf, mmap.mmap):
            given.append((done, new))
        return new

    monkeypatch.setattr(module, "RELEASE_BYTES", 64 << 10)
    monkeypatch.setattr(module, "release_behind", spy)
    with open_log(path) as reader:
        topics = reader.read(REQUESTS).topics
    want = expected(msgs)
    assert {t: d.read for t, d in topics.items()} == {t: len(c["log_ns"]) for t, c in want.items()}
    size = path.stat().st_size
    walks = [i for i, (done, _) in enumerate(given) if done == 0]
    assert len(walks) >= 2  # the catalog's walk and the read's
    for start, stop in zip(walks, [*walks[1:], len(given)], strict=True):
        steps = given[start:stop]
        assert all(a == b_prev for (a, _), (_, b_prev) in zip(steps[1:], steps, strict=False))  # no gap
        assert steps[-1][1] >= size - (64 << 10) - 2 * mmap.PAGESIZE
    assert base.RELEASE_BYTES == 16 << 20
