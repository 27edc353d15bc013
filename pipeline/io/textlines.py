"""The data lines of a delimited text file by their field count: blank, ragged, split, and the sample slot of each.

A stream read with ``time: {rate_hz: R}`` gets its time from its row index, so every line the reader drops or
adds would move every later sample by one period. :func:`field_counts` counts the fields of each physical line
after the preamble and header (vectorized, a chunk of bytes at a time), and :func:`plan_lines` turns the counts
into slots:

- a blank line (nothing but spaces) is no sample and takes no slot (a stray line break);
- two adjacent lines with too few fields whose counts add up to one line's (``n`` or ``n + 1``: the break fell
  between two fields or inside one) are a **split** line: one sample, one slot, its values dropped (which field
  the break cut is unknown);
- any other line whose field count differs from the file's is **ragged**: it keeps its slot, its values dropped;
- every other line keeps its slot, whether the reader keeps its values or drops them (all-NaN, unparseable).

Field counts ignore quoting: a quoted delimiter or line break would be miscounted, so a file whose physical lines
do not match the parser's rows one to one is left unclassified by the caller.
"""

from __future__ import annotations

import codecs
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np

_CHUNK = 1 << 24
_SPACE = np.zeros(256, dtype=bool)
_SPACE[[ord(" "), ord("\t"), ord("\r"), ord("\n"), ord("\v"), ord("\f")]] = True
_PROBE = "\n,;\t 0a"


@dataclass(frozen=True)
class LinePlan:
    """Per data line (0-based among the lines after preamble and header): its slot and its kind."""

    slot: np.ndarray      # int64 sample index of each line; -1 for a blank line
    blank: np.ndarray     # bool
    ragged: np.ndarray    # bool: too few or too many fields, not part of a split line
    split: np.ndarray     # bool: either half of a line broken in two
    n_fields: int         # the field count a whole line has


def ascii_compatible(encoding: str) -> bool:
    """Whether the delimiters and line ends of text in ``encoding`` are their ASCII bytes (not UTF-16/32)."""
    try:
        return _PROBE.encode(encoding).endswith(_PROBE.encode("ascii"))
    except (LookupError, UnicodeError):
        return False


def field_counts(handle: BinaryIO, *, skip: int, delimiter: str | None, encoding: str) -> np.ndarray:
    """Fields of each line after the first ``skip`` lines (0: blank; int32, 4 bytes a line); ``delimiter`` None:
    runs of whitespace.

    ``delimiter`` must be one ASCII character. Text in an encoding that is not ASCII-compatible is decoded and
    counted in UTF-8.
    """
    source: BinaryIO | codecs.StreamReader = handle
    if not ascii_compatible(encoding):
        source = codecs.getreader(encoding)(handle)
    counts: list[np.ndarray] = []
    rest = b""
    while True:
        piece = source.read(_CHUNK)
        if isinstance(piece, str):
            piece = piece.encode("utf-8")
        if not piece:
            break
        data = rest + piece
        end = data.rfind(b"\n") + 1
        rest = data[end:]
        if end:
            counts.append(_counts(data[:end], delimiter))
    if rest:
        counts.append(_counts(rest + b"\n", delimiter))
    every = np.concatenate(counts) if counts else np.zeros(0, dtype=np.int32)
    return every[skip:]


def _counts(data: bytes, delimiter: str | None) -> np.ndarray:
    """Fields per line of ``data``, which ends with a line end."""
    buf = np.frombuffer(data, dtype=np.uint8)
    starts = np.concatenate(([0], np.flatnonzero(buf == 10)[:-1] + 1))  # each line with its own line end
    space = _SPACE[buf]
    if delimiter is None:
        token = ~space
        token[1:] &= space[:-1]  # a field starts where a non-space follows a space (or the line end)
        return np.add.reduceat(token, starts, dtype=np.int32)
    delim = buf == ord(delimiter)
    content = np.add.reduceat(~space | delim, starts, dtype=np.int32)
    return np.where(content > 0, np.add.reduceat(delim, starts, dtype=np.int32) + 1, 0).astype(np.int32)


def plan_lines(fields: np.ndarray, header_fields: int) -> LinePlan:
    """Slots and kinds of the data lines from their field counts (0: blank).

    The count a whole line has is the header's (or `columns`'), unless most lines agree on another one (data
    lines with one trailing delimiter more than the header, say).
    """
    fields = np.asarray(fields)  # int32 from field_counts (a file holds < 2**31 bytes: TEXT_MAX_BYTES)
    blank = fields == 0
    n = header_fields
    filled = fields[~blank]
    if filled.size and (filled == n).sum() * 2 < filled.size:
        values, freq = np.unique(filled, return_counts=True)
        if freq.max() * 2 > filled.size:
            n = int(values[freq.argmax()])
    short = ~blank & (fields < n)
    split = np.zeros(fields.size, dtype=bool)
    second_half = np.zeros(fields.size, dtype=bool)
    pair_sum = fields[:-1] + fields[1:]
    candidates = np.flatnonzero(short[:-1] & short[1:] & ((pair_sum == n) | (pair_sum == n + 1)))
    taken = -1
    for i in candidates.tolist():  # greedy, left to right: a line belongs to one pair at most
        if i > taken:
            split[i] = split[i + 1] = second_half[i + 1] = True
            taken = i + 1
    ragged = ~blank & ~split & (fields != n)
    takes_slot = ~blank & ~second_half
    slot = np.cumsum(takes_slot) - 1
    slot[blank] = -1
    return LinePlan(slot=slot.astype(np.int64), blank=blank, ragged=ragged, split=split, n_fields=n)


