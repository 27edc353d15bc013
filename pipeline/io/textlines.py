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
from dataclasses import dataclass
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
    """Fields of each line after the first ``skip`` lines (0: blank); ``delimiter`` None: runs of whitespace.

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
    every = np.concatenate(counts) if counts else np.zeros(0, dtype=np.int64)
    return every[skip:]


def _counts(data: bytes, delimiter: str | None) -> np.ndarray:
    """Fields per line of ``data``, which ends with a line end."""
    buf = np.frombuffer(data, dtype=np.uint8)
    starts = np.concatenate(([0], np.flatnonzero(buf == 10)[:-1] + 1))  # each line with its own line end
    space = _SPACE[buf]
    if delimiter is None:
        token = ~space
        token[1:] &= space[:-1]  # a field starts where a non-space follows a space (or the line end)
        return np.add.reduceat(token, starts, dtype=np.int64)
    delim = buf == ord(delimiter)
    content = np.add.reduceat(~space | delim, starts, dtype=np.int64)
    return np.where(content > 0, np.add.reduceat(delim, starts, dtype=np.int64) + 1, 0)


def plan_lines(fields: np.ndarray, header_fields: int) -> LinePlan:
    """Slots and kinds of the data lines from their field counts (0: blank).

    The count a whole line has is the header's (or `columns`'), unless most lines agree on another one (data
    lines with one trailing delimiter more than the header, say).
    """
    fields = np.asarray(fields, dtype=np.int64)
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
