"""Delimited text logs: a text trial is one file or a directory of text files, each file one stream ("topic").

What a lab exports varies, so the reader copes with: comma, tab, semicolon or whitespace separators (detected
from the first lines unless given), preamble lines before the header (``skip_rows``), files without a header
(column names from the config), header names with stray spaces or non-ASCII units (``" PWM (µs)"`` is matched
as ``"PWM (µs)"``), and gzip-compressed files (detected by content, the ``1f 8b`` magic, not by name).

The time column is parsed from its text, exactly: ``1700000000.123456789`` s becomes ``1700000000123456789`` ns
without a trip through float64 (which keeps only ~0.4 µs at today's epoch). Relative times get ``epoch_s`` added.

Parsing options live in the vehicle config (:class:`~pipeline.config.sources.CsvOptions`, per stream), so
:func:`open_text` alone can only list files; give the options with :meth:`TextLogReader.configure` (or as
``read(requests, csv_options=...)``). A file without options is read with the defaults: detected delimiter,
header on the first line, no time column (``log_ns`` is then the row number).

A value that does not parse as a number is not fatal: its row is dropped from the file's columns and the
1-based line numbers are reported in :attr:`CsvTopicData.dropped_lines` (the ingest report shows them). A bad
or empty time stamp raises :class:`~pipeline.errors.IngestError` with the line numbers. Line numbers assume one
record per physical line (no quoted newlines).

Every data line is classified by :mod:`pipeline.io.textlines` (blank, all-NaN, ragged, split in two) and counted in
:attr:`CsvTopicData.line_counts`; a dropped line keeps its sample slot and a split line takes one, so a time
rebuilt from the row index (``time: {rate_hz: ...}``) is not shifted by either. Dropped and split lines are
logged as a warning with their line numbers.

A file is counted (a block of bytes at a time) before anything parses it, and refused with an IngestError naming
the file and the limit beyond :data:`TEXT_MAX_BYTES` of text (inflated, for a ``.gz``: a 5-MB ``.csv.gz`` can
hold gigabytes of rows), :data:`TEXT_MAX_LINES` lines or a line of :data:`TEXT_MAX_LINE_BYTES`;
``open_text(path, max_bytes=..., max_lines=..., max_line_bytes=...)`` sets other limits (ingest: the params keys
``ingest.text_max_bytes``, ``text_max_lines`` and ``text_max_line_bytes``, as a :class:`TextLimits`).
"""

from __future__ import annotations

import gzip
import io
import logging
import re
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from decimal import Decimal
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from pipeline.errors import IngestError

if TYPE_CHECKING:  # pandas parses the text where a file is read: `auvid inspect` of a bag imports this module too
    import pandas as pd

    from pipeline.config.sources import CsvOptions  # (pydantic: the options come validated)
from pipeline.io.base import ReadResult, SalvageInfo, TopicData, TopicInfo
from pipeline.io.textlines import LinePlan, LineScan, field_counts, plan_lines, scan_lines
from pipeline.units import TIME_UNITS_NS

log = logging.getLogger(__name__)

GZIP_MAGIC = b"\x1f\x8b"
TEXT_SUFFIXES = (".csv", ".tsv", ".txt", ".dat", ".log", ".gz")
_CANDIDATE_DELIMITERS = (",", "\t", ";")
_WHITESPACE = r"\s+"
_SNIFF_LINES = 20
_MAX_REPORTED_LINES = 50
_INT64_MAX = (1 << 63) - 1
_DECIMAL = re.compile(r"^([+-]?)(\d*)(?:\.(\d*))?$")
_T = TypeVar("_T")
_HEAD_LINE_CHARS = 1 << 20  # a sniffed line longer than this is cut there
# The most text one file may hold, inflated: what pandas parses into memory (a float per value, a Python string
# per time stamp: ~100 bytes a row). A lab's trial at 1 kHz for an hour is ~3.6 M lines, ~300 MB.
TEXT_MAX_BYTES = 1 << 30
TEXT_MAX_LINES = 10_000_000
TEXT_MAX_LINE_BYTES = 16 << 20  # one line (a row of a log is bytes to kilobytes; pandas buffers a line whole)


