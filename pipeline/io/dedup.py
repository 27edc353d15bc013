"""Records written twice: a chunk anywhere in a file, a message among the recent ones of its channel.

A damaged or carelessly concatenated log can hold the same record twice (a chunk copied by a resumed upload, a
message record repeated by a retrying writer); read naively, every message in it counts twice and nothing says
so. The record walks of MCAP files and ROS 1 bags ask :class:`Seen` about each chunk and message record: a chunk
whose bytes equal an earlier chunk's, or a message record equal (channel, times, sequence, payload) to one of the
last :data:`WINDOW` messages of its channel, is dropped, counted and reported with the salvage report
(:class:`pipeline.io.base.SalvageInfo`, ``duplicates``).

Keys hold a CRC-32 of the bytes with their length and the record's own header fields, so memory stays at a
few dozen bytes per chunk and per recent message however long the file.
"""

from __future__ import annotations

import zlib
from collections import deque
from collections.abc import Hashable

WINDOW = 64  # recent messages per channel compared with each new one


def crc(data: bytes | memoryview) -> int:
    return zlib.crc32(data)


class Seen:
    """Chunks and recent messages of one walk over one file."""

    def __init__(self, window: int = WINDOW) -> None:
        self.window = window
        self.count = 0                     # records dropped as duplicates
        self.first_at: int | None = None   # file offset of the first of them
        self._chunks: set[Hashable] = set()
        self._recent: dict[int, tuple[deque[Hashable], set[Hashable]]] = {}

    def chunk(self, key: Hashable, at: int) -> bool:
        """True when a chunk with this key was seen before in the walk (it is then counted as a duplicate)."""
        if key in self._chunks:
            self._dropped(at)
            return True
        self._chunks.add(key)
        return False

    def message(self, channel: int, key: Hashable, at: int) -> bool:
        """True when this message record equals one of the last ``window`` of its channel (counted)."""
        order, keys = self._recent.setdefault(channel, (deque(), set()))
        if key in keys:
            self._dropped(at)
            return True
        order.append(key)
        keys.add(key)
        if len(order) > self.window:
            keys.discard(order.popleft())
        return False

    def _dropped(self, at: int) -> None:
        self.count += 1
        if self.first_at is None or 0 <= at < self.first_at:
            self.first_at = at

    def describe(self) -> str:
        """The report's words for what was dropped ('' when nothing was)."""
        if not self.count:
            return ""
        where = f", the first at byte {self.first_at}" if self.first_at is not None and self.first_at >= 0 else ""
        return f"{self.count} duplicate record(s) dropped (the same chunk or message twice{where})"
