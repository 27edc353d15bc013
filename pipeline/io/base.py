"""What every log reader speaks: the :class:`LogReader` protocol and its results, and the batches of payloads.

A container reader (MCAP, ROS 1 bag, ROS 2 bag) only has to list its topics and yield the payloads of the
requested topics in storage order, as batches (:class:`Batch`: one buffer of decompressed chunks or sqlite rows,
and per topic the start, length and log time of each payload in it); :class:`pipeline.io.reader.RawReader` does
the rest once for all of them. Here too: the vectorized helpers that read fields out of a batch's buffer, the
batcher and the streamed walk that turn a callback-style record walk into batches, and page-aligned scratch
buffers for the positioned reads.
"""

from __future__ import annotations

import contextlib
import mmap
import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class TopicInfo:
    """One topic as the storage describes it (no message decoded)."""

    topic: str
    msgtype: str
    count: int
    first_ns: int | None
    last_ns: int | None
    has_header: bool


@dataclass
class TopicData:
    """The decoded columns of one topic, in storage order."""

    topic: str
    msgtype: str
    log_ns: np.ndarray
    header_ns: np.ndarray | None
    columns: dict[str, np.ndarray]
    path: str
    read: int
    expected: int


@dataclass
class SalvageInfo:
    """What the salvage path kept from a damaged file."""

    kept: int
    stopped_at_byte: int | None
    reason: str
    duplicates: int = 0  # records dropped because the file holds them twice (pipeline.io.dedup)


@dataclass
class ReadResult:
    topics: dict[str, TopicData]
    failed: dict[str, str] = field(default_factory=dict)
    salvage: SalvageInfo | None = None


@runtime_checkable
class LogReader(Protocol):
    path: Path
    format: str

    def topics(self) -> dict[str, TopicInfo]: ...

    def read(self, requests: dict[str, list[str]]) -> ReadResult: ...

    def close(self) -> None: ...

    def __enter__(self) -> LogReader: ...

    def __exit__(self, *exc: object) -> None: ...


@dataclass
class Rows:
    """Where the payloads of one topic lie in a batch's buffer, in storage order, with their log times."""

    starts: np.ndarray
    lengths: np.ndarray
    log_ns: np.ndarray


@dataclass
class Batch:
    """A buffer of payload bytes (decompressed chunks, sqlite rows) and the rows of each requested topic in it."""

    buf: np.ndarray
    rows: dict[str, Rows]


def take_rows(buf: np.ndarray, at: np.ndarray, width: int) -> np.ndarray:
    """The ``width`` bytes at each offset ``at`` of the byte buffer ``buf``, as a new (len(at), width) array.

    One fancy index over a (stride 1) view of the buffer as ``width``-byte items: a memcpy per row, several
    times faster than indexing a 2-D ``sliding_window_view``.
    """
    if width > len(buf):
        if len(at):
            raise IndexError(f"{width} bytes at offsets into a buffer of {len(buf)}")
        return np.empty((0, width), dtype=np.uint8)
    items = np.ndarray(shape=(len(buf) - width + 1,), dtype=np.dtype((np.void, width)), buffer=buf, strides=(1,))
    return items[at].view(np.uint8).reshape(len(at), width)


def ascending(values: np.ndarray) -> bool:
    """Whether ``values`` never step back (equal neighbours allowed): the readers' record offsets and ingest's
    stamps are nearly always in order already, and then need no sort (one comparison pass, no argsort)."""
    return len(values) < 2 or bool((values[1:] >= values[:-1]).all())


def field_view(rows: np.ndarray, at: int, dtype: np.dtype | str) -> np.ndarray:
    """Bytes ``[at, at + itemsize)`` of every row of a C-contiguous (n, width) byte array, as a strided 1-D view
    of ``dtype`` values: no copy, and several times faster to read than a copy of the byte columns."""
    if not rows.shape[0]:
        return np.empty(0, dtype=dtype)
    return np.ndarray(shape=(rows.shape[0],), dtype=dtype, buffer=rows, offset=at, strides=(rows.strides[0],))


#: Batches of the indexed readers (MCAP and ROS 1 chunks): small enough that a batch's record headers and
#: payloads are still in the CPU's caches when they are located and gathered after the read
#: (docs/benchmarks.md, "Batch size").
BATCH_BYTES = 4 << 20
#: Batches of a streamed record walk (:func:`stream_walk`): smaller, since up to ``ahead`` + 2 of them are alive at
#: once (queued, being filled, being decoded), each as its payloads and then their joined copy.
WALK_BATCH_BYTES = 4 << 20
#: A record walk over a memory-mapped file gives back the pages behind it every this many bytes.
RELEASE_BYTES = 16 << 20


def release_behind(buf: bytes | mmap.mmap, done: int, pos: int) -> int:
    """Drop the pages of the read-only file mapping ``buf`` from ``done`` up to ``pos`` (rounded down to a page)
    from this process's resident memory; returns the new ``done``. The kernel keeps them in its page cache, and a
    later read of them (a duplicate check looking back) maps them again: without this, a walk over an unindexed
    file held the whole file in the process's RSS. Not a mapping: nothing to do."""
    if not isinstance(buf, mmap.mmap):
        return done
    upto = pos - pos % mmap.PAGESIZE
    if upto > done:
        buf.madvise(mmap.MADV_DONTNEED, done, upto - done)
    return max(done, upto)