@dataclass(frozen=True)
class TextLimits:
    """What one text file may hold: bytes of text (inflated), lines, bytes in one line."""

    max_bytes: int = TEXT_MAX_BYTES
    max_lines: int = TEXT_MAX_LINES
    max_line_bytes: int = TEXT_MAX_LINE_BYTES


@dataclass
class CsvTopicData(TopicData):
    """TopicData of one CSV file, plus the rows dropped because a value did not parse, and every line's kind.

    ``rows``: the sample slot of each kept row: its index among the file's data lines, blank lines and the second
    half of a split line not counted, so that time rebuilt from the row index (the stream option
    ``time: {rate_hz: ...}``) counts dropped rows too. ``line_counts``: data lines by kind (``lines``, ``kept``,
    ``blank``, ``all_nan``, ``ragged``, ``split``, ``unparseable``); ``line_numbers``: the first 1-based line numbers
    of each kind that is dropped (blank lines only between data lines).
    """

    dropped_lines: list[int] = field(default_factory=list)
    dropped_count: int = 0
    rows: np.ndarray | None = None
    line_counts: dict[str, int] = field(default_factory=dict)
    line_numbers: dict[str, list[int]] = field(default_factory=dict)


def is_gzip(path: str | Path) -> bool:
    with open(path, "rb") as handle:
        return handle.read(2) == GZIP_MAGIC


_PIECE = 1 << 20


def inflate_cut(path: str | Path, max_bytes: int = TEXT_MAX_BYTES) -> tuple[bytes, SalvageInfo]:
    """The complete lines of a gzip file cut short, and the salvage report.

    Streams the file through ``zlib.decompressobj`` (member after member) and keeps the text up to the last line
    end that inflated before the cut; the partial last line is dropped. A stream that is corrupt rather than
    cut (a deflate error, a CRC-32 or size that does not match) is an :class:`IngestError`: where corrupt bytes
    start cannot be told, so nothing is kept; so is one that inflates past ``max_bytes``.
    """
    path = Path(path)
    parts: list[bytes] = []
    size = 0
    with open(path, "rb") as fh:
        inflater, pos, member = zlib.decompressobj(wbits=31), 0, 0
        while True:
            piece = fh.read(_PIECE)
            if not piece:
                break
            while piece:
                try:
                    parts.append(inflater.decompress(piece, max_bytes + 1 - size))
                except zlib.error as err:
                    raise IngestError(f"gzip stream does not decompress (member at byte {member}): {err}",
                                      file=path) from err
                size += len(parts[-1])
                if size > max_bytes:
                    raise IngestError(f"gzip stream inflates to more than {max_bytes} bytes of text, the limit "
                                      "per text file", file=path)
                if not inflater.eof:
                    pos += len(piece)
                    break
                rest = inflater.unused_data
                pos += len(piece) - len(rest)
                piece = rest.lstrip(b"\x00")  # zero padding after a member (gzip allows it)
                pos += len(rest) - len(piece)
                member = pos
                if not piece:
                    continue
                if not piece.startswith(GZIP_MAGIC[:len(piece)]):
                    raise IngestError(f"data after the gzip stream at byte {pos} is not another gzip member",
                                      file=path)
                inflater = zlib.decompressobj(wbits=31)
        if inflater.eof or pos == member:  # complete (or nothing after the last complete member)
            raise IngestError("gzip file is complete; nothing to salvage", file=path)
    text = b"".join(parts)
    keep = text.rfind(b"\n") + 1
    lines = text.count(b"\n", 0, keep)
    info = SalvageInfo(kept=lines, stopped_at_byte=pos, reason=(
        f"{path.name}: gzip stream cut short at byte {pos} (no end marker): kept the {lines} complete line(s) "
        f"inflated before the cut, dropped {len(text) - keep} byte(s) of a partial line"))
    log.warning("%s", info.reason)
    return text[:keep], info


