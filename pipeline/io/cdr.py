"""Decode one topic into columns: the fast columnar path, with a per-message fallback.

The fast path never builds a Python object per message. All payloads of a topic are concatenated into one
buffer; for each requested field the byte offset is computed from the message definition, as a numpy array over
the messages, so that strings and sequences before the field (whose lengths vary per message) are skipped with
vectorized reads of their length prefixes. CDR aligns each primitive to its size, relative to the end of the
4-byte encapsulation header; ROS 1 has no alignment and no header. Whole columns are then gathered with one
fancy-indexing read. Whatever the fast path cannot describe (a selection by name, a sequence of varying length
of strings or structs, big-endian CDR, a payload shorter than its definition) is decoded per message by rosbags,
and :attr:`TopicData.path` says which path was taken. Both paths give bit-identical values.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from rosbags.typesys.base import Nodetype

from pipeline.io.base import RawTopic, TopicData, TopicInfo
from pipeline.io.fields import FieldPath, Step, TypeRegistry, extract, header_ns

log = logging.getLogger(__name__)

SIZES = {
    "bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4, "uint32": 4,
    "int64": 8, "uint64": 8, "float32": 4, "float64": 8,
}
DTYPES = {
    "bool": "u1", "byte": "u1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "<i2", "uint16": "<u2",
    "int32": "<i4", "uint32": "<u4", "int64": "<i8", "uint64": "<u8", "float32": "<f4", "float64": "<f8",
}
_HEADER_STEPS = {
    "sec": (Step("attr", name="header"), Step("attr", name="stamp"), Step("attr", name="sec")),
    "nanosec": (Step("attr", name="header"), Step("attr", name="stamp"), Step("attr", name="nanosec")),
}


class Bail(Exception):
    """The fast path cannot describe this topic; decode it per message."""


class Columnar:
    """Concatenated payloads of one topic and vectorized reads into them."""

    def __init__(self, payloads: list[bytes], *, ros1: bool, defs: dict[str, Any]) -> None:
        self.ros1 = ros1
        self.defs = defs
        lengths = np.fromiter((len(p) for p in payloads), dtype=np.int64, count=len(payloads))
        starts = np.zeros(len(payloads), dtype=np.int64)
        if len(payloads) > 1:
            np.cumsum(lengths[:-1], out=starts[1:])
        self.buf = np.frombuffer(b"".join(payloads), dtype=np.uint8)
        head = 0 if ros1 else 4
        self.base = starts + head
        self.room = lengths - head
        if not ros1 and len(payloads):
            if (lengths < 4).any() or (self.buf[starts + 1] != 1).any() or (self.buf[starts] != 0).any():
                raise Bail("not little-endian plain CDR")

    def _align(self, pos: np.ndarray, size: int) -> np.ndarray:
        if self.ros1 or size <= 1:
            return pos
        return (pos + (size - 1)) // size * size

    def gather(self, pos: np.ndarray, base_type: str) -> np.ndarray:
        size = SIZES[base_type]
        pos = self._align(pos, size)
        if len(pos) and ((pos + size) > self.room).any():
            raise Bail("payload shorter than its definition")
        idx = (self.base + pos)[:, None] + np.arange(size, dtype=np.int64)
        return np.ascontiguousarray(self.buf[idx]).view(DTYPES[base_type]).ravel()

    def _u32(self, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos = self._align(pos, 4)
        return self.gather(pos, "uint32").astype(np.int64), pos + 4

    def skip(self, node: tuple[int, Any], pos: np.ndarray) -> np.ndarray:
        kind, detail = node
        if kind == Nodetype.BASE:
            name = detail[0]
            if name == "string":
                length, pos = self._u32(pos)
                return pos + length
            if name not in SIZES:
                raise Bail(f"type {name}")
            return self._align(pos, SIZES[name]) + SIZES[name]
        if kind == Nodetype.NAME:
            for _, sub in self.defs[detail][1]:
                pos = self.skip(sub, pos)
            return pos
        sub, n = detail
        if kind == Nodetype.SEQUENCE:
            n, pos = self._u32(pos)
        return self.skip_elements(sub, n, pos)

    def skip_elements(self, sub: tuple[int, Any], n: int | np.ndarray, pos: np.ndarray) -> np.ndarray:
        if sub[0] == Nodetype.BASE and sub[1][0] in SIZES:
            size = SIZES[sub[1][0]]
            if isinstance(n, np.ndarray):
                return np.where(n > 0, self._align(pos, size) + n * size, pos)
            return self._align(pos, size) + n * size if n else pos
        if isinstance(n, np.ndarray):
            if len(n) and (n != n[0]).any():
                raise Bail("sequence of varying length of strings or structs")
            n = int(n[0]) if len(n) else 0
        for _ in range(n):
            pos = self.skip(sub, pos)
        return pos

    def column(self, top: str, steps: tuple[Step, ...], n: int) -> np.ndarray:
        pos = np.zeros(n, dtype=np.int64)
        cur = top
        node: tuple[int, Any] = (Nodetype.NAME, top)
        for step in steps:
            if step.kind == "attr":
                for name, sub in self.defs[cur][1]:
                    if name == step.name:
                        node = sub
                        break
                    pos = self.skip(sub, pos)
            elif step.kind == "index":
                kind, (sub, length) = node
                if kind == Nodetype.SEQUENCE:
                    length, pos = self._u32(pos)
                    if len(length) and (length <= step.index).any():
                        raise Bail("index beyond the sequence in some messages")
                pos = self.skip_elements(sub, step.index, pos)
                node = sub
            else:
                raise Bail("selection by name")
            if node[0] == Nodetype.NAME:
                cur = node[1]
        return self.gather(pos, node[1][0])


def _as_float(values: np.ndarray, base_type: str) -> np.ndarray:
    if base_type == "bool":
        return (values != 0).astype(np.float64)
    return values.astype(np.float64)


def fast_columns(
    registry: TypeRegistry, msgtype: str, payloads: list[bytes], plans: list[FieldPath], *, ros1: bool,
    has_header: bool,
) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """Columns of one topic without decoding messages; raises :class:`Bail` when it cannot."""
    col = Columnar(payloads, ros1=ros1, defs=registry.defs)
    n = len(payloads)
    # The definition must describe every payload exactly (as rosbags checks per message): a type that differs
    # from what was recorded (e.g. a standard type that changed between ROS distributions) is not read.
    end = col.skip((Nodetype.NAME, msgtype), np.zeros(n, dtype=np.int64))
    slack = col.room - end
    if n and ((slack < 0).any() or (slack != 0 if ros1 else slack > 3).any()):
        raise Bail("payload sizes do not match the definition")
    out = {fp.text: _as_float(col.column(msgtype, fp.steps, n), fp.leaf) for fp in plans}
    stamps = None
    if has_header:
        sec = col.column(msgtype, _HEADER_STEPS["sec"], n).astype(np.int64)
        nsec = col.column(msgtype, _HEADER_STEPS["nanosec"], n).astype(np.int64)
        stamps = sec * 1_000_000_000 + nsec
    return out, stamps


def slow_columns(
    registry: TypeRegistry, msgtype: str, payloads: list[bytes], plans: list[FieldPath], *, ros1: bool,
    has_header: bool,
) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """Columns of one topic, one rosbags message object per payload."""
    store = registry.store
    deser = store.deserialize_ros1 if ros1 else store.deserialize_cdr
    n = len(payloads)
    out = {fp.text: np.empty(n, dtype=np.float64) for fp in plans}
    stamps = np.empty(n, dtype=np.int64) if has_header else None
    for i, raw in enumerate(payloads):
        msg = deser(raw, msgtype)
        for fp in plans:
            out[fp.text][i] = extract(msg, fp)
        if stamps is not None:
            stamps[i] = header_ns(msg)
    return out, stamps


def decode_topic(
    registry: TypeRegistry, info: TopicInfo, raw: RawTopic, plans: list[FieldPath], *, ros1: bool,
    allow_fast: bool = True,
) -> TopicData:
    """Decode the requested fields of one topic, by the fast path when it can describe them."""
    path = "fast"
    columns: dict[str, np.ndarray]
    try:
        if not allow_fast:
            raise Bail("fast path disabled")
        columns, stamps = fast_columns(registry, info.msgtype, raw.payloads, plans, ros1=ros1,
                                       has_header=info.has_header)
    except Bail as why:
        log.debug("topic %s: per-message decoding (%s)", info.topic, why)
        path = "per-message"
        columns, stamps = slow_columns(registry, info.msgtype, raw.payloads, plans, ros1=ros1,
                                       has_header=info.has_header)
    return TopicData(
        topic=info.topic, msgtype=info.msgtype, log_ns=np.asarray(raw.log_ns, dtype=np.int64), header_ns=stamps,
        columns=columns, path=path, read=len(raw.payloads), expected=info.count)
