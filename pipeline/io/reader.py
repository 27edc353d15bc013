"""The shared decode step: :class:`RawReader`, the base of the container readers (MCAP, ROS 1 bag, ROS 2 bag).

A subclass lists its topics and yields batches of payloads (:class:`pipeline.io.base.Batch`); the base validates
the requested topics and field paths against the message definitions before the long loop, decodes each batch of
each topic by the fast columnar path (:mod:`pipeline.io.cdr`) or per message, fills the columns in place (memory
stays near one copy of the extracted arrays plus one batch), and cross-checks the number of messages read against
the number the storage says it holds.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from types import TracebackType
from typing import Any, TypeVar

import numpy as np

from pipeline.errors import IngestError
from pipeline.io.base import Batch, ReadResult, SalvageInfo, TopicData, TopicInfo
from pipeline.io.errors import Restart
from pipeline.io.fields import TypeRegistry
from pipeline.io.msgdefs import UserTypes

log = logging.getLogger(__name__)

_T = TypeVar("_T")
_RESTARTS = 64  # each restart moves one more file (of a split bag) to its salvage path


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
        return self._restarting(lambda: self._log_times(topics))

    def _log_times(self, topics: list[str]) -> dict[str, np.ndarray]:
        parts: dict[str, list[np.ndarray]] = {t: [] for t in topics}
        for batch in (self._batches(list(topics)) if topics else ()):
            for topic, rows in batch.rows.items():
                if topic in parts:
                    parts[topic].append(np.asarray(rows.log_ns, dtype=np.int64))
        return {t: np.concatenate(p) if p else np.empty(0, dtype=np.int64) for t, p in parts.items()}

    def first_message(self, topic: str) -> Any:
        """The topic's first message, deserialized (rosbags objects), or None if it holds none or cannot be
        decoded."""
        return self._restarting(lambda: self._first_message(topic))

    def _first_message(self, topic: str) -> Any:
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
        return self._restarting(lambda: self._read(requests))

    def _restarting(self, run: Callable[[], _T]) -> _T:
        """``run()``, again each time it raises :class:`Restart` (every pass over the batches can meet damage:
        ``read``, and `auvid inspect`'s ``log_times`` and ``first_message``)."""
        for _ in range(_RESTARTS):
            try:
                return run()
            except Restart:  # damage found while reading: the reader now reads that file by its salvage path,
                self.catalog()  # listed again by it (read() does this itself; log_times did not, and looped)
        return run()

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
