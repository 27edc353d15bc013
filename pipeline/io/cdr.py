"""Decode one topic into columns: the fast columnar path, with a per-message fallback.

The fast path never builds a Python object per message. A container reader hands over batches: one byte buffer
(decompressed chunks) and, per topic, the start and length of each payload in it. For each requested field the
byte offset is computed from the message definition, as a numpy array over the messages, so that strings and
sequences before the field (whose lengths vary per message) are skipped with vectorized reads of their length
prefixes; a sequence of structs whose length varies is skipped group by group (messages with the same length
together). CDR aligns each primitive to its size, relative to the end of the 4-byte encapsulation header, in the
byte order that header names; ROS 1 has no alignment and no header. Whole columns are then gathered with one
vectorized read per byte. A selection by name (``velocity[name=th1]``) compares the strings of the key list
column-wise. Whatever the fast path cannot describe (a payload shorter or longer than its definition, mixed byte
orders, an unknown type) is decoded per message by rosbags, batch by batch, and :attr:`TopicData.path` says which
path was taken. Both paths give bit-identical values.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np
from rosbags.typesys.base import Nodetype

from pipeline.io.base import Rows, TopicData, TopicInfo, field_view, take_rows
from pipeline.io.fields import FieldPath, Step, TypeRegistry, extract, header_ns

log = logging.getLogger(__name__)

SIZES = {
    "bool": 1, "byte": 1, "char": 1, "int8": 1, "uint8": 1, "int16": 2, "uint16": 2, "int32": 4, "uint32": 4,
    "int64": 8, "uint64": 8, "float32": 4, "float64": 8,
}
DTYPES = {
    "bool": "u1", "byte": "i1", "char": "u1", "int8": "i1", "uint8": "u1", "int16": "i2", "uint16": "u2",
    "int32": "i4", "uint32": "u4", "int64": "i8", "uint64": "u8", "float32": "f4", "float64": "f8",
}
_HEADER_STEPS = {
    "sec": (Step("attr", name="header"), Step("attr", name="stamp"), Step("attr", name="sec")),
    "nanosec": (Step("attr", name="header"), Step("attr", name="stamp"), Step("attr", name="nanosec")),
}
MAX_GROUPS = 64  # distinct lengths of one struct sequence in one batch before giving up


class Bail(Exception):
    """The fast path cannot describe this batch; decode it per message."""


class Columnar:
    """Payloads of one topic in a shared buffer, and vectorized reads into them.

    Positions are relative to the start of each message's body (after the CDR header); every method takes the
    message indices ``rows`` that its positions ``pos`` belong to.
    """

    def __init__(self, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray, *, ros1: bool,
                 defs: dict[str, Any]) -> None:
        self.ros1 = ros1
        self.defs = defs
        self.buf = buf
        head = 0 if ros1 else 4
        self.base = starts + head
        self.room = lengths - head
        self.order = "<"
        self.mat: np.ndarray | None = None
        self.probe: list[tuple[int, int]] | None = None  # byte ranges that decide the layout (one-message probe)
        self.n = len(starts)
        self._strs: dict[int, tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]] = {}
        self._cache: dict[tuple[Step, ...], tuple[Any, ...]] = {}
        if not ros1 and len(starts):
            if (lengths < 4).any() or (buf[starts] != 0).any():
                raise Bail("not plain CDR")
            flags = buf[starts + 1]
            if (flags > 1).any() or (len(flags) > 1 and (flags != flags[0]).any()):
                raise Bail("mixed or unknown CDR byte orders")
            self.order = "<" if flags[0] == 1 else ">"

    def _align(self, pos: np.ndarray, size: int) -> np.ndarray:
        if self.ros1 or size <= 1:
            return pos
        return (pos + (size - 1)) & ~(size - 1)

    def gather(self, rows: np.ndarray, pos: np.ndarray, base_type: str) -> np.ndarray:
        size = SIZES[base_type]
        pos = self._align(pos, size)
        if len(pos) and ((pos + size) > self.room[rows]).any():
            raise Bail("payload shorter than its definition")
        if self.mat is not None and len(rows) == self.n and len(pos) and (pos == pos[0]).all():
            a = int(pos[0]) + (0 if self.ros1 else 4)  # the same offset in every message: one strided copy
            raw = np.ascontiguousarray(self.mat[:, a:a + size])
        else:
            at = self.base[rows] + pos
            raw = self.buf[at] if size == 1 else take_rows(self.buf, at, size)
        dtype = DTYPES[base_type] if size == 1 else self.order + DTYPES[base_type]
        return raw.view(dtype).ravel()

    def densify(self, limit: int = 1 << 16) -> None:
        """Copy the payloads into one (messages x length) matrix when all have the same length."""
        lengths = self.room + (0 if self.ros1 else 4)
        if not self.n or (lengths != lengths[0]).any():
            return
        width = int(lengths[0])
        starts = self.base - (0 if self.ros1 else 4)
        if width > limit or width < 1 or int(starts[-1]) + width > len(self.buf):
            return
        self.mat = take_rows(self.buf, starts, width)
        self.buf = self.mat.reshape(-1)
        self.base = np.arange(self.n, dtype=np.int64) * width + (0 if self.ros1 else 4)
        self._strs = {}

    def _u32(self, rows: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pos = self._align(pos, 4)
        if self.probe is not None and len(pos):
            self.probe.append((int(pos[0]), 4))
        return self.gather(rows, pos, "uint32").astype(np.int64), pos + 4

    def skip(self, node: tuple[int, Any], rows: np.ndarray, pos: np.ndarray) -> np.ndarray:
        kind, detail = node
        if kind == Nodetype.BASE:
            name = detail[0]
            if name == "string":
                length, pos = self._u32(rows, pos)
                end = pos + length
                if len(end) and (end > self.room[rows]).any():
                    raise Bail("string beyond the payload")
                return end
            if name not in SIZES:
                raise Bail(f"type {name}")
            return self._align(pos, SIZES[name]) + SIZES[name]
        if kind == Nodetype.NAME:
            for _, sub in self.defs[detail][1]:
                pos = self.skip(sub, rows, pos)
            return pos
        sub, n = detail
        if kind == Nodetype.SEQUENCE:
            n, pos = self._u32(rows, pos)
            if len(n) and (n > self.room[rows]).any():
                raise Bail("sequence length beyond the payload")
        return self.skip_elements(sub, n, rows, pos)

    def skip_elements(self, sub: tuple[int, Any], n: int | np.ndarray, rows: np.ndarray,
                      pos: np.ndarray) -> np.ndarray:
        if sub[0] == Nodetype.BASE and sub[1][0] in SIZES:
            size = SIZES[sub[1][0]]
            if isinstance(n, np.ndarray):
                return np.where(n > 0, self._align(pos, size) + n * size, pos)
            return self._align(pos, size) + n * size if n else pos
        if isinstance(n, np.ndarray):
            if not len(n):
                return pos
            if (n == n[0]).all():
                n = int(n[0])
            else:
                values = np.unique(n)
                if len(values) > MAX_GROUPS:
                    raise Bail("too many distinct lengths of a sequence of strings or structs")
                out = np.empty_like(pos)
                for v in values.tolist():
                    m = n == v
                    out[m] = self.skip_elements(sub, int(v), rows[m], pos[m])
                return out
        for _ in range(n):
            pos = self.skip(sub, rows, pos)
        return pos

    def _strings(self, rows: np.ndarray, pos: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """For each element ``j`` of the string sequence at ``pos``: the messages that have it, where its text
        starts and how long the text is (as rosbags decodes it: CDR's terminating NUL dropped). Cached."""
        key = id(pos)
        if key in self._strs:
            return self._strs[key][1]
        n, p = self._u32(rows, pos)
        if len(n) and (n > self.room[rows]).any():
            raise Bail("sequence length beyond the payload")
        out = []
        live = np.arange(len(rows))
        for j in range(int(n.max()) if len(n) else 0):
            live = live[n[live] > j]
            length, start = self._u32(rows[live], p[live])
            end = start + length
            if len(end) and (end > self.room[rows[live]]).any():
                raise Bail("string beyond the payload")
            p = p.copy()
            p[live] = end
            out.append((live, start, length - (0 if self.ros1 else 1)))
            if self.probe is not None and len(live):
                self.probe.append((int(start[0]), int(length[0])))
        self._strs[key] = (pos, out)
        return out

    def _select_index(self, rows: np.ndarray, pos: np.ndarray, key: bytes) -> np.ndarray:
        """Index of the first string equal to ``key`` in the string sequence at ``pos``; -1 where absent."""
        idx = np.full(len(rows), -1, dtype=np.int64)
        want = np.frombuffer(key, dtype=np.uint8)
        for j, (live, start, length) in enumerate(self._strings(rows, pos)):
            cand = live[(length == len(key)) & (idx[live] < 0)]
            if not len(cand) or not len(key):
                idx[cand] = j
                continue
            at = self.base[rows[cand]] + start[np.searchsorted(live, cand)]
            eq = (take_rows(self.buf, at, len(key)) == want).all(axis=1)
            idx[cand[eq]] = j
        return idx

    def column(self, top: str, steps: tuple[Step, ...], n: int) -> tuple[np.ndarray, str]:
        """Values of one field path for all ``n`` messages (NaN where an index or name is absent)."""
        rows, pos, leaf = self.locate(top, steps, n)
        return self.values(rows, pos, leaf, n)

    def values(self, rows: np.ndarray, pos: np.ndarray, leaf: str, n: int) -> tuple[np.ndarray, str]:
        values = self.gather(rows, pos, leaf)
        if len(rows) == n:
            return values, leaf
        out = np.full(n, np.nan)
        out[rows] = _as_float(values, leaf)
        return out, "float64"

    def gather_many(self, pos: list[np.ndarray], leaves: list[str]) -> list[np.ndarray] | None:
        """Fields of all messages at a constant distance from the first, read with one gather; None if not."""
        sizes = [SIZES[leaf] for leaf in leaves]
        pos = [self._align(p, z) for p, z in zip(pos, sizes, strict=True)]
        first = pos[0]
        if not len(first):
            return None
        deltas = []
        for p in pos:
            d = p[0] - first[0]
            if d < 0 or d > 256 or (p - first != d).any():
                return None
            deltas.append(int(d))
        width = max(d + z for d, z in zip(deltas, sizes, strict=True))
        at = self.base + first
        if (at + width > len(self.buf)).any():
            return None
        for d, z in zip(deltas, sizes, strict=True):
            if (first + d + z > self.room).any():
                raise Bail("payload shorter than its definition")
        win = take_rows(self.buf, at, width)
        out = []
        for d, z, leaf in zip(deltas, sizes, leaves, strict=True):
            dtype = DTYPES[leaf] if z == 1 else self.order + DTYPES[leaf]
            out.append(np.ascontiguousarray(win[:, d:d + z]).view(dtype).ravel())
        return out

    def locate(self, top: str, steps: tuple[Step, ...], n: int) -> tuple[np.ndarray, np.ndarray, str]:
        """Messages that hold the field (all but those where an index or name is absent), its positions, type."""
        rows = np.arange(n, dtype=np.int64)
        pos = np.zeros(n, dtype=np.int64)
        cur = top
        node: tuple[int, Any] = (Nodetype.NAME, top)
        starts: dict[str, np.ndarray] = {}
        first = 0
        for k in range(len(steps), 0, -1):
            if steps[:k] in self._cache:
                rows, pos, cur, node, starts = self._cache[steps[:k]]
                first = k
                break
        for i, step in enumerate(steps):
            if i < first:
                continue
            if step.kind == "attr":
                fields = self.defs[cur][1]
                names = [f for f, _ in fields]
                want = {step.name}
                if i + 1 < len(steps) and steps[i + 1].kind == "select":
                    want.add(steps[i + 1].name)
                starts = {}
                p = pos
                for name, sub in fields:
                    starts[name] = p
                    if want <= set(starts):
                        break
                    p = self.skip(sub, rows, p)
                node = fields[names.index(step.name)][1]
                pos = starts[step.name]
            else:
                kind, (sub, length) = node
                if step.kind == "index":
                    at: np.ndarray | int = step.index
                else:
                    key = step.value.encode("utf-8")
                    at = self._select_index(rows, starts[step.name], key)
                if kind == Nodetype.SEQUENCE:
                    length, pos = self._u32(rows, pos)
                    if len(length) and (length > self.room[rows]).any():
                        raise Bail("sequence length beyond the payload")
                    keep = length > at
                else:
                    keep = np.full(len(rows), True) if isinstance(at, np.ndarray) else None
                    if isinstance(at, np.ndarray):
                        keep &= at < length
                if isinstance(at, np.ndarray):
                    keep &= at >= 0
                if keep is not None and not keep.all():
                    rows, pos = rows[keep], pos[keep]
                    if isinstance(at, np.ndarray):
                        at = at[keep]
                pos = self.skip_elements(sub, at, rows, pos)
                node = sub
            if node[0] == Nodetype.NAME:
                cur = node[1]
            self._cache[steps[:i + 1]] = (rows, pos, cur, node, starts)
        return rows, pos, node[1][0]


def _as_float(values: np.ndarray, base_type: str) -> np.ndarray:
    if base_type == "bool":
        return (values != 0).astype(np.float64)
    with np.errstate(invalid="ignore"):  # a signalling NaN in a float32 field (damaged bytes) stays a NaN
        return values.astype(np.float64, copy=False)


def fast_columns(
    registry: TypeRegistry, msgtype: str, buf: np.ndarray, rows: Rows, plans: list[FieldPath], *, ros1: bool,
    has_header: bool, cache: dict[int, _Layout] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    """Columns of one batch of one topic without decoding messages; raises :class:`Bail` when it cannot.

    ``cache``: a dict kept from batch to batch of the topic, where the layouts of uniform batches are reused.
    """
    n = len(rows.starts)
    if n > 1 and (rows.lengths == rows.lengths[0]).all():
        got = _uniform_columns(registry, msgtype, buf, rows, plans, ros1=ros1, has_header=has_header, cache=cache)
        if got is not None:
            return got
    col = Columnar(buf, rows.starts, rows.lengths, ros1=ros1, defs=registry.defs)
    col.densify()
    every = np.arange(n, dtype=np.int64)
    # The definition must describe every payload exactly (as rosbags checks per message): a type that differs
    # from what was recorded (e.g. a standard type that changed between ROS distributions) is not read.
    end = col.skip((Nodetype.NAME, msgtype), every, np.zeros(n, dtype=np.int64))
    slack = col.room - end
    if n and ((slack < 0).any() or (slack != 0 if ros1 else slack > 3).any()):
        raise Bail("payload sizes do not match the definition")
    located = {text: col.locate(msgtype, steps, n) for text, steps in _wanted(plans, has_header)}
    raw: dict[str, tuple[np.ndarray, str]] = {}
    # Fields at a constant distance from each other (a quaternion, a stamp) are read with one gather each group.
    groups: list[list[str]] = []
    for text, (r, p, _leaf) in located.items():
        if len(r) != n:
            continue
        for g in groups:
            d = p[:1] - located[g[0]][1][:1]
            if len(d) and 0 <= d[0] <= 64:
                g.append(text)
                break
        else:
            groups.append([text])
    for g in groups if col.mat is None else ():
        got = col.gather_many([located[t][1] for t in g], [located[t][2] for t in g]) if len(g) > 1 else None
        if got is not None:
            raw.update({t: (v, located[t][2]) for t, v in zip(g, got, strict=True)})
    for text, (r, p, leaf) in located.items():
        if text not in raw:
            raw[text] = col.values(r, p, leaf, n)
    return _finish(raw, plans, has_header)


def _wanted(plans: list[FieldPath], has_header: bool) -> list[tuple[str, tuple[Step, ...]]]:
    wanted = [(fp.text, fp.steps) for fp in plans]
    if has_header:
        wanted += [("\0sec", _HEADER_STEPS["sec"]), ("\0nanosec", _HEADER_STEPS["nanosec"])]
    return wanted


def _finish(raw: dict[str, tuple[np.ndarray, str]], plans: list[FieldPath],
            has_header: bool) -> tuple[dict[str, np.ndarray], np.ndarray | None]:
    out = {fp.text: _as_float(*raw[fp.text]) for fp in plans}
    stamps = None
    if has_header:
        stamps = raw["\0sec"][0].astype(np.int64) * 1_000_000_000 + raw["\0nanosec"][0].astype(np.int64)
    return out, stamps


_WORDS = {1: np.dtype(np.uint8), 2: np.dtype(np.uint16), 4: np.dtype(np.uint32), 8: np.dtype(np.uint64)}
SPAN_GAP = 256  # byte ranges closer than this are read with one gather (a gather costs per row more than per byte)


@dataclass
class _Layout:
    """Where the wanted fields lie in messages of one width, worked out on one message: valid for every message
    whose bytes at ``checks`` equal ``seen`` (length prefixes, selection keys, the encapsulation)."""

    checks: list[tuple[int, int]]
    seen: list[bytes]
    fields: dict[str, tuple[int, str]]
    spans: list[list[int]]
    order: str


def _layout(registry: TypeRegistry, msgtype: str, first: np.ndarray, plans: list[FieldPath], *, ros1: bool,
            has_header: bool) -> _Layout:
    width = len(first)
    head = 0 if ros1 else 4
    one = Columnar(first, np.zeros(1, dtype=np.int64), np.array([width], dtype=np.int64), ros1=ros1,
                   defs=registry.defs)
    one.probe = []
    zero = np.zeros(1, dtype=np.int64)
    end = one.skip((Nodetype.NAME, msgtype), zero, zero.copy())
    slack = width - head - int(end[0])
    if slack < 0 or (slack != 0 if ros1 else slack > 3):
        raise Bail("payload sizes do not match the definition")
    located = {text: one.locate(msgtype, steps, 1) for text, steps in _wanted(plans, has_header)}
    checks = {(a + head, w) for a, w in one.probe if w > 0}  # a set: a length prefix is probed once per field
    if not ros1:
        checks.add((0, 2))  # CDR encapsulation: plain CDR in the first message's byte order
    fields: dict[str, tuple[int, str]] = {}
    for text, (r, p, leaf) in located.items():
        if len(r):
            fields[text] = (int(one._align(p, SIZES[leaf])[0]) + head, leaf)
    ranges = sorted([*checks, *((a, SIZES[leaf]) for a, leaf in fields.values())])
    spans: list[list[int]] = []
    for a, w in ranges:
        if spans and a <= spans[-1][1] + SPAN_GAP:
            spans[-1][1] = max(spans[-1][1], a + w)
        else:
            spans.append([a, a + w])
    if spans and spans[-1][1] > width:
        raise Bail("payload shorter than its definition")
    checks = sorted(checks)
    return _Layout(checks, [first[a:a + w].tobytes() for a, w in checks], fields, spans, one.order)


def _uniform_columns(
    registry: TypeRegistry, msgtype: str, buf: np.ndarray, rows: Rows, plans: list[FieldPath], *, ros1: bool,
    has_header: bool, cache: dict[int, _Layout] | None = None,
) -> tuple[dict[str, np.ndarray], np.ndarray | None] | None:
    """Columns when every message has the first one's layout: equal lengths and equal bytes in every length
    prefix (and in the key strings of selections), so that each field lies at one offset in all of them.

    The layout is worked out on the first message alone, recording the byte ranges it depended on; those ranges
    and the fields' own bytes are then read from every message (nearby ranges with one gather, never the whole
    payload), the recorded ranges compared with the first message's, and each field is one strided copy.
    None when the messages differ in those bytes (the general path then handles them). ``cache`` (width ->
    layout) lets the next batch of the topic reuse the layout when its first message agrees at those ranges.
    """
    n = len(rows.starts)
    width = int(rows.lengths[0])
    s0 = int(rows.starts[0])
    first = buf[s0:s0 + width]
    lay = cache.get(width) if cache is not None else None
    if lay is None or any(first[a:a + w].tobytes() != b for (a, w), b in zip(lay.checks, lay.seen, strict=True)):
        lay = _layout(registry, msgtype, first, plans, ros1=ros1, has_header=has_header)
        if cache is not None:
            cache[width] = lay
    checks, fields, spans = lay.checks, lay.fields, lay.spans
    got: list[tuple[int, np.ndarray]] = []
    for lo, hi in spans:
        got.append((lo, take_rows(buf, rows.starts + lo, hi - lo)))

    def part(a: int, w: int, dtype: np.dtype | str | None = None) -> np.ndarray:
        """Bytes [a, a + w) of every message: a (n, w) byte view, or with ``dtype`` (itemsize w) its values."""
        for lo, win in got:
            if lo <= a and a + w <= lo + win.shape[1]:
                return win[:, a - lo:a - lo + w] if dtype is None else field_view(win, a - lo, dtype)
        raise AssertionError("byte range outside the spans read")

    for a, w in checks:
        word = _WORDS.get(w)
        if word is not None:
            same = (part(a, w, word) == first[a:a + w].view(word)[0]).all()
        else:
            same = (part(a, w) == first[a:a + w]).all()
        if not same:
            return None
    raw: dict[str, tuple[np.ndarray, str]] = {}
    for text, _steps in _wanted(plans, has_header):
        if text not in fields:
            raw[text] = (np.full(n, np.nan), "float64")
            continue
        a, leaf = fields[text]
        size = SIZES[leaf]
        dtype = DTYPES[leaf] if size == 1 else lay.order + DTYPES[leaf]
        raw[text] = (part(a, size, dtype), leaf)
    return _finish(raw, plans, has_header)


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


class TopicDecoder:
    """Decodes one topic batch by batch, by the fast path where it can, and joins the pieces at the end."""

    def __init__(self, registry: TypeRegistry, info: TopicInfo, plans: list[FieldPath], *, ros1: bool,
                 allow_fast: bool = True) -> None:
        self.registry = registry
        self.info = info
        self.plans = plans
        self.ros1 = ros1
        self.allow_fast = allow_fast
        # The columns are allocated once, at the size the storage announces, and filled batch by batch, so that
        # peak memory stays near one copy of the extracted arrays (grown by doubling if the storage undercounts).
        self.out: dict[str, np.ndarray] = {}
        self.paths: set[str] = set()
        self.read = 0
        self._layouts: dict[int, _Layout] = {}  # message width -> fast-path layout, reused batch after batch

    def _put(self, name: str, values: np.ndarray, dtype: type) -> None:
        col = self.out.get(name)
        end = self.read + len(values)
        if col is None or end > len(col):
            grown = np.empty(max(end, self.info.count, 2 * len(col) if col is not None else 0), dtype=dtype)
            if col is not None:
                grown[:self.read] = col[:self.read]
            self.out[name] = col = grown
        col[self.read:end] = values

    def feed(self, buf: np.ndarray, rows: Rows) -> None:
        """Decode one batch (raises what rosbags raises on a payload the definition does not describe)."""
        n = len(rows.starts)
        if not n:
            return
        info = self.info
        try:
            if not self.allow_fast:
                raise Bail("fast path disabled")
            columns, stamps = fast_columns(self.registry, info.msgtype, buf, rows, self.plans, ros1=self.ros1,
                                           has_header=info.has_header, cache=self._layouts)
            self.paths.add("fast")
        except Bail as why:
            if "fast" in self.paths or not self.paths:
                log.debug("topic %s: per-message decoding of %d messages (%s)", info.topic, n, why)
            payloads = [buf[s:s + ln].tobytes() for s, ln in zip(rows.starts.tolist(), rows.lengths.tolist(),
                                                                  strict=True)]
            columns, stamps = slow_columns(self.registry, info.msgtype, payloads, self.plans, ros1=self.ros1,
                                           has_header=info.has_header)
            self.paths.add("per-message")
        for name, values in columns.items():
            self._put(name, values, np.float64)
        if stamps is not None:
            self._put("\0header_ns", stamps, np.int64)
        self._put("\0log_ns", rows.log_ns, np.int64)
        self.read += n

    def result(self, expected: int) -> TopicData:
        out, self.out = self.out, {}

        def take(name: str, dtype: type) -> np.ndarray:
            col = out.pop(name, None)
            if col is None:
                return np.empty(0, dtype=dtype)
            return col if len(col) == self.read else col[:self.read].copy()

        columns = {fp.text: take(fp.text, np.float64) for fp in self.plans}
        stamps = take("\0header_ns", np.int64) if self.info.has_header else None
        log_ns = take("\0log_ns", np.int64)
        path = "fast" if self.paths <= {"fast"} and self.paths else \
            "per-message" if self.paths <= {"per-message"} else "mixed"
        if not self.paths:
            path = "fast" if self.allow_fast else "per-message"
        return TopicData(topic=self.info.topic, msgtype=self.info.msgtype, log_ns=log_ns, header_ns=stamps,
                         columns=columns, path=path, read=self.read, expected=expected)
