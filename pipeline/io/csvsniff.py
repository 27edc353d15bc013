"""Guess the parsing options of a delimited text file: encoding, preamble, header, delimiter, time column and unit.

:func:`sniff_csv` reads the first lines of a file and returns :class:`~pipeline.config.sources.CsvOptions` as a
vehicle config would state them, or None for the time column when no column looks like time. The guess is
for ``auvid inspect`` and ``auvid init``; ingest never guesses (the config states the options).

- encoding: UTF-8 if the head decodes, else cp1252 (a towing-tank export with a ``°`` in its preamble);
- delimiter: from the last lines of the head (the data), by :func:`pipeline.io.text.sniff_delimiter`;
- data: the first run of lines that are all numbers with the data's field count; the line just before it is
  the header when it has as many fields and is not all numbers; anything earlier is preamble (``skip_rows``);
  without a header the columns are named ``col1``, ``col2``, ...;
- time column: a column named like time (``t``, ``time``, ``timestamp``, ``stamp_ns``, ``t [s]``, ...), else
  the first column of a headerless file when its values increase; unit from its name (``_ns``, ``[ms]``, ...)
  or from the magnitude of its values (epoch seconds ~1.7e9, ms ~1.7e12, us ~1.7e15, ns ~1.7e18), else
  relative seconds.
"""

from __future__ import annotations

import gzip
import re
import zlib
from dataclasses import dataclass
from pathlib import Path

from pipeline.config.sources import CsvOptions
from pipeline.errors import IngestError
from pipeline.io.text import inflate_cut, is_gzip, sniff_delimiter

HEAD_BYTES = 64 * 1024
HEAD_LINES = 60
_RUN = 5  # consecutive numeric lines that make the start of the data
_TIME_NAME = re.compile(r"^(t|time|times|timestamp|stamp|sec|secs|seconds|zeit|tid)([\s_\-\[(].*)?$|.*(time|stamp).*",
                        re.IGNORECASE)
_UNIT_IN_NAME = (("ns", "ns"), ("nsec", "ns"), ("us", "us"), ("µs", "us"), ("usec", "us"), ("ms", "ms"),
                 ("msec", "ms"), ("s", "s"), ("sec", "s"))
_EPOCH_UNITS = ((1e17, "ns"), (1e14, "us"), (1e11, "ms"), (1e8, "s"))  # median value above: epoch in that unit


@dataclass(frozen=True)
class SniffedCsv:
    """What :func:`sniff_csv` found: the options (None if no time column was found) and what it saw."""

    options: CsvOptions | None
    columns: list[str]
    delimiter: str
    skip_rows: int
    header: bool
    encoding: str
    time_column: str | None
    note: str  # how the time column and unit were chosen, for humans


def _head(path: Path) -> tuple[list[str], str]:
    opener = gzip.open if is_gzip(path) else open
    try:
        with opener(path, "rb") as handle:  # type: ignore[operator]
            raw = handle.read(HEAD_BYTES)
    except EOFError:  # a .gz cut short before HEAD_BYTES: its complete lines, as the reader keeps them
        raw = inflate_cut(path)[0][:HEAD_BYTES]
    except (gzip.BadGzipFile, zlib.error) as err:  # a damaged .gz (file-system errors pass through)
        raise IngestError(f"gzip stream does not decompress: {err}", file=path) from err
    for encoding in ("utf-8", "cp1252"):
        try:
            text = raw.decode(encoding)
        except UnicodeDecodeError as err:
            if encoding == "utf-8" and err.start >= len(raw) - 4:  # a character cut at the end of the head
                text = raw[:err.start].decode(encoding)
            else:
                continue
        lines = text.splitlines()
        if len(raw) == HEAD_BYTES and lines:
            lines = lines[:-1]  # the last line may be cut
        return lines[:HEAD_LINES], encoding
    return raw.decode("latin-1").splitlines()[:HEAD_LINES], "latin-1"


