"""The reader protocol every log container implements, and the shared decode step.

A container reader (MCAP, ROS 1 bag, ROS 2 bag) only has to list its topics and yield the payloads of the
requested topics in storage order, as batches (:class:`Batch`: one buffer of ~16 MB of decompressed chunks or
sqlite rows, and per topic the start, length and log time of each payload in it); :class:`RawReader` does the
rest once for all of them: it validates the requested topics and field paths against the message definitions
before the long loop, decodes each batch of each topic by the fast columnar path (:mod:`pipeline.io.cdr`) or per
message, fills the columns in place (memory stays near one copy of the extracted arrays plus one batch), and
cross-checks the number of messages read against the number the storage says it holds.
"""

from __future__ import annotations

import contextlib
import logging
import mmap
import queue
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol, runtime_checkable

import numpy as np

from pipeline.errors import IngestError
from pipeline.io.fields import TypeRegistry
from pipeline.io.msgdefs import UserTypes

log = logging.getLogger(__name__)


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


class Restart(Exception):
    """The reader found damage while reading and switched to its salvage path; read again from the start."""


_RESTARTS = 64  # each restart moves one more file (of a split bag) to its salvage path


#: Batches of the indexed readers (MCAP and ROS 1 chunks): 4 MB, not 16, so that a batch's record headers and
#: payloads are still in the CPU's caches when they are located and gathered after the read (``ingest_log`` of the
#: one-hour plain MCAP 0.278 -> 0.230 s of CPU, the four-hour one 0.859 -> 0.735; zstd and ROS 1 the same or a
#: little better; bench/ingest_knobs.py batch, docs/benchmarks.md sixth round).
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
    file held the whole file in the process's RSS (a four-hour bag, ~840 MB). Not a mapping: nothing to do."""
    if not isinstance(buf, mmap.mmap):
        return done
    upto = pos - pos % mmap.PAGESIZE
    if upto > done:
        buf.madvise(mmap.MADV_DONTNEED, done, upto - done)
    return max(done, upto)


class Batcher:
    """Collects payloads one by one (sqlite rows, a record walk) and hands them on as batches of ~16 MB."""

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


