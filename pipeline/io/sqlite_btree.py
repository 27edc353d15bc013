"""The rows of an intact rosbag2 ``messages`` table read from its b-tree pages, many at a time, with numpy.

sqlite hands rows over one at a time, and even its aggregates (one ``group_concat`` row per batch) cost more CPU
than rosbags' raw iteration (docs/benchmarks.md, "sqlite3 fetches"). The table's pages hold the same bytes
in a simple format (https://sqlite.org/fileformat2.html): here the b-tree is walked from the table's root page
(found in ``sqlite_master`` by sqlite itself) level by level to list the leaf pages in key (``id``) order; then
~16 MB of leaves at a time are read with one positioned read into a reused buffer, and every cell of them is
parsed at once as numpy arrays: the cell's payload size and rowid (varints), the record's header (four serial
types) and its values (``topic_id`` and ``timestamp``: big-endian integers of 0 to 8 bytes; ``data``: a blob,
whose bytes stay where they lie in the buffer). A payload too large for its page is joined from its overflow
pages and appended to the batch's buffer.

Only what this module fully understands is taken: a page that is not a table b-tree page, a record that is not
(NULL id, integer, integer, blob), sizes that do not add up, rowids that do not increase, an overflow chain that
leaves the file or loops, a file cut short, all raise :class:`NotPlain`. The caller then reads the rest of the
file (the rows after the last one handed on) through sqlite, whose own checks, errors and the salvage path apply
as before. The values are the bytes sqlite would return: the reader's tests compare both fetches bit for bit.
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pipeline.io.base import scratch_buffer
from pipeline.io.errors import NotPlain
from pipeline.io.sqlite_format import (
    HEADER_BYTES,
    INT_BYTES,
    INTERIOR_TABLE,
    LEAF_TABLE,
    MAGIC,
    MIN_USABLE,
    is_int,
    local_payload,
    max_local,
    page_size,
    usable_size,
    valid_page_size,
)

MAX_DEPTH = 32
#: Bytes gathered from the start of every cell: payload size, rowid, the record's header, topic_id and timestamp
#: of a rosbag2 row fit in them (at most 3 + 4 + 4 + 3 + 8 + 8).
PREFIX = 32

#: Serial type -> bytes of an integer value, and whether it is an integer (:data:`.sqlite_format.INT_BYTES`).
_INT_BYTES = np.array(INT_BYTES, dtype=np.int64)
_IS_INT = np.array([is_int(t) for t in range(len(INT_BYTES))])


@dataclass(frozen=True)
class Layout:
    page_size: int
    usable: int   # page size less the bytes the header reserves at each page's end
    pages: int    # whole pages in the file

    @classmethod
    def of(cls, fd: int) -> Layout:
        head = os.pread(fd, HEADER_BYTES, 0)
        if len(head) < HEADER_BYTES or head[:16] != MAGIC:
            raise NotPlain("no sqlite header")
        size = page_size(head)
        if not valid_page_size(size):
            raise NotPlain(f"page size {size}")
        usable = usable_size(head, size)
        if usable < MIN_USABLE:
            raise NotPlain(f"{head[20]} reserved bytes a page")
        return cls(size, usable, os.fstat(fd).st_size // size)


@dataclass
class RowBatch:
    """Rows in ``id`` order: topic ids, timestamps, and where each payload lies in ``buf``."""

    topic_id: np.ndarray
    log_ns: np.ndarray
    buf: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray
    first_id: int
    last_id: int


def leaf_pages(fd: int, layout: Layout, root: int) -> np.ndarray:
    """The leaf pages of the table b-tree rooted at ``root``, in key order (every leaf is at the same depth:
    the tree is walked a level at a time, reading interior pages only)."""
    level = np.array([root], dtype=np.int64)
    seen = 0
    for _ in range(MAX_DEPTH):
        ordered = np.sort(level)  # (not np.unique: in numpy 2 its first call imports numpy.ma)
        if ordered[0] < 1 or ordered[-1] > layout.pages or (ordered[1:] == ordered[:-1]).any():
            raise NotPlain("a child page outside the file, or met twice")
        seen += len(level)
        if seen > layout.pages:
            raise NotPlain("more b-tree pages than the file holds")
        children = []
        for pgno in level.tolist():
            page = os.pread(fd, layout.page_size, (pgno - 1) * layout.page_size)
            if len(page) != layout.page_size:
                raise NotPlain(f"page {pgno} cut short")
            at = HEADER_BYTES if pgno == 1 else 0
            if page[at] == LEAF_TABLE and not children:  # the leaf level (each leaf's type is checked as it is read)
                return level
            if page[at] != INTERIOR_TABLE:
                raise NotPlain(f"page {pgno} of type {page[at]} among the interior pages of the b-tree")
            children.append(_children(page, at, layout))
        level = np.concatenate(children)
    raise NotPlain(f"b-tree deeper than {MAX_DEPTH} levels")


def _children(page: bytes, at: int, layout: Layout) -> np.ndarray:
    """Child page numbers of an interior table page: each cell's left child, then the right-most pointer."""
    n = int.from_bytes(page[at + 3:at + 5], "big")
    if at + 12 + 2 * n > layout.usable:
        raise NotPlain("cell pointers overrun an interior page")
    arr = np.frombuffer(page, dtype=np.uint8)
    ptr = np.frombuffer(page, dtype=">u2", count=n, offset=at + 12).astype(np.int64)
    if n and (ptr.min() < at + 12 + 2 * n or ptr.max() + 4 > layout.usable):
        raise NotPlain("a cell outside its interior page")
    left = _be(arr, ptr, np.full(n, 4, dtype=np.int64))
    return np.append(left, int.from_bytes(page[at + 8:at + 12], "big")).astype(np.int64)