def looks_like_text_dir(path: str | Path) -> bool:
    """A directory holding at least one text file (by suffix) and no bag metadata / storage files."""
    path = Path(path)
    if not path.is_dir() or (path / "metadata.yaml").exists():
        return False
    files = _text_files(path)
    return bool(files) and not any(p.suffix in {".db3", ".mcap", ".bag"} for p in path.iterdir())


def open_text(path: str | Path, *, max_bytes: int = TEXT_MAX_BYTES, max_lines: int = TEXT_MAX_LINES,
              max_line_bytes: int = TEXT_MAX_LINE_BYTES) -> TextLogReader:
    """Open a directory of delimited text files (a CSV trial) or a single text file (at most ``max_bytes``,
    ``max_lines`` and a line of ``max_line_bytes`` per file)."""
    return TextLogReader(path, max_bytes=max_bytes, max_lines=max_lines, max_line_bytes=max_line_bytes)


def _text_files(directory: Path) -> list[Path]:
    return sorted(p for p in directory.rglob("*") if p.is_file() and not any(
        part.startswith(".") for part in p.relative_to(directory).parts) and p.name.lower().endswith(TEXT_SUFFIXES))


class TextLogReader:
    """LogReader over a CSV trial directory (or one file). Topics are file names relative to the directory."""

    format = "csv"

    def __init__(self, path: str | Path, *, max_bytes: int = TEXT_MAX_BYTES, max_lines: int = TEXT_MAX_LINES,
                 max_line_bytes: int = TEXT_MAX_LINE_BYTES) -> None:
        self.path = Path(path)
        self.max_bytes, self.max_lines, self.max_line_bytes = max_bytes, max_lines, max_line_bytes
        if not self.path.exists():
            raise FileNotFoundError(self.path)
        if self.path.is_dir():
            self._base = self.path
            self._files = {p.relative_to(self.path).as_posix(): p for p in _text_files(self.path)}
        else:
            self._base = self.path.parent
            self._files = {self.path.name: self.path}
        if not self._files:
            raise IngestError("no delimited text files (.csv, .tsv, .txt, .dat, .gz) in directory", file=self.path)
        self._options: dict[str, CsvOptions] = {}
        self._cut: dict[str, tuple[bytes, SalvageInfo]] = {}  # gzip files cut short: their complete lines
        self._scans: dict[tuple[str, int], LineScan] = {}  # (file, lines skipped) -> its count, within budget

    # -- LogReader protocol -------------------------------------------------------------------------------
    def __enter__(self) -> TextLogReader:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()

    def close(self) -> None:
        """Nothing stays open between calls."""

    def configure(self, csv_options: dict[str, CsvOptions]) -> None:
        """Set the parsing options per file (topic name); unknown names raise IngestError listing the files."""
        for name in csv_options:
            self._file(name)
        self._options.update(csv_options)

    def topics(self) -> dict[str, TopicInfo]:
        """Files of the trial; ``count`` is the number of data lines (non-blank, after preamble and header)."""
        out = {}
        for name in self._files:
            count = self._count_data_lines(name)
            out[name] = TopicInfo(topic=name, msgtype="csv", count=count, first_ns=None, last_ns=None,
                                  has_header=False)
        return out

    def is_empty(self, name: str) -> bool:
        """Whether a file holds no line with anything but white space (no header, no data): an empty stream."""
        return not self._scan(name, 0).any_content

    def fields(self, topic: str) -> list[str]:
        """Column names of a file (stripped of surrounding spaces)."""
        self._scan(topic, 0)
        return list(self._header(topic)[1])

    def read(self, requests: dict[str, list[str]],
             csv_options: dict[str, CsvOptions] | None = None) -> ReadResult:
        """Read the requested columns of each requested file as float64, stamped by the time column."""
        if csv_options:
            self.configure(csv_options)
        topics: dict[str, TopicData] = {}
        for name, columns in requests.items():
            topics[name] = self._read_file(name, columns)
        return ReadResult(topics=topics, failed={}, salvage=self._salvage_report(topics))

    def _salvage_report(self, topics: dict[str, TopicData]) -> SalvageInfo | None:
        cut = [self._cut[name][1] for name in topics if name in self._cut]
        if not cut:
            return None
        return SalvageInfo(kept=sum(topics[n].read for n in topics if n in self._cut),
                           stopped_at_byte=cut[0].stopped_at_byte, reason="; ".join(c.reason for c in cut))

    # -- internals ----------------------------------------------------------------------------------------
    def _file(self, name: str) -> Path:
        try:
            return self._files[name]
        except KeyError:
            raise IngestError(f"no file {name!r} in CSV trial; available: {sorted(self._files)}",
                              file=self.path, topic=name) from None

    def _opts(self, name: str) -> CsvOptions | None:
        return self._options.get(name)

    def _source(self, name: str) -> Path | io.BytesIO:
        """What pandas reads: the file, or the complete lines of a gzip file cut short."""
        return io.BytesIO(self._cut[name][0]) if name in self._cut else self._file(name)

    def _binary(self, name: str) -> io.BufferedIOBase:
        path = self._file(name)
        if name in self._cut:
            return io.BytesIO(self._cut[name][0])
        return gzip.open(path, "rb") if is_gzip(path) else open(path, "rb")  # type: ignore[return-value]

    def _tolerating_cut(self, name: str, run: Callable[[], _T]) -> _T:
        """``run()``; when a gzip file ends before its end marker, again on the complete lines before the cut."""
        try:
            return run()
        except EOFError:
            path = self._file(name)
            if name in self._cut or not is_gzip(path):
                raise
        self._cut[name] = inflate_cut(path, self.max_bytes)
        return run()

    def _text_head(self, name: str, n_lines: int) -> list[str]:
        path = self._file(name)
        opts = self._opts(name)
        encoding = opts.encoding if opts else "utf-8"

        def head() -> list[str]:
            lines: list[str] = []
            with io.TextIOWrapper(self._binary(name), encoding=encoding, errors="strict", newline="") as handle:
                while len(lines) < n_lines and (line := handle.readline(_HEAD_LINE_CHARS)):
                    lines.append(line.rstrip("\r\n"))
            return lines

        try:
            return self._tolerating_cut(name, head)
        except (UnicodeError, OSError, EOFError, zlib.error) as err:
            raise IngestError(f"cannot read as {encoding} text: {err}{_bom_hint(err, encoding)}", file=path) from err

    def _count_data_lines(self, name: str) -> int:
        opts = self._opts(name)
        skip = (opts.skip_rows if opts else 0) + (1 if (opts is None or opts.header) else 0)
        count = self._scan(name, 0).data_after(skip)
        return count if count is not None else self._scan(name, skip).data_lines

    def _scan(self, name: str, skip: int) -> LineScan:
        """The file's lines counted in blocks; an IngestError naming the limit when it holds more than the budget."""
        if (name, skip) in self._scans:
            return self._scans[name, skip]
        path = self._file(name)

        def scan() -> LineScan:
            with self._binary(name) as handle:
                return scan_lines(handle, skip=skip, max_bytes=self.max_bytes, max_lines=self.max_lines,
                                  max_line_bytes=self.max_line_bytes)

        try:
            found = self._tolerating_cut(name, scan)
        except (OSError, EOFError, zlib.error) as err:  # zlib.error: a corrupt deflate stream in a .gz
            raise IngestError(f"cannot read: {err}", file=path) from err
        if found.over is not None:
            inflated = " (inflated)" if is_gzip(path) else ""
            limit = {"bytes": f"more than {self.max_bytes} bytes of text{inflated}",
                     "lines": f"more than {self.max_lines} lines",
                     "line": f"a line longer than {self.max_line_bytes} bytes"}[found.over]
            raise IngestError(f"text file holds {limit}, the limit per text file (stopped counting at "
                              f"{found.size} bytes, line {found.lines + 1}); split the log", file=path)
        self._scans[name, skip] = found
        return found

    def _delimiter(self, name: str) -> str:
        opts = self._opts(name)
        if opts is not None and opts.delimiter is not None:
            return _WHITESPACE if opts.delimiter.strip() == "" and opts.delimiter not in ("\t",) else opts.delimiter
        skip = opts.skip_rows if opts else 0
        lines = [ln for ln in self._text_head(name, skip + _SNIFF_LINES)[skip:] if ln.strip()]
        if not lines:
            raise IngestError("empty file (no header or data lines)", file=self._file(name))
        return sniff_delimiter(lines)

    def _read_kwargs(self, name: str) -> dict[str, object]:
        opts = self._opts(name)
        sep = self._delimiter(name)
        kwargs: dict[str, object] = {
            "sep": sep,
            "skiprows": opts.skip_rows if opts else 0,
            "encoding": opts.encoding if opts else "utf-8",
            "skip_blank_lines": False,
            "engine": "c",
        }
        if sep != _WHITESPACE:
            kwargs["skipinitialspace"] = True
        if opts is not None and not opts.header:
            kwargs["header"] = None
            kwargs["names"] = list(opts.columns or [])
        return kwargs

    def _compression(self, name: str) -> dict[str, object]:
        """pandas' compression for the source (evaluated when read: a cut file is read as plain text)."""
        return {"compression": "gzip" if name not in self._cut and is_gzip(self._file(name)) else None}

    def _header(self, name: str) -> tuple[list[str], list[str]]:
        """(raw names as pandas sees them, stripped names)."""
        import pandas as pd

        path = self._file(name)
        kwargs = self._read_kwargs(name)
        try:
            frame = self._tolerating_cut(name, lambda: pd.read_csv(  # type: ignore[call-overload]
                self._source(name), nrows=0, **{**kwargs, **self._compression(name)}))
        except pd.errors.EmptyDataError as err:
            raise IngestError("empty file (no header or data lines)", file=path, topic=name) from err
        except (ValueError, UnicodeError, OSError, EOFError, zlib.error) as err:
            raise IngestError(f"{name}: cannot parse as delimited text: {err}{_bom_hint(err, kwargs['encoding'])}",
                              file=path, topic=name) from err  # a trial directory's quarantine names the file
        raw = [str(c) for c in frame.columns]
        return raw, [c.strip() for c in raw]

    def _read_file(self, name: str, columns: list[str]) -> CsvTopicData:
        import pandas as pd

        path = self._file(name)
        opts = self._opts(name)
        self._scan(name, 0)  # within the budget before pandas parses it
        raw, stripped = self._header(name)
        by_name = dict(zip(stripped, raw, strict=True))
        wanted = list(dict.fromkeys([*(c.strip() for c in columns), *([opts.time_column.strip()] if opts else [])]))
        for col in wanted:
            if col not in by_name:
                raise IngestError(f"no column {col!r}; available: {stripped}", file=path, topic=name, field=col)
        kwargs = self._read_kwargs(name)
        use = [by_name[c] for c in wanted]
        dtype = {by_name[opts.time_column.strip()]: str} if opts else None
        try:
            frame = self._tolerating_cut(name, lambda: pd.read_csv(  # type: ignore[call-overload]
                self._source(name), usecols=use, dtype=dtype, **{**kwargs, **self._compression(name)}))
        except (ValueError, UnicodeError, OSError, EOFError, zlib.error, pd.errors.ParserError) as err:
            raise IngestError(f"{name}: cannot parse as delimited text: {err}{_bom_hint(err, kwargs['encoding'])}",
                              file=path, topic=name) from err
        frame.columns = [str(c).strip() for c in frame.columns]
        skip = (opts.skip_rows if opts else 0) + (1 if (opts is None or opts.header) else 0)
        plan = self._line_plan(name, str(kwargs["sep"]), skip, len(raw), len(frame))
        all_nan = frame.isna().all(axis=1).to_numpy() & ~(plan.blank | plan.ragged | plan.split)
        keep = ~(plan.blank | plan.ragged | plan.split | all_nan)
        lines = np.flatnonzero(keep).astype(np.int64) + skip + 1
        slots = plan.slot[keep]
        frame = frame.loc[keep].reset_index(drop=True)
        expected = len(frame) + int(plan.ragged.sum()) + int(plan.split.sum()) // 2
        counts, numbers = _line_kinds(plan, all_nan, skip)

        if opts is not None:
            log_ns = time_to_ns(frame[opts.time_column.strip()], opts, path=path, topic=name, lines=lines)
        else:
            log_ns = np.arange(len(frame), dtype=np.int64)

        values: dict[str, np.ndarray] = {}
        bad = np.zeros(len(frame), dtype=bool)
        for col in dict.fromkeys(c.strip() for c in columns):
            series = frame[col]
            if series.dtype == object or pd.api.types.is_string_dtype(series.dtype):
                text = series.astype("string").str.strip()
                numeric = pd.to_numeric(text, errors="coerce")
                bad |= (numeric.isna() & text.notna() & (text != "")).to_numpy()
                values[col] = numeric.to_numpy(dtype=np.float64, na_value=np.nan)
            else:
                values[col] = series.to_numpy(dtype=np.float64, na_value=np.nan)
        dropped: list[int] = []
        rows = slots
        if bad.any():
            dropped = lines[bad].tolist()
            log.warning("%s: dropped %d row(s) with unparseable numbers at line(s) %s", path, len(dropped),
                        dropped[:10])
            keep = ~bad
            log_ns = log_ns[keep]
            rows = rows[keep]
            values = {k: v[keep] for k, v in values.items()}
        counts.update(kept=len(log_ns), unparseable=len(dropped))
        if dropped:
            numbers["unparseable"] = dropped[:_MAX_REPORTED_LINES]
        _warn_lines(path, counts, numbers)
        return CsvTopicData(topic=name, msgtype="csv", log_ns=log_ns, header_ns=None, columns=values,
                            path="csv", read=len(log_ns), expected=expected,
                            dropped_lines=dropped[:_MAX_REPORTED_LINES], dropped_count=len(dropped), rows=rows,
                            line_counts=counts, line_numbers=numbers)

    def _line_plan(self, name: str, sep: str, skip: int, header_fields: int, parsed: int) -> LinePlan:
        """The kind and slot of each data line; every parsed row a whole line when the lines cannot be counted."""
        opts = self._opts(name)
        encoding = opts.encoding if opts else "utf-8"
        delimiter = None if sep == _WHITESPACE else sep
        plan = None
        if delimiter is None or (len(delimiter) == 1 and delimiter.isascii()):
            try:
                with self._binary(name) as handle:
                    fields = field_counts(handle, skip=skip, delimiter=delimiter, encoding=encoding)
            except (UnicodeError, OSError, EOFError, zlib.error) as err:
                raise IngestError(f"cannot read as {encoding} text: {err}{_bom_hint(err, encoding)}",
                                  file=self._file(name), topic=name) from err
            if fields.size == parsed:
                plan = plan_lines(fields, header_fields)
            else:  # quoted line breaks, bare CR line ends: physical lines are not the parser's rows
                log.warning("%s: %d lines after the header but %d rows parsed (quoted line breaks or CR line "
                            "ends?): lines not classified, every row taken as one sample", self._file(name),
                            fields.size, parsed)
        if plan is None:
            plan = plan_lines(np.full(parsed, header_fields, dtype=np.int64), header_fields)
        return plan