class RawReader:
    """Base of the container readers: subclasses implement ``_scan``, ``_raw`` and set ``_encodings``.

    ``_scan()`` fills ``self._infos`` (topic -> TopicInfo), ``self._types`` (the TypeRegistry of the file's
    types) and ``self._encoding`` (topic -> "cdr" | "ros1" | other, unsupported).
    ``_batches(topics)`` yields :class:`Batch` es holding the payloads of the requested topics, in storage order;
    it may raise :class:`Restart` after switching to the salvage path.
    """

    format = "?"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._infos: dict[str, TopicInfo] | None = None
        self._encoding: dict[str, str] = {}
        self._types: TypeRegistry | None = None
        self.user_types: UserTypes | None = None  # the user's message definitions, for types the log lacks
        self.allow_fast = True
        self.salvage: SalvageInfo | None = None

    # -- protocol -------------------------------------------------------------------------------------------
    def topics(self) -> dict[str, TopicInfo]:
        """Every topic with its type, message count and first / last log time, as the storage holds them."""
        return self.catalog()

    def catalog(self) -> dict[str, TopicInfo]:
        """The topics as cheaply listed: a reader may take the counts from the recorder's own summary (checked
        against what :meth:`read` finds) and leave first / last unknown (None) until read; :meth:`topics` is exact.
        """
        if self._infos is None:
            self._scan()
        assert self._infos is not None
        return dict(self._infos)

    def use_definitions(self, user: UserTypes | None) -> None:
        """Take the user's message definitions for the types this log does not embed (before anything is read)."""
        self.user_types = user
        self._infos = None  # has_header and the type registry depend on them: scan again

    def undecodable(self, topic: str) -> str | None:
        """Why ``topic`` cannot be decoded (no definition of its type, an encoding that is not CDR / ROS 1), or
        None; nothing is decoded."""
        info = self.catalog()[topic]
        return self._undecodable(topic, info.msgtype)

    # -- inspection (auvid inspect / init) -------------------------------------------------------------------
    def encoding(self, topic: str) -> str:
        """The topic's serialization as the storage states it: ``cdr``, ``ros1``, or another (unsupported)."""
        self.catalog()
        return self._encoding.get(topic, "")

    def field_paths(self, topic: str) -> list[str]:
        """The scalar leaf paths of the topic's type (arrays as ``name[i]``); IngestError if it has no
        definition."""
        from pipeline.io.fields import leaf_paths

        why = self.undecodable(topic)
        if why is not None:
            raise IngestError(f"cannot list the fields of {topic!r}: {why}", file=self.path, topic=topic)
        assert self._types is not None
        return leaf_paths(self._types.defs, self.catalog()[topic].msgtype)

    def log_times(self, topics: list[str]) -> dict[str, np.ndarray]:
        """The log time of every message of ``topics``, in storage order; nothing is decoded (works for types
        without a definition)."""
        parts: dict[str, list[np.ndarray]] = {t: [] for t in topics}
        for batch in (self._batches(list(topics)) if topics else ()):
            for topic, rows in batch.rows.items():
                if topic in parts:
                    parts[topic].append(np.asarray(rows.log_ns, dtype=np.int64))
        return {t: np.concatenate(p) if p else np.empty(0, dtype=np.int64) for t, p in parts.items()}

    def first_message(self, topic: str) -> Any:
        """The topic's first message, deserialized (rosbags objects), or None if it holds none or cannot be
        decoded."""
        if self.undecodable(topic) is not None:
            return None
        assert self._types is not None
        store = self._types.store
        msgtype = self.catalog()[topic].msgtype
        batches = self._batches([topic])
        try:
            for batch in batches:
                rows = batch.rows.get(topic)
                if rows is None or not len(rows.starts):
                    continue
                start, length = int(rows.starts[0]), int(rows.lengths[0])
                payload = batch.buf[start:start + length].tobytes()
                if self._encoding.get(topic) == "ros1":
                    return store.deserialize_ros1(payload, msgtype)
                return store.deserialize_cdr(payload, msgtype)
        finally:
            close = getattr(batches, "close", None)
            if close is not None:
                close()
        return None

    def read(self, requests: dict[str, list[str]]) -> ReadResult:
        for _ in range(_RESTARTS):
            try:
                return self._read(requests)
            except Restart:  # damage found while reading: the reader now reads that file by its salvage path
                continue
        return self._read(requests)

    def _read(self, requests: dict[str, list[str]]) -> ReadResult:
        from pipeline.io import fields

        infos = self.catalog()
        missing = [t for t in requests if t not in infos]
        if missing:
            raise IngestError(
                f"topic {missing[0]!r} not in {self.path.name}; available: {sorted(infos)}",
                file=self.path, topic=missing[0])
        failed: dict[str, str] = {}
        plans: dict[str, list[fields.FieldPath]] = {}
        for topic, paths in requests.items():
            why = self._undecodable(topic, infos[topic].msgtype)
            if why:
                log.warning("%s: topic %s cannot be decoded: %s", self.path, topic, why)
                failed[topic] = why
                continue
            msgtype = infos[topic].msgtype
            plans[topic] = [fields.resolve(self._types, msgtype, p, file=self.path, topic=topic) for p in paths]
        return self._decode(plans, failed, infos)

    def _decode(self, plans: dict[str, list[Any]], failed: dict[str, str], infos: dict[str, TopicInfo]) -> ReadResult:
        from pipeline.io import cdr

        assert self._types is not None
        decoders = {t: cdr.TopicDecoder(self._types, infos[t], fplans, ros1=self._encoding[t] == "ros1",
                                        allow_fast=self.allow_fast) for t, fplans in plans.items()}
        result = ReadResult(topics={}, failed=dict(failed))
        broken: dict[str, str] = {}
        for batch in (self._batches(list(plans)) if plans else ()):
            for topic, rows in batch.rows.items():
                if topic in broken or topic not in decoders:
                    continue
                try:
                    decoders[topic].feed(batch.buf, rows)
                except Exception as err:  # noqa: BLE001 - a payload the definition does not describe
                    log.warning("%s: topic %s failed to decode: %s", self.path, topic, err)
                    broken[topic] = f"decoding failed: {type(err).__name__}: {err}"
        result.salvage = self.salvage
        for topic, dec in decoders.items():
            expected = infos[topic].count
            if topic in broken:
                result.failed[topic] = broken[topic]
                continue
            if self.salvage is None and dec.read != expected:
                expected = self._recount(topic, dec.read, expected)
            if self.salvage is None and dec.read != expected:
                raise IngestError(f"read {dec.read} messages but the storage holds {expected}", file=self.path,
                                  topic=topic)
            result.topics[topic] = data = dec.result(expected if self.salvage is None else dec.read)
            self._was_read(topic, data)
        return result

    def close(self) -> None:
        """Release file handles (readers open files only while reading)."""

    def __enter__(self) -> RawReader:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    # -- helpers for subclasses -----------------------------------------------------------------------------
    def _undecodable(self, topic: str, msgtype: str) -> str | None:
        enc = self._encoding.get(topic, "")
        if enc not in ("cdr", "ros1"):
            return f"message encoding {enc!r} is not CDR or ROS 1; cannot decode"
        assert self._types is not None
        return self._types.ensure(msgtype)

    def _recount(self, topic: str, read: int, listed: int) -> int:
        """The storage's own count of ``topic`` when the listed count disagrees with what was read."""
        return listed

    def _was_read(self, topic: str, data: TopicData) -> None:
        """Hook: a reader whose catalog left something unknown fills it in from what was read."""

    def _scan(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _batches(self, topics: list[str]) -> Iterator[Batch]:  # pragma: no cover - abstract
        raise NotImplementedError


#: Bytes of a memory page, the period of :func:`aligned_empty`'s placement.
PAGE = 4096


def aligned_empty(size: int, phase: int = 0):
    """An uninitialised uint8 array of ``size`` bytes that starts ``phase`` bytes after a page boundary.

    The kernel copies a read from the page cache ~3.5x slower (0.09 s of CPU instead of 0.025 for 200 MB, here)
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
