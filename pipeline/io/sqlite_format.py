"""sqlite3's file format (https://sqlite.org/fileformat2.html) as both page walkers read it: the vectorized walker
of an intact table (:mod:`.sqlite_btree`) and the salvage walker of a damaged file (:mod:`.sqlite_pages`).

The database header's fields, the page types, the varint, the serial types of record values, and how much of an
overflowing cell's payload stays on its page. Each walker checks the values against the file in its own way
(the intact walker hands the rest to sqlite, the salvage walker skips the cell), so these only read and compute.
"""

from __future__ import annotations

import mmap

from pipeline.io.errors import Malformed

MAGIC = b"SQLite format 3\x00"
HEADER_BYTES = 100  # the database header, at the start of page 1
INTERIOR_TABLE, LEAF_TABLE = 0x05, 0x0D  # b-tree page types (the first byte of a page's header)
MIN_USABLE = 480  # the least a page may keep for content after the bytes reserved at its end

#: Serial type (0 to 9) -> bytes of its value when it is an integer (1-6; 8 and 9 are the constants 0 and 1).
INT_BYTES = (0, 1, 2, 3, 4, 6, 8, 0, 0, 0)


def is_int(serial: int) -> bool:
    """Whether serial type ``serial`` holds an integer (1 to 6 bytes of it, or the constants 0 and 1)."""
    return 1 <= serial <= 6 or serial in (8, 9)


def page_size(head: bytes) -> int:
    """The page size the database header states (its value 1 means 65536)."""
    size = int.from_bytes(head[16:18], "big")
    return 65536 if size == 1 else size


def valid_page_size(size: int) -> bool:
    """A power of two from 512 to 65536, as sqlite writes them."""
    return size >= 512 and not size & (size - 1)


def usable_size(head: bytes, size: int) -> int:
    """The bytes of each page of ``size`` that hold content: the page less the bytes reserved at its end."""
    return size - head[20]


def claimed_pages(head: bytes) -> int:
    """The file's size in pages as the header counts it (valid when :func:`count_valid`)."""
    return int.from_bytes(head[28:32], "big")


def count_valid(head: bytes) -> bool:
    """Whether the header's page count is current: the writer that kept it also wrote the matching version."""
    return head[24:28] == head[92:96]


def max_local(usable: int) -> int:
    """The largest payload of a table leaf cell that lies wholly on its page (pages of ``usable`` bytes)."""
    return usable - 35


def local_payload(size: int, usable: int) -> int:
    """Bytes of a table leaf cell's payload of ``size`` bytes that lie on its page when the payload overflows
    (``size`` > :func:`max_local`); the rest follows on the overflow pages, ``usable`` - 4 bytes each."""
    m = (usable - 12) * 32 // 255 - 23
    k = m + (size - m) % (usable - 4)
    return k if k <= usable - 35 else m


def varint(buf: bytes | mmap.mmap, pos: int, end: int) -> tuple[int, int]:
    """sqlite's big-endian varint at ``pos`` (1 to 9 bytes): (value, position after it)."""
    value = 0
    for i in range(9):
        if pos + i >= end:
            raise Malformed("varint runs past its page")
        byte = buf[pos + i]
        if i == 8:
            return (value << 8) | byte, pos + 9
        value = (value << 7) | (byte & 0x7F)
        if byte < 0x80:
            return value, pos + i + 1
    raise AssertionError("unreachable")