class Batcher:
    """Collects payloads one by one (sqlite rows, a record walk) and hands them on as batches of ~``limit`` bytes."""

    def __init__(self, limit: int = BATCH_BYTES) -> None:
        self.limit = limit
        self._parts: list[bytes] = []
        self._topics: list[str] = []
        self._log_ns: list[int] = []
        self._size = 0

    def add(self, topic: str, log_ns: int, payload: bytes) -> Batch | None:
        self._parts.append(payload)
        self._topics.append(topic)
        self._log_ns.append(log_ns)
        self._size += len(payload)
        return self.flush() if self._size >= self.limit else None

    def flush(self) -> Batch | None:
        if not self._parts:
            return None
        parts, topics, stamps = self._parts, self._topics, self._log_ns
        self._parts, self._topics, self._log_ns, self._size = [], [], [], 0
        lengths = np.fromiter(map(len, parts), dtype=np.int64, count=len(parts))
        starts = np.zeros(len(parts), dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        buf = np.frombuffer(b"".join(parts), dtype=np.uint8)
        del parts
        log_ns = np.asarray(stamps, dtype=np.int64)
        names = np.asarray(topics, dtype=object)
        rows = {}
        for topic in dict.fromkeys(topics):
            m = names == topic
            rows[topic] = Rows(starts[m], lengths[m], log_ns[m])
        return Batch(buf, rows)


class _Stopped(Exception):
    """The consumer of a streamed walk went away."""


_DONE = object()


def stream_walk(walk: Callable[[Callable[[str, int, bytes], None]], object], limit: int = WALK_BATCH_BYTES,
                ahead: int = 2) -> Iterator[Batch]:
    """Batches of ~``limit`` bytes from a callback-style record walk, as the walk goes.

    ``walk(emit)`` calls ``emit(topic, log_ns, payload)`` for each wanted message. It runs in a thread that stays
    at most ``ahead`` batches in front of the consumer, so memory stays bounded however long the file (the walks
    of unindexed and damaged files are callback-style; the indexed paths are generators already). An exception
    in the walk is raised in the consumer; a consumer that stops early stops the walk.
    """
    q: queue.Queue[object] = queue.Queue(maxsize=ahead)
    stop = threading.Event()

    def put(item: object) -> None:
        while not stop.is_set():
            try:
                q.put(item, timeout=0.05)
                return
            except queue.Full:
                continue
        raise _Stopped

    def run() -> None:
        batcher = Batcher(limit)

        def emit(topic: str, log_ns: int, payload: bytes) -> None:
            batch = batcher.add(topic, log_ns, payload)
            if batch is not None:
                put(batch)

        try:
            walk(emit)
            last = batcher.flush()
            if last is not None:
                put(last)
            put(_DONE)
        except _Stopped:
            pass
        except BaseException as err:  # noqa: BLE001 - handed to the consumer, raised there
            with contextlib.suppress(_Stopped):
                put(err)

    thread = threading.Thread(target=run, name="record-walk", daemon=True)
    thread.start()
    try:
        while True:
            item = q.get()
            if item is _DONE:
                return
            if isinstance(item, BaseException):
                raise item
            assert isinstance(item, Batch)
            yield item
    finally:
        stop.set()
        thread.join()


#: Bytes of a memory page, the period of :func:`aligned_empty`'s placement.
PAGE = 4096


def aligned_empty(size: int, phase: int = 0):
    """An uninitialised uint8 array of ``size`` bytes that starts ``phase`` bytes after a page boundary.

    The kernel copies a read from the page cache several times slower (docs/benchmarks.md, "Read alignment")
    when the destination lies 8 to 40 bytes after the source in their pages ("4K aliasing" of the copy's loads
    and stores), and a large numpy array starts 16 bytes into a page: every page-aligned read into one (a sqlite
    page) hit it. A reader places each read at its file offset's phase in the page instead."""
    import numpy as np  # here: a plain ``import pipeline.io`` stays free of numpy

    raw = np.empty(size + PAGE, dtype=np.uint8)
    start = (phase - raw.ctypes.data) % PAGE
    return raw[start:start + size]


def scratch_buffer(scratch: list, size: int, phase: int = 0):
    """``size`` bytes of the reusable uint8 buffer ``scratch[0]`` (a page-aligned array), starting ``phase`` (mod
    :data:`PAGE`) bytes after a page boundary, the buffer grown (with 1/8 headroom) when too small: the batched
    readers read each batch's pages or chunks into it, at the phase of the file offset read from
    (:func:`aligned_empty`), instead of allocating one per batch."""
    phase %= PAGE
    if len(scratch[0]) < phase + size:
        scratch[0] = aligned_empty(size + (size >> 3) + PAGE)
    return scratch[0][phase:phase + size]
