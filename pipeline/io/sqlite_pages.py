"""Rows of a cut or damaged sqlite3 file read from its pages, without sqlite's b-tree (salvage of a rosbag2 .db3).

sqlite reaches a row through the interior pages of its table's b-tree; in a file cut short (power loss, a copy
that stopped) some of those interior pages lie past the cut although the leaf pages they point to are intact,
and sqlite answers "database disk image is malformed" for the whole query. :class:`SqlitePages` reads the file
format itself (https://sqlite.org/fileformat2.html), the way sqlite's own recovery extension does: every page
whose type byte says "table b-tree leaf" is parsed, and each cell that lies wholly in the file (with its
overflow pages) gives its rowid and record. Which table a leaf belongs to is not written on it; the caller
recognizes its rows by their shape (:func:`decode_record`).

Every length and page number comes from the damaged file, so each is checked against the file before use: a
cell or record that overruns its page, an overflow chain that leaves the file or loops, a varint past the end,
are skipped (counted in :attr:`SqlitePages.bad_cells`), never allocated.
"""

from __future__ import annotations

import mmap
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from pipeline.errors import IngestError
from pipeline.io.errors import Malformed
from pipeline.io.sqlite_format import (
    HEADER_BYTES,
    INT_BYTES,
    LEAF_TABLE,
    MAGIC,
    MIN_USABLE,
    claimed_pages,
    count_valid,
    is_int,
    local_payload,
    max_local,
    page_size,
    usable_size,
    valid_page_size,
    varint,
)

_U16, _U32 = struct.Struct(">H"), struct.Struct(">I")


def cut_short(path: str | Path) -> str | None:
    """Why the sqlite file at ``path`` is shorter than it should be (not whole pages, or fewer pages than its
    header counts), or None. sqlite itself reads a partial last page as zeros and drops its rows unseen."""
    with open(path, "rb") as fh:
        head = fh.read(HEADER_BYTES)
        size = fh.seek(0, 2)
    if len(head) < HEADER_BYTES or head[:16] != MAGIC:
        return None
    psize = page_size(head)
    if not valid_page_size(psize):
        return None
    claimed = claimed_pages(head)
    valid = count_valid(head)  # the header's page count is kept up to date by this writer
    if valid and size >= claimed * psize:
        return None  # every page the header counts is there (bytes beyond them are another kind of damage)
    if size % psize:
        return f"the file ends {size % psize} bytes into page {size // psize + 1} (not whole pages)"
    if valid:
        return f"the file holds {size // psize} pages of the {claimed} its header counts"
    return None