def _bom_hint(err: BaseException, encoding: object) -> str:
    """What to give instead when ``utf-16`` / ``utf-32`` meets a file without a byte-order mark."""
    if isinstance(err, UnicodeError) and "BOM" in str(err):
        return (f" (`encoding: {encoding}` needs a byte-order mark at the start of the file; for a file without "
                "one give the byte order: utf-16-le, utf-16-be, utf-32-le or utf-32-be)")
    return ""


def _line_kinds(plan: LinePlan, all_nan: np.ndarray, skip: int) -> tuple[dict[str, int], dict[str, list[int]]]:
    """Counts of the data lines by kind and the first line numbers of each dropped kind."""
    filled = np.flatnonzero(~plan.blank)
    inner_blank = plan.blank.copy()
    inner_blank[filled[-1] + 1 if filled.size else 0:] = False  # blank lines at the end are no news
    counts = {"lines": int(plan.blank.size), "blank": int(plan.blank.sum()), "blank_between": int(inner_blank.sum()),
              "all_nan": int(all_nan.sum()), "ragged": int(plan.ragged.sum()), "split": int(plan.split.sum())}
    numbers = {kind: (np.flatnonzero(mask)[:_MAX_REPORTED_LINES] + skip + 1).tolist()
               for kind, mask in (("blank", inner_blank), ("all_nan", all_nan), ("ragged", plan.ragged),
                                  ("split", plan.split)) if mask.any()}
    return counts, numbers