def row_batches(path: str | Path, root: int, limit: int = 16 << 20) -> Iterator[RowBatch]:
    """The rows of the table rooted at page ``root`` of the file at ``path``, ~``limit`` bytes of leaf pages at a
    time, in key order. The batch's buffer is reused by the next batch: take what is needed before asking for it.
    """
    fd = os.open(path, os.O_RDONLY)
    try:
        layout = Layout.of(fd)
        leaves = leaf_pages(fd, layout, root)
        per = max(1, limit // layout.page_size)
        scratch = [np.empty(0, dtype=np.uint8)]
        last = None
        for g in range(0, len(leaves), per):
            group = leaves[g:g + per]
            buf, page_at = _read_pages(fd, layout, group, scratch)
            batch = _parse(fd, layout, buf, page_at)
            if len(batch.starts):
                if last is not None and batch.first_id <= last:
                    raise NotPlain("rowids out of order across leaves")
                last = batch.last_id
                yield batch
    finally:
        os.close(fd)


def _read_pages(fd: int, layout: Layout, group: np.ndarray, scratch: list[np.ndarray]) -> tuple[np.ndarray, ...]:
    """The pages of ``group`` in one buffer, and where each starts in it: one read of the span they lie in when
    that span is mostly theirs (a bag written in order), else one read a page. :data:`PREFIX` bytes of slack
    follow the pages, so that the first bytes of any cell can be gathered without a bounds check."""
    ps = layout.page_size
    lo, hi = int(group.min()), int(group.max())
    span = hi - lo + 1
    if span <= 2 * len(group) + 16:
        buf = scratch_buffer(scratch, span * ps + PREFIX, phase=(lo - 1) * ps)
        if os.preadv(fd, [buf[:span * ps]], (lo - 1) * ps) != span * ps:
            raise NotPlain("leaf pages cut short")
        return buf, (group - lo) * ps
    buf = scratch_buffer(scratch, len(group) * ps + PREFIX)
    for k, pgno in enumerate(group.tolist()):
        if os.preadv(fd, [buf[k * ps:(k + 1) * ps]], (pgno - 1) * ps) != ps:
            raise NotPlain("a leaf page cut short")
    return buf, np.arange(len(group), dtype=np.int64) * ps


def _varints(buf: np.ndarray, pos: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The sqlite varints (1 to 9 bytes, big-endian, 7 bits a byte, all 8 in the ninth) at ``pos``, each to end
    before ``end``: (values as uint64, the positions after them). While every varint goes on, whole arrays are
    used; from the first byte where some end, only the rest are indexed."""
    if (pos >= end).any():
        raise NotPlain("a varint runs past its page or record")
    if len(pos) and len(buf) >= 4 and pos.max() + 4 <= len(buf):
        short = _short_varints(buf, pos, end)
        if short is not None:
            return short
    b = buf[pos]
    value = (b & 0x7F).astype(np.uint64)
    if not (b & 0x80).any():
        return value, pos + 1
    after = pos.copy()
    more = None  # all of them
    for i in range(1, 9):
        if more is None and (b & 0x80).all():
            p = pos + i
            if (p >= end).any():
                raise NotPlain("a varint runs past its page or record")
            b = buf[p]
            if i == 8:
                return (value << np.uint64(8)) | b, p + 1
            value = (value << np.uint64(7)) | (b & 0x7F)
            continue
        if more is None:  # the varints that end at byte i - 1
            done = (b & 0x80) == 0
            after[done] = pos[done] + i
            more = np.flatnonzero(~done)
        if not len(more):
            return value, after
        p = pos[more] + i
        if (p >= end[more]).any():
            raise NotPlain("a varint runs past its page or record")
        b = buf[p]
        if i == 8:
            value[more] = (value[more] << np.uint64(8)) | b
            after[more] = p + 1
            return value, after
        value[more] = (value[more] << np.uint64(7)) | (b & 0x7F)
        done = b < 0x80
        after[more[done]] = p[done] + 1
        more = more[~done]
    if more is None:  # every varint ended at byte 8 (the loop returned) or before
        raise AssertionError("unreachable")
    return value, after


def _short_varints(buf: np.ndarray, pos: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """:func:`_varints` when every one is 1 to 4 bytes long (sizes, rowids and types of a bag below 2**28 rows
    and payloads): one gather of 4 bytes each, then whole-array arithmetic; None if some are longer."""
    word = np.ndarray(shape=(len(buf) - 3,), dtype=">u4", buffer=buf, strides=(1,))[pos].astype(np.uint64)
    b = [(word >> np.uint64(shift)) & np.uint64(0xFF) for shift in (24, 16, 8, 0)]
    ends = [x < 0x80 for x in b]
    if not (ends[0] | ends[1] | ends[2] | ends[3]).all():
        return None
    value = b[0] & np.uint64(0x7F)
    length = np.ones(len(pos), dtype=np.int64)
    going = ~ends[0]
    for j in (1, 2, 3):
        if not going.any():
            break
        value = np.where(going, (value << np.uint64(7)) | (b[j] & np.uint64(0x7F)), value)
        length += going
        going &= ~ends[j]
    after = pos + length
    if (after > end).any():
        raise NotPlain("a varint runs past its page or record")
    return value, after


def _be(buf: np.ndarray, at: np.ndarray, nbytes: np.ndarray) -> np.ndarray:
    """The unsigned big-endian integers of ``nbytes`` (0 to 8) bytes at ``at``."""
    if not len(at):
        return np.zeros(0, dtype=np.uint64)
    most = int(nbytes.max())
    if most == nbytes.min() and most in (1, 2, 4, 8) and len(buf) >= most:  # one gather of a big-endian view
        items = np.ndarray(shape=(len(buf) - most + 1,), dtype=f">u{most}", buffer=buf, strides=(1,))
        return items[at].astype(np.uint64)
    value = np.zeros(len(at), dtype=np.uint64)
    for j in range(most):
        m = nbytes > j
        value[m] = (value[m] << np.uint64(8)) | buf[at[m] + j]
    return value


def _ints(buf: np.ndarray, at: np.ndarray, serial: np.ndarray) -> np.ndarray:
    """The signed integers of serial types ``serial`` (1-6, 8, 9) at ``at``, as int64."""
    if len(at) and serial.min() == serial.max():  # one type for the batch (the usual case): one gather
        kind = int(serial[0])
        if kind in (8, 9):
            return np.full(len(at), kind - 8, dtype=np.int64)
        n = int(_INT_BYTES[kind])
        if n in (1, 2, 4, 8) and len(buf) >= n:
            items = np.ndarray(shape=(len(buf) - n + 1,), dtype=f">i{n}", buffer=buf, strides=(1,))
            return items[at].astype(np.int64)
    nbytes = _INT_BYTES[serial]
    raw = _be(buf, at, nbytes)
    shift = (64 - 8 * nbytes).astype(np.uint64) % np.uint64(64)  # 0 bytes: shift 0, value 0
    value = ((raw << shift).view(np.int64)) >> shift.astype(np.int64)
    return np.where(serial == 9, 1, value)


def _parse(fd: int, layout: Layout, buf: np.ndarray, page_at: np.ndarray) -> RowBatch:
    """Every cell of the leaf pages starting at ``page_at`` in ``buf``."""
    usable = layout.usable
    if (buf[page_at] != LEAF_TABLE).any():
        raise NotPlain("a page of the table's leaf level is not a table leaf")
    ncells = (buf[page_at + 3].astype(np.int64) << 8) | buf[page_at + 4]
    if (8 + 2 * ncells > usable).any():
        raise NotPlain("cell pointers overrun a leaf page")
    total = int(ncells.sum())
    page = np.repeat(page_at, ncells)
    k = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(ncells) - ncells, ncells)
    ptr_at = page + 8 + 2 * k
    ptr = (buf[ptr_at].astype(np.int64) << 8) | buf[ptr_at + 1]
    if not total:
        empty = np.empty(0, dtype=np.int64)
        return RowBatch(empty, empty, buf, empty, empty, 0, 0)
    if ((ptr < 8 + 2 * np.repeat(ncells, ncells)) | (ptr >= usable)).any():
        raise NotPlain("a cell outside its leaf page")
    end = page + usable
    fast = _parse_prefixes(buf, page + ptr, end, usable)
    if fast is not None:
        return fast
    size, p = _varints(buf, page + ptr, end)
    rowid, p = _varints(buf, p, end)
    rowid = rowid.view(np.int64)
    if size.max() > layout.pages * usable:
        raise NotPlain("a payload larger than the file")
    size = size.astype(np.int64)
    if (rowid[1:] <= rowid[:-1]).any():  # (not np.diff: it overflows between the extremes)
        raise NotPlain("rowids out of order on the leaf pages")
    over = size > max_local(usable)
    if over.any():
        buf, p, end = _overflowed(fd, layout, buf, p, end, size, over)
    elif (p + size > end).any():
        raise NotPlain("a cell runs past its page")
    rec_end = p + size
    hsize, t0, t1, t2, t3, q = _record_header(buf, p, rec_end)
    if (q != p + hsize).any():
        raise NotPlain("a record that does not hold four columns")
    if (t0.max() != 0 or t1.max() > 9 or t2.max() > 9 or not _IS_INT[t1].all() or not _IS_INT[t2].all()
            or t3.min() < 12 or (t3 & np.uint64(1)).any()):
        raise NotPlain("a row that is not (NULL id, integer topic_id, integer timestamp, blob data)")
    t1, t2 = t1.astype(np.int64), t2.astype(np.int64)
    n1, n2 = _INT_BYTES[t1], _INT_BYTES[t2]
    length = ((t3 - np.uint64(12)) >> np.uint64(1)).astype(np.int64)
    body = p + hsize
    if (hsize + n1 + n2 + length != size).any():
        raise NotPlain("a record's values do not add up to its size")
    tid = _ints(buf, body, t1)
    stamp = _ints(buf, body + n1, t2)
    return RowBatch(tid, stamp, buf, body + n1 + n2, length, int(rowid[0]), int(rowid[-1]))


def _word_varints(flat: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Varints of 1 to 4 bytes at ``pos`` of ``flat`` (4 bytes readable at each): (values, lengths), or None
    when some are longer. One gather of a (little-endian) word each; the length from its continuation bits; the
    value from the 7-bit groups packed together, big end first, and shifted by the bytes not used."""
    w = np.ndarray(shape=(len(flat) - 3,), dtype="<u4", buffer=flat, strides=(1,))[pos]
    c0 = (w >> 7) & 1
    c1 = c0 & (w >> 15)
    c2 = c1 & (w >> 23)
    if (c2 & (w >> 31)).any():
        return None
    length = 1 + c0 + c1 + (c2 & 1)
    packed = ((w & 0x7F) << 21) | ((w & 0x7F00) << 6) | ((w & 0x7F0000) >> 9) | ((w & 0x7F000000) >> 24)
    return (packed >> (7 * (4 - length))).astype(np.int64), length.astype(np.int64)


def _parse_prefixes(buf: np.ndarray, cell: np.ndarray, end: np.ndarray, usable: int) -> RowBatch | None:
    """:func:`_parse` for the usual rows, from the first :data:`PREFIX` bytes of each cell gathered into one small
    array (one scattered read of the page buffer; every later gather stays in cache): payload size below 2**21,
    rowid from 1 to 2**28, a record header of one-byte types, no overflow. None when some row is not like that
    (the caller parses the batch the general way), NotPlain when a row's sizes do not add up."""
    n = len(cell)
    items = np.ndarray(shape=(len(buf) - PREFIX + 1,), dtype=np.dtype((np.void, PREFIX)), buffer=buf, strides=(1,))
    flat = items[cell].view(np.uint8).reshape(-1)
    base = np.arange(n, dtype=np.int64) * PREFIX
    got = _word_varints(flat, base)
    if got is None:
        return None
    size, n_size = got
    got = _word_varints(flat, base + n_size)
    if got is None:
        return None
    rowid, n_rowid = got
    at = n_size + n_rowid  # the record, from the cell's start
    head = np.ndarray(shape=(len(flat) - 3,), dtype=">u4", buffer=flat, strides=(1,))[base + at].astype(np.int64)
    if (head & 0x80808080).any() or (n_size > 3).any() or (size > max_local(usable)).any():
        return None
    got = _word_varints(flat, base + at + 4)
    if got is None:
        return None
    t3, n_t3 = got
    hsize, t0, t1, t2 = ((head >> shift) & 0xFF for shift in (24, 16, 8, 0))
    if (hsize != 4 + n_t3).any() or t0.max() != 0 or t1.max() > 9 or t2.max() > 9 or not _IS_INT[t1].all() \
            or not _IS_INT[t2].all() or t3.min() < 12 or (t3 & 1).any():
        return None
    n1, n2 = _INT_BYTES[t1], _INT_BYTES[t2]
    if (at + hsize + n1 + n2 > PREFIX).any():
        return None
    length = (t3 - 12) >> 1
    if (hsize + n1 + n2 + length != size).any() or (cell + at + size > end).any():
        raise NotPlain("a record's values do not add up to its size, or it runs past its page")
    if (rowid[1:] <= rowid[:-1]).any():
        raise NotPlain("rowids out of order on the leaf pages")
    body = base + at + hsize
    tid = _ints(flat, body, t1)
    stamp = _ints(flat, body + n1, t2)
    return RowBatch(tid, stamp, buf, cell + at + hsize + n1 + n2, length, int(rowid[0]), int(rowid[-1]))


def _record_header(buf: np.ndarray, p: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, ...]:
    """The header size and four serial types of the records at ``p``, and where the fourth ends. rosbag2's rows
    start with four one-byte varints (header size, NULL id, topic_id's and timestamp's types): one gather of 4
    bytes each; a record that does not is not plain."""
    if len(buf) < 4 or (p + 5 > end).any():
        raise NotPlain("a record shorter than rosbag2's")
    head = np.ndarray(shape=(len(buf) - 3,), dtype=">u4", buffer=buf, strides=(1,))[p].astype(np.int64)
    if (head & 0x80808080).any():
        raise NotPlain("a record header of more than four columns' worth of one-byte types")
    t3, q = _varints(buf, p + 4, end)
    hsize, t0, t1, t2 = ((head >> shift) & 0xFF for shift in (24, 16, 8, 0))
    return hsize, t0, t1, t2, t3, q


def _overflowed(fd: int, layout: Layout, buf: np.ndarray, p: np.ndarray, end: np.ndarray, size: np.ndarray,
                over: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Join each overflowing payload (its local bytes, then its chain of overflow pages) after the batch's pages;
    the record positions and ends of those cells then point there."""
    u, ps = layout.usable, layout.page_size
    local_ok = ~over
    if (p[local_ok] + size[local_ok] > end[local_ok]).any():
        raise NotPlain("a cell runs past its page")
    parts, at = [], len(buf)
    p, end = p.copy(), end.copy()
    for i in np.flatnonzero(over).tolist():
        total = int(size[i])
        local = local_payload(total, u)
        start = int(p[i])
        if start + local + 4 > int(end[i]):
            raise NotPlain("an overflowing cell runs past its page")
        chunks = [buf[start:start + local].tobytes()]
        nxt = int.from_bytes(buf[start + local:start + local + 4].tobytes(), "big")
        left, seen = total - local, set()
        while left > 0:
            if not 1 <= nxt <= layout.pages or nxt in seen:
                raise NotPlain(f"overflow page {nxt} outside the file or met twice")
            seen.add(nxt)
            take = min(left, u - 4)
            page = os.pread(fd, 4 + take, (nxt - 1) * ps)
            if len(page) != 4 + take:
                raise NotPlain("an overflow page cut short")
            chunks.append(page[4:])
            nxt = int.from_bytes(page[:4], "big")
            left -= take
        p[i], end[i] = at, at + total
        parts.append(b"".join(chunks))
        at += total
    joined = np.concatenate([buf, np.frombuffer(b"".join(parts), dtype=np.uint8)])
    return joined, p, end