_BLOCK = 1 << 22
_HEAD = 1 << 16  # the first lines, by line (their flags kept); then counts only, a block of _BLOCK bytes at a time
_HEAD_BLOCK = 1 << 18
_BLANKS = b" \t\r\x0b\x0c"


@dataclass(frozen=True)
class LineScan:
    """One pass over a text file's bytes: its size, its lines, and the non-blank ones after the first ``skip``."""

    size: int          # bytes (inflated, for a .gz)
    lines: int         # physical lines (a last line without a line end counts)
    data_lines: int    # non-blank lines after the first ``skip``
    any_content: bool  # some byte that is not white space
    over: str | None   # which budget the file exceeds ("bytes" / "lines" / "line"); the scan stops there
    skip: int = 0
    head: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # first lines: non-blank?

    def data_after(self, skip: int) -> int | None:
        """Non-blank lines after the first ``skip`` (None: beyond what the scan kept of the head)."""
        if skip == self.skip:
            return self.data_lines
        if self.skip == 0 and (skip <= self.head.size or self.head.size == self.lines):
            return self.data_lines - int(np.count_nonzero(self.head[:skip]))
        return None


def _longest_inside(piece: bytes) -> int:
    """The longest line between two line ends of ``piece`` (bytes; the ends not counted)."""
    ends = np.flatnonzero(np.frombuffer(piece, dtype=np.uint8) == 10)
    return int((np.diff(ends) - 1).max()) if len(ends) > 1 else 0


def scan_lines(handle: BinaryIO, *, skip: int, max_bytes: int, max_lines: int,
               max_line_bytes: int = 16 << 20) -> LineScan:
    """Count lines a block of bytes at a time (numpy, no Python loop per line), stopping past a budget: bytes,
    lines, or one line's bytes (``max_line_bytes``: a longer line is found by the run of bytes without a line end
    across blocks, and, for a limit below a block, by the gaps between the line ends inside one).

    A line is blank when it holds nothing but ASCII white space (``bytes.strip()``'s set); line ends are ``\\n``
    bytes, as the reader's physical lines (quoted line breaks are not told apart). Memory: one block, a few
    bytes per byte of it.
    """
    size = lines = data = 0
    head: list[np.ndarray] = []
    pending = content_seen = open_line = False  # the current, unterminated line: has content, exists
    run = 0  # bytes since the last line end
    while piece := handle.read(_BLOCK if lines >= max(skip, _HEAD) else _HEAD_BLOCK):
        open_line = piece[-1:] != b"\n"
        size += len(piece)
        if size > max_bytes:
            return LineScan(size, lines, data, content_seen, "bytes", skip)
        first = piece.find(b"\n")
        run += len(piece) if first < 0 else first
        if run > max_line_bytes:
            return LineScan(size, lines, data, content_seen, "line", skip)
        if first >= 0:
            run = len(piece) - 1 - piece.rfind(b"\n")
            if max_line_bytes < len(piece) and _longest_inside(piece) > max_line_bytes:  # a limit below a block
                return LineScan(size, lines, data, content_seen, "line", skip)
        if lines >= max(skip, _HEAD):  # past the head: counts only
            squeezed = piece.translate(None, _BLANKS)  # white space but line ends removed
            ends_at = np.frombuffer(squeezed, dtype=np.uint8) == 10
            n_ends = int(np.count_nonzero(ends_at))
            if n_ends:
                blank = int(np.count_nonzero(ends_at[1:] & ends_at[:-1])) + int(bool(ends_at[0]) and not pending)
                data += n_ends - blank
                content_seen |= n_ends > blank
                lines += n_ends
                pending = not squeezed.endswith(b"\n")
            else:
                pending |= bool(squeezed)
            if lines > max_lines:
                return LineScan(size, lines, data, content_seen, "lines", skip)
            continue
        buf = np.frombuffer(piece, dtype=np.uint8)
        content = ~_SPACE[buf]
        ends = np.flatnonzero(buf == 10)
        if ends.size:
            starts = np.concatenate(([0], ends[:-1] + 1))
            has = np.logical_or.reduceat(content[:ends[-1] + 1], starts)  # each segment holds its line end
            has[0] |= pending
            if lines < _HEAD:
                head.append(has[:_HEAD - lines])
            data += int(np.count_nonzero(has[max(0, skip - lines):]))
            content_seen |= bool(has.any())
            lines += int(ends.size)
            pending = bool(content[ends[-1] + 1:].any())
        else:
            pending |= bool(content.any())
        if lines > max_lines:
            return LineScan(size, lines, data, content_seen, "lines", skip)
    if run > max_line_bytes:
        return LineScan(size, lines, data, content_seen, "line", skip)
    if open_line:
        if lines < _HEAD:
            head.append(np.array([pending]))
        lines += 1
        data += pending and lines > skip
        content_seen |= pending
    return LineScan(size, lines, data, content_seen, "lines" if lines > max_lines else None, skip,
                    np.concatenate(head) if head else np.zeros(0, dtype=bool))