def _warn_lines(path: Path, counts: dict[str, int], numbers: dict[str, list[int]]) -> None:
    """One warning per file naming the lines dropped or split, and how time from the row index treats them."""
    parts = []
    for kind, what in (("all_nan", "without a value"), ("ragged", "with a field count unlike the file's"),
                       ("split", "split in two (each pair read as one dropped sample)"),
                       ("blank", "blank between data lines (not counted as samples)")):
        if kind in numbers:
            total = counts["blank_between" if kind == "blank" else kind]
            parts.append(f"{total} line(s) {what} at {numbers[kind][:10]}")
    if parts:
        log.warning("%s: dropped %s; every other dropped line keeps its slot in a time rebuilt from the row index",
                    path, "; ".join(parts))


def sniff_delimiter(lines: list[str]) -> str:
    """Comma, tab or semicolon if every line has the same nonzero count of it; else whitespace."""
    for cand in _CANDIDATE_DELIMITERS:
        counts = {ln.count(cand) for ln in lines}
        if len(counts) == 1 and counts.pop() > 0:
            return cand
    widths = {len(ln.split()) for ln in lines}
    if len(widths) == 1 and widths.pop() > 1:
        return _WHITESPACE
    # ragged lines: the candidate present on the most lines, else whitespace
    best = max(_CANDIDATE_DELIMITERS, key=lambda c: sum(c in ln for ln in lines))
    return best if any(best in ln for ln in lines) else _WHITESPACE