class SqlitePages:
    """The pages of one sqlite3 file (memory-mapped; the caller closes it)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._fh = open(self.path, "rb")  # noqa: SIM115 - closed by close()
        try:
            self.size = self._fh.seek(0, 2)
            if self.size < 100:
                raise IngestError(f"sqlite file of {self.size} bytes has no header (100 bytes)", file=self.path)
            self.buf = mmap.mmap(self._fh.fileno(), 0, access=mmap.ACCESS_READ)
        except BaseException:
            self._fh.close()
            raise
        head = self.buf[:HEADER_BYTES]
        self.page_size = page_size(head)
        if head[:16] != MAGIC or not valid_page_size(self.page_size):
            self.close()
            raise IngestError("not an sqlite3 file (magic or page size wrong in its header)", file=self.path)
        self.usable = usable_size(head, self.page_size)
        if self.usable < MIN_USABLE:
            self.close()
            raise IngestError(f"sqlite header reserves {head[20]} bytes a page; impossible", file=self.path)
        (self.encoding,) = _U32.unpack_from(head, 56)
        self.claimed_pages = claimed_pages(head)
        self.pages = -(-self.size // self.page_size)  # the last may be partial
        self.bad_cells = 0

    def close(self) -> None:
        if getattr(self, "buf", None) is not None:
            self.buf.close()
            self.buf = None  # type: ignore[assignment]
        self._fh.close()

    def __enter__(self) -> SqlitePages:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def cut_at(self) -> int | None:
        """Where the file ends, when it ends inside a page or before the pages its header counts; else None."""
        whole = self.size // self.page_size
        return self.size if self.size % self.page_size or self.claimed_pages > whole else None

    def table_leaves(self) -> Iterator[int]:
        """Numbers of the pages (1-based) whose type byte says table b-tree leaf."""
        for pgno in range(1, self.pages + 1):
            at = (pgno - 1) * self.page_size + (HEADER_BYTES if pgno == 1 else 0)
            if at < self.size and self.buf[at] == LEAF_TABLE:
                yield pgno

    def leaf_cells(self, pgno: int) -> Iterator[tuple[int, bytes]]:
        """(rowid, record) of each cell of leaf page ``pgno`` that lies wholly in the file, in key order."""
        base = (pgno - 1) * self.page_size
        head = base + (HEADER_BYTES if pgno == 1 else 0)
        end = min(base + self.page_size, self.size)
        if head + 8 > end:
            return
        (ncells,) = _U16.unpack_from(self.buf, head + 3)
        for i in range(ncells):
            ptr = head + 8 + 2 * i
            if ptr + 2 > end:
                self.bad_cells += ncells - i
                return
            (off,) = _U16.unpack_from(self.buf, ptr)
            try:
                if off < 8 or base + off >= end:
                    raise Malformed("cell pointer outside its page")
                yield self._cell(base + off, end)
            except Malformed:
                self.bad_cells += 1

    def _cell(self, at: int, end: int) -> tuple[int, bytes]:
        size, p = varint(self.buf, at, end)
        rowid, p = varint(self.buf, p, end)
        if rowid >= 1 << 63:
            rowid -= 1 << 64
        u = self.usable
        if size <= max_local(u):
            if p + size > end:
                raise Malformed("cell runs past its page (or the file's end)")
            return rowid, bytes(self.buf[p:p + size])
        if size > (self.pages + 1) * u:
            raise Malformed(f"cell claims {size} bytes, more than the file holds")
        local = local_payload(size, u)
        if p + local + 4 > end:
            raise Malformed("cell runs past its page (or the file's end)")
        parts = [bytes(self.buf[p:p + local])]
        (nxt,) = _U32.unpack_from(self.buf, p + local)
        left, seen = size - local, set()
        while left > 0:
            if not 1 <= nxt <= self.pages or nxt in seen:
                raise Malformed(f"overflow page {nxt} outside the file or met twice")
            seen.add(nxt)
            start = (nxt - 1) * self.page_size
            take = min(left, u - 4)
            if start + 4 + take > self.size:
                raise Malformed("overflow page cut short")
            parts.append(bytes(self.buf[start + 4:start + 4 + take]))
            (nxt,) = _U32.unpack_from(self.buf, start)
            left -= take
        return rowid, b"".join(parts)


def decode_record(record: bytes) -> tuple[list[int], list[Any]]:
    """The serial types and values of an sqlite record: None, int, float, or bytes (blob or undecoded text)."""
    hsize, p = varint(record, 0, len(record))
    if hsize > len(record) or hsize < p:
        raise Malformed("record header overruns the record")
    types = []
    while p < hsize:
        t, p = varint(record, p, hsize)
        types.append(t)
    out: list[Any] = []
    q = hsize
    for t in types:
        if t == 0:
            out.append(None)
            continue
        if 1 <= t <= 6:
            n = INT_BYTES[t]
            if q + n > len(record):
                raise Malformed("record value overruns the record")
            out.append(int.from_bytes(record[q:q + n], "big", signed=True))
        elif t == 7:
            if q + 8 > len(record):
                raise Malformed("record value overruns the record")
            out.append(struct.unpack_from(">d", record, q)[0])
            n = 8
        elif t in (8, 9):
            out.append(t - 8)
            n = 0
        elif t >= 12:
            n = (t - 12) // 2
            if q + n > len(record):
                raise Malformed("record value overruns the record")
            out.append(record[q:q + n])
        else:
            raise Malformed(f"reserved serial type {t}")
        q += n
    return types, out


@dataclass
class MessageRows:
    """The rows of a rosbag2 ``messages`` table found on the pages, in rowid order (one entry a row)."""

    pgno: np.ndarray
    rowid: np.ndarray
    topic_id: np.ndarray
    log_ns: np.ndarray
    bad_cells: int
    cut_at: int | None


def message_rows(pages: SqlitePages, topic_ids: set[int]) -> MessageRows:
    """Every row shaped like a rosbag2 message (NULL rowid alias, integer topic_id of a known topic, integer
    timestamp, blob data) on the table leaf pages; a rowid met twice (a stale copy) is taken once."""
    cols: tuple[list[int], ...] = ([], [], [], [])
    for pgno in pages.table_leaves():
        for rowid, record in pages.leaf_cells(pgno):
            try:
                types, values = decode_record(record)
            except Malformed:
                pages.bad_cells += 1
                continue
            if len(types) != 4 or types[0] != 0 or not (is_int(types[1]) and is_int(types[2])) \
                    or types[3] < 12 or types[3] % 2 or values[1] not in topic_ids:
                continue
            for col, value in zip(cols, (pgno, rowid, values[1], values[2]), strict=True):
                col.append(value)
    pg, rowid, tid, stamp = (np.asarray(c, dtype=np.int64) for c in cols)
    order = np.argsort(rowid, kind="stable")
    first = np.ones(len(order), dtype=bool)
    first[1:] = np.diff(rowid[order]) != 0
    keep = order[first]
    return MessageRows(pg[keep], rowid[keep], tid[keep], stamp[keep], pages.bad_cells, pages.cut_at)


def message_payloads(pages: SqlitePages, rows: MessageRows, wanted: set[int]) -> Iterator[tuple[int, int, bytes]]:
    """(topic id, timestamp, data) of the rows of ``wanted`` topics, in rowid order."""
    cache: tuple[int, dict[int, bytes]] = (-1, {})
    for pgno, rowid, tid, stamp in zip(rows.pgno.tolist(), rows.rowid.tolist(), rows.topic_id.tolist(),
                                       rows.log_ns.tolist(), strict=True):
        if tid not in wanted:
            continue
        if cache[0] != pgno:
            cache = (pgno, dict(pages.leaf_cells(pgno)))
        _, values = decode_record(cache[1][rowid])
        yield tid, stamp, values[3]