def _split(line: str, delimiter: str) -> list[str]:
    if delimiter == " ":
        return line.split()
    return [f.strip() for f in line.split(delimiter)]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _numeric(fields: list[str]) -> bool:
    return bool(fields) and all(_is_number(f) for f in fields if f != "") and any(f != "" for f in fields)


def _unit_from_name(name: str) -> str | None:
    low = name.lower().strip()
    bracket = re.search(r"[\[(]\s*([a-zµ]+)\s*[\])]", low)
    if bracket:
        token = bracket.group(1)
    else:
        parts = re.split(r"[_\s.]", low)
        token = parts[-1] if len(parts) > 1 else ""
    return dict(_UNIT_IN_NAME).get(token)


def sniff_csv(path: str | Path) -> SniffedCsv:
    """The parsing options of one delimited text file (see the module docstring)."""
    path = Path(path)
    lines, encoding = _head(path)
    body = [ln for ln in lines if ln.strip()]
    tail = body[-min(len(body), 10):] if body else []
    sep = sniff_delimiter(tail) if tail else ","
    delimiter = " " if sep == r"\s+" else sep
    widths = [len(_split(ln, delimiter)) for ln in tail]
    width = max(set(widths), key=widths.count) if widths else 0
    numeric = [bool(ln.strip()) and len(_split(ln, delimiter)) == width and _numeric(_split(ln, delimiter))
               for ln in lines]
    start = next((i for i in range(len(lines)) if all(numeric[i:i + _RUN]) and numeric[i]), None)
    header = False
    columns: list[str] = []
    if start is None:  # no data lines in the head (a header only, or text): take the first line as header
        start = 1 if lines else 0
        header = bool(lines)
        columns = _split(lines[0], delimiter) if lines else []
    else:
        prev = start - 1
        while prev >= 0 and not lines[prev].strip():
            prev -= 1
        if prev >= 0 and len(_split(lines[prev], delimiter)) == width and not _numeric(_split(lines[prev], delimiter)):
            header = True
            columns = _split(lines[prev], delimiter)
            start = prev + 1
        else:
            columns = [f"col{i + 1}" for i in range(width)]
    skip_rows = start - 1 if header else start
    data = [_split(ln, delimiter) for ln, ok in zip(lines, numeric, strict=True) if ok]

    time_column: str | None = next((c for c in columns if _TIME_NAME.match(c.strip())), None)
    how = f"time column {time_column!r} by its name" if time_column else ""
    if time_column is None and columns and data:
        first = [float(row[0]) for row in data if row and row[0] != ""]
        if len(first) > 1 and all(b >= a for a, b in zip(first, first[1:], strict=False)) and first[-1] > first[0]:
            time_column = columns[0]
            how = f"time column {time_column!r}: the first column, increasing"
    if time_column is None:
        note = "no column looks like time (give `csv: {time_column: ...}` in the vehicle config)"
        return SniffedCsv(None, columns, delimiter, skip_rows, header, encoding, None, note)
    j = columns.index(time_column)
    values = sorted(float(row[j]) for row in data if len(row) > j and row[j] != "")
    median = values[len(values) // 2] if values else 0.0
    unit = _unit_from_name(time_column)
    origin = "absolute"
    if unit is not None:
        how += f", unit {unit} from its name"
        scale = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[unit]
        if abs(median) * scale < 1e8:
            origin = "relative"
    else:
        unit = next((u for floor, u in _EPOCH_UNITS if abs(median) >= floor), None)
        if unit is not None:
            how += f", epoch time in {unit} from its magnitude"
        else:
            unit, origin = "s", "relative"
            how += ", relative seconds (small values)"
    if origin == "relative":
        how += "; relative: set `epoch_s` to the start time if known"
    options = CsvOptions(time_column=time_column, time_unit=unit, time_origin=origin,  # type: ignore[arg-type]
                         delimiter=delimiter if delimiter != "," else None, skip_rows=skip_rows, header=header,
                         columns=None if header else columns, encoding=encoding)
    return SniffedCsv(options, columns, delimiter, skip_rows, header, encoding, time_column, how)