def _epoch_ns(epoch_s: float) -> int:
    return int((Decimal(repr(epoch_s)) * 1_000_000_000).to_integral_value())


def time_to_ns(raw: pd.Series, opts: CsvOptions, *, path: Path | str, topic: str,
               lines: np.ndarray) -> np.ndarray:
    """Exact decimal text -> int64 ns in the configured unit and origin; bad stamps raise IngestError.

    A stamp beyond int64 nanoseconds (past the year 2262, e.g. ``99999999999`` s or ``1e300``) is an error
    naming its lines, never a wrapped value; negative absolute stamps (before 1970) are logged.
    """
    import pandas as pd

    unit_ns = TIME_UNITS_NS[opts.time_unit]
    digits = len(str(unit_ns)) - 1
    text = raw.astype("string").str.strip().fillna("")
    parts = text.str.extract(_DECIMAL)
    ok = parts[1].fillna("").ne("") | parts[2].fillna("").ne("")
    ok &= text.ne("")
    ns = np.zeros(len(text), dtype=np.int64)
    okv = ok.to_numpy(dtype=bool)
    out_of_range = np.zeros(len(text), dtype=bool)
    max_whole = _INT64_MAX // unit_ns - 1  # whole units that still leave room for the fraction
    if okv.any():
        sign = np.where(parts[0][ok].fillna("").to_numpy(dtype=object) == "-", -1, 1).astype(np.int64)
        whole_text = parts[1][ok].fillna("").str.lstrip("0").replace("", "0")
        # up to 19 digits fit uint64 exactly; longer ones are out of range whatever they hold
        long = (whole_text.str.len() > 19).to_numpy(dtype=bool)
        whole_u = whole_text.where(~long, "0").astype("uint64").to_numpy(dtype=np.uint64)
        big = long | (whole_u > np.uint64(max_whole))
        whole = np.where(big, 0, whole_u).astype(np.int64)
        frac = parts[2][ok].fillna("").str.ljust(digits + 1, "0").str.slice(0, digits + 1)
        frac_int = frac.astype("int64").to_numpy(dtype=np.int64)
        frac_ns = (frac_int + 5) // 10  # round half up at the nanosecond
        ns[okv] = sign * (whole * unit_ns + frac_ns)
        out_of_range[np.flatnonzero(okv)[big]] = True
    rest = ~okv
    if rest.any():  # exponent notation and the like: through float, then check
        floats = pd.to_numeric(text[rest], errors="coerce").to_numpy(dtype=np.float64, na_value=np.nan)
        bad = ~np.isfinite(floats)
        if bad.any():
            bad_lines = lines[rest][bad].tolist()
            raise IngestError(f"unparseable or empty time stamp at line(s) {bad_lines[:_MAX_REPORTED_LINES]} "
                              f"({len(bad_lines)} in all)", file=path, topic=topic, field=opts.time_column)
        with np.errstate(over="ignore"):
            scaled = floats * unit_ns
        big = np.abs(scaled) >= 2.0**63 - 1024  # the largest float64 below 2**63 is 2**63 - 1024
        ns[rest] = np.round(np.where(big, 0.0, scaled)).astype(np.int64)
        out_of_range[np.flatnonzero(rest)[big]] = True
    offset = _epoch_ns(opts.epoch_s) if opts.time_origin == "relative" else 0
    if abs(offset) > _INT64_MAX:
        raise IngestError(f"epoch_s {opts.epoch_s!r} is beyond the int64 nanosecond range (year 1678..2262)",
                          file=path, topic=topic, field="epoch_s")
    if len(ns) and not out_of_range.all():
        lo, hi = int(ns[~out_of_range].min()), int(ns[~out_of_range].max())
        if not (-_INT64_MAX <= lo + offset and hi + offset <= _INT64_MAX):
            out_of_range |= (ns.astype(object) + offset > _INT64_MAX) | (ns.astype(object) + offset < -_INT64_MAX)
    if out_of_range.any():
        bad_lines = lines[out_of_range].tolist()
        raise IngestError(f"time stamp beyond the int64 nanosecond range (year 1678..2262) at line(s) "
                          f"{bad_lines[:_MAX_REPORTED_LINES]} ({len(bad_lines)} in all)", file=path, topic=topic,
                          field=opts.time_column)
    if offset:
        ns = ns + np.int64(offset)
    if opts.time_origin == "absolute" and len(ns) and (ns < 0).any():
        neg = lines[ns < 0].tolist()
        log.warning("%s: %s: absolute time stamp before 1970 at line(s) %s (%d in all)", path, topic,
                    neg[:10], len(neg))
    return ns
