"""The reader protocol every log container implements, and the shared decode step.

A container reader (MCAP, ROS 1 bag, ROS 2 bag) only has to list its topics and yield the raw payloads of the
requested topics in storage order; :class:`RawReader` does the rest once for all of them: it validates the
requested topics and field paths against the message definitions before the long loop, decodes each topic by
the fast columnar path (:mod:`pipeline.io.cdr`) or per message (:mod:`pipeline.io.fields`), and cross-checks
the number of messages read against the number the storage says it holds.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import Protocol, runtime_checkable

import numpy as np

from pipeline.errors import IngestError
from pipeline.io.fields import TypeRegistry

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
class RawTopic:
    """Raw payloads of one topic gathered by a container reader."""

    log_ns: list[int] = field(default_factory=list)
    payloads: list[bytes] = field(default_factory=list)


class RawReader:
    """Base of the container readers: subclasses implement ``_scan``, ``_raw`` and set ``_encodings``.

    ``_scan()`` fills ``self._infos`` (topic -> TopicInfo), ``self._types`` (the TypeRegistry of the file's
    types) and ``self._encoding`` (topic -> "cdr" | "ros1" | other, unsupported).
    ``_raw(topics)`` returns topic -> RawTopic for the requested topics, in storage order.
    """

    format = "?"

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._infos: dict[str, TopicInfo] | None = None
        self._encoding: dict[str, str] = {}
        self._types: TypeRegistry | None = None
        self.allow_fast = True
        self.salvage: SalvageInfo | None = None

    # -- protocol -------------------------------------------------------------------------------------------
    def topics(self) -> dict[str, TopicInfo]:
        if self._infos is None:
            self._scan()
        assert self._infos is not None
        return dict(self._infos)

    def read(self, requests: dict[str, list[str]]) -> ReadResult:
        from pipeline.io import cdr, fields

        infos = self.topics()
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
        raw = self._raw(list(plans)) if plans else {}
        result = ReadResult(topics={}, failed=failed, salvage=self.salvage)
        for topic, fplans in plans.items():
            info = infos[topic]
            rt = raw.get(topic, RawTopic())
            expected = info.count
            if self.salvage is None and len(rt.payloads) != expected:
                raise IngestError(
                    f"read {len(rt.payloads)} messages but the storage holds {expected}", file=self.path,
                    topic=topic)
            ros1 = self._encoding[topic] == "ros1"
            try:
                data = cdr.decode_topic(self._types, info, rt, fplans, ros1=ros1, allow_fast=self.allow_fast)
            except Exception as err:  # noqa: BLE001 - a payload the definition does not describe
                log.warning("%s: topic %s failed to decode: %s", self.path, topic, err)
                result.failed[topic] = f"decoding failed: {type(err).__name__}: {err}"
                continue
            data.expected = expected if self.salvage is None else len(rt.payloads)
            result.topics[topic] = data
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

    def _scan(self) -> None:  # pragma: no cover - abstract
        raise NotImplementedError

    def _raw(self, topics: list[str]) -> dict[str, RawTopic]:  # pragma: no cover - abstract
        raise NotImplementedError
