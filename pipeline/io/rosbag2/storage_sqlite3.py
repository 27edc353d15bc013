"""The sqlite3 storage of a ROS 2 bag: topics and counts through sqlite, the ``messages`` rows in bulk.

Rows come from the table's b-tree pages (:mod:`pipeline.io.sqlite_btree`) while they are as rosbag2 writes them,
else through sqlite's aggregates or row by row; a damaged file is read from its intact pages
(:mod:`pipeline.io.sqlite_pages`): one sqlite reports, or one whose rows come back out of id order (every fetch
checks that ids rise strictly, so the paging loop ends). The file is always opened read-only and never written
beside.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np

from pipeline.errors import IngestError
from pipeline.io.base import Batch, Batcher, Rows, SalvageInfo
from pipeline.io.errors import Malformed, NotPlain, Restart
from pipeline.io.fields import TypeRegistry, normalize_msgtype

if TYPE_CHECKING:
    import sqlite3

    from pipeline.io.sqlite_pages import MessageRows

log = logging.getLogger(__name__)


class Sqlite3Storage:
    """The sqlite3 half of :class:`pipeline.io.rosbag2.reader.Rosbag2Reader` (a mixin: the reader holds the state
    and undoes per-message compression, ``_decompress``)."""

    files: list[Path]
    salvage: SalvageInfo | None
    compression_mode: str
    _types: TypeRegistry | None
    _infos: dict[str, Any] | None
    _ids: list[dict[int, str]]
    _pages: dict[Path, PageSalvage]
    _row_fetch: bool
    _page_fetch: bool

    def _connect(self, path: Path, *, tolerant: bool = False) -> sqlite3.Connection:
        import sqlite3  # here: a bag of MCAP storage (or an MCAP file, which detection looks at) needs no sqlite

        try:
            con = sqlite3.connect(_read_only_uri(path), uri=True)
            if tolerant:  # read what is there of a file whose header claims more pages than it holds
                con.execute("PRAGMA writable_schema = ON")
            return con
        except sqlite3.Error as err:
            raise IngestError(f"cannot open sqlite storage: {err}", file=path) from err

    def _scan_sqlite(self, path: Path, ids: dict[int, str], add: Any, *, stats: bool = True) -> None:
        import sqlite3

        from pipeline.io.sqlite_pages import cut_short

        cut = cut_short(path)
        con = self._connect(path, tolerant=cut is not None)
        damage = None if cut is None else sqlite3.DatabaseError(f"cut short: {cut}")
        try:
            try:
                topics = self._schema_rows(con, path, ids)
            except (sqlite3.DatabaseError, IngestError) as err:
                if cut is not None:
                    raise IngestError(f"sqlite storage cut short ({cut}) before its tables 'topics' and "
                                      f"'message_definitions' end: {err}", file=path) from err
                if isinstance(err, IngestError):
                    raise
                # A file cut short: sqlite refuses a header that claims more pages than the file holds, unless
                # told that the schema may be odd; the small tables at the file's start then read as usual.
                con.close()
                con = self._connect(path, tolerant=True)
                try:
                    topics = self._schema_rows(con, path, ids)
                except sqlite3.DatabaseError:
                    raise IngestError(f"not a readable rosbag2 sqlite3 storage file: {err}", file=path) from err
                damage = err
            if path in self._pages:
                counted = self._pages[path].counted()
            elif damage is not None:
                counted = self._salvage_sqlite(path, ids, damage).counted()
            elif stats:
                try:
                    counted = {tid: (n, lo, hi) for tid, n, lo, hi in con.execute(
                        "SELECT topic_id, COUNT(*), MIN(timestamp), MAX(timestamp) FROM messages GROUP BY topic_id")}
                except sqlite3.DatabaseError as err:  # damaged or missing pages under the messages table
                    counted = self._salvage_sqlite(path, ids, err).counted()
            else:
                counted = {}
        except UnicodeDecodeError as err:  # names that are not UTF-8
            raise IngestError(f"not a readable rosbag2 sqlite3 storage file: {err}", file=path) from err
        finally:
            con.close()
        for tid, name, typ, fmt in topics:
            n, lo, hi = counted.get(tid, (0, None, None))
            add(name, normalize_msgtype(typ), fmt, n, lo, hi)

    def _schema_rows(self, con: sqlite3.Connection, path: Path, ids: dict[int, str]) -> list[tuple[Any, ...]]:
        """Register the message definitions; the rows of table ``topics`` (their ids into ``ids``)."""
        tables = {r[0] for r in con.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if "message_definitions" in tables:
            for typ, enc, text in con.execute(
                    "SELECT topic_type, encoding, encoded_message_definition FROM message_definitions"):
                if not (isinstance(typ, str) and isinstance(enc, str) and isinstance(text, str)):
                    raise IngestError(f"damaged row in table 'message_definitions': type {typ!r}, encoding "
                                      f"{enc!r} (expected three strings)", file=path)
                self._types.add(normalize_msgtype(typ), enc, text)  # type: ignore[union-attr]
        topics = list(con.execute("SELECT id, name, type, serialization_format FROM topics"))
        for tid, name, typ, fmt in topics:
            if not (isinstance(tid, int) and isinstance(name, str) and isinstance(typ, str)
                    and isinstance(fmt, str)):
                raise IngestError(
                    f"damaged row in table 'topics': id {tid!r}, name {name!r}, type {typ!r}, "
                    f"serialization_format {fmt!r} (expected an integer id and three strings)", file=path)
            ids[tid] = name
        return topics

    def _salvage_sqlite(self, path: Path, ids: dict[int, str], err: sqlite3.DatabaseError) -> PageSalvage:
        """Read the message rows of a damaged storage file from its intact pages (:mod:`.sqlite_pages`)."""
        from pipeline.io.sqlite_pages import SqlitePages, message_rows

        log.warning("%s: sqlite cannot read the messages table (%s); reading the rows from the intact pages",
                    path, err)
        with SqlitePages(path) as pages:
            rows = message_rows(pages, set(ids))
        damaged = f"; {rows.bad_cells} damaged cell(s) skipped" if rows.bad_cells else ""
        found = PageSalvage(rows, f"{path.name}: {err}; kept the {len(rows.rowid)} message row(s) on intact "
                                   f"pages{damaged}")
        self._pages[path] = found
        log.warning("%s", found.reason)
        first = next(iter(self._pages.values()))
        self.salvage = SalvageInfo(  # every damaged file of a split bag
            kept=sum(len(p.rows.rowid) for p in self._pages.values()), stopped_at_byte=first.rows.cut_at,
            reason="; ".join(p.reason for p in self._pages.values()))
        return found

    def _page_batches(self, path: Path, wanted: dict[int, str]) -> Iterator[Batch]:
        """The rows of a damaged storage file, from its intact pages, in rowid order."""
        from pipeline.io.sqlite_pages import SqlitePages, message_payloads

        batcher = Batcher()
        with SqlitePages(path) as pages:
            try:
                for tid, log_ns, data in message_payloads(pages, self._pages[path].rows, set(wanted)):
                    batch = batcher.add(wanted[tid], log_ns, self._decompress(data, path))
                    if batch is not None:
                        yield batch
            except (Malformed, KeyError) as err:  # the file changed since the scan
                raise IngestError(f"storage file changed while reading its pages: {err}", file=path) from err
        last = batcher.flush()
        if last is not None:
            yield last

    def _sqlite_batches(self, path: Path, wanted: dict[int, str]) -> Iterator[Batch]:
        """Rows in bulk, ~16 MB at a time, in ``id`` order. The messages table's leaf pages are read and parsed
        many rows at once (:mod:`.sqlite_btree`, the cheapest of the three), as long as they hold what that
        parser takes; from the first thing it does not (or a schema other than rosbag2's), sqlite fetches the rest
        of the rows: one row of aggregates a batch (:func:`_concatenated_rows`; sqlite joins the payloads and
        lists the ids, stamps and lengths in C). Per-message compression needs each payload on its own: those
        rows come through the sqlite3 module one by one (:func:`_fetched_rows`), as they do when ``_row_fetch``
        is set. A damaged file is read from its intact pages instead (:meth:`_salvage_sqlite`).
        """
        import sqlite3

        if path in self._pages:
            yield from self._page_batches(path, wanted)
            return
        per_message = self.compression_mode == "MESSAGE"
        con = self._connect(path)
        fetched = 0
        try:
            if per_message or self._row_fetch:
                rows = _fetched_rows(con, wanted, lambda d: self._decompress(bytes(d), path) if per_message else d)
            elif self._page_fetch:
                rows = _paged_rows(con, path, wanted)
            else:
                rows = _concatenated_rows(con, wanted)
            for tid_arr, stamp_arr, buf, starts, lengths in rows:
                fetched += len(lengths)
                yield _batch(wanted, tid_arr, stamp_arr, buf, starts, lengths)
        except _DamagedRow as err:
            raise IngestError(f"damaged row in table 'messages' after {fetched} rows: {err} (expected integer "
                              "topic_id and timestamp, blob data)", file=path) from err
        except sqlite3.DatabaseError as err:  # damaged pages found while fetching (opening was fine)
            con.close()
            ids = self._ids[self.files.index(path)]
            self._salvage_sqlite(path, ids, err)
            self._infos = None  # counts from the pages now
            raise Restart from err
        finally:
            con.close()


def _read_only_uri(path: Path) -> str:
    """The sqlite URI that opens ``path`` read-only and never writes beside it (no journal, no -wal file).

    The path is percent-encoded: a '?', '#' or '%' in a directory name would otherwise end the file name early
    and open (or create) another file.
    """
    return f"file:{quote(str(Path(path).resolve()), safe='/')}?mode=ro&immutable=1"


class _DamagedRow(Exception):
    """A row of table ``messages`` whose topic_id or timestamp is not an integer, or whose data is not a blob."""


def _unordered(ids: np.ndarray, after: int | None) -> str | None:
    """Why the ids of a batch fetched ``ORDER BY id`` (after id ``after``) show a damaged b-tree, or None.

    sqlite trusts the tree: with a page duplicated or moved, ``WHERE id > ?`` hands back rows at or before ``?``
    (the paging loop would fetch the same rows for ever) and a scan meets rows twice. Requiring every batch's ids
    to rise strictly, beyond the last batch's, bounds the loop by the rows the file holds.
    """
    if after is not None and ids.size and ids[0] <= after:
        return f"id {int(ids[0])} came after id {after}"
    down = np.flatnonzero(np.diff(ids) <= 0)
    if down.size:
        return f"id {int(ids[down[0] + 1])} came after id {int(ids[down[0]])}"
    return None


def _out_of_order(why: str) -> sqlite3.DatabaseError:
    """The damage as the sqlite error that sends the file to its salvage path (read from its intact pages)."""
    import sqlite3

    return sqlite3.DatabaseError(f"rows of table 'messages' out of id order ({why}): its b-tree is damaged")


def _messages_sql(wanted: dict[int, str], columns: str, after: bool, limit: int | None) -> str:
    where = f"topic_id IN ({','.join(str(int(i)) for i in wanted)})"
    return (f"SELECT {columns} FROM messages WHERE {'id > ? AND ' if after else ''}{where} ORDER BY id"
            + (f" LIMIT {int(limit)}" if limit else ""))


def _paged_rows(con: sqlite3.Connection, path: Path, wanted: dict[int, str],
                limit: int | None = None) -> Iterator[tuple[np.ndarray, ...]]:
    """The wanted rows parsed from the messages table's pages (:func:`.sqlite_btree.row_batches`); from the first
    page or row that parser does not take, the rows after the last one handed on through
    :func:`_concatenated_rows`. Only the rosbag2 table (id INTEGER PRIMARY KEY, topic_id, timestamp, data, a rowid
    table) in a file with no write-ahead log beside it is read from its pages."""
    from pipeline.io.sqlite_btree import row_batches

    root = _messages_root(con, path)
    if root is None:
        yield from _concatenated_rows(con, wanted)
        return
    ids = np.fromiter(wanted, dtype=np.int64, count=len(wanted))
    last: int | None = None
    try:
        for rows in row_batches(path, root, limit or BATCH_BYTES):
            keep = np.isin(rows.topic_id, ids)
            if keep.all():
                yield rows.topic_id, rows.log_ns, rows.buf, rows.starts, rows.lengths
            elif keep.any():
                yield rows.topic_id[keep], rows.log_ns[keep], rows.buf, rows.starts[keep], rows.lengths[keep]
            last = rows.last_id
    except NotPlain as why:
        log.info("%s: %s; sqlite reads the rows after id %s", path, why, last)
        yield from _concatenated_rows(con, wanted, after=last)


def _messages_root(con: sqlite3.Connection, path: Path) -> int | None:
    """The root page of table ``messages`` when its pages can be read as rosbag2 writes them, else None."""
    found = con.execute("SELECT rootpage, sql FROM sqlite_master WHERE type = 'table' AND name = 'messages'").fetchall()
    if len(found) != 1 or not isinstance(found[0][0], int) or "WITHOUT ROWID" in str(found[0][1]).upper():
        return None
    columns = [(name, str(typ).upper(), pk) for _, name, typ, _, _, pk in con.execute("PRAGMA table_info(messages)")]
    if columns != [("id", "INTEGER", 1), ("topic_id", "INTEGER", 0), ("timestamp", "INTEGER", 0),
                   ("data", "BLOB", 0)]:
        return None
    wal = Path(f"{path}-wal")
    if wal.exists() and wal.stat().st_size:  # committed rows may lie in the log, not yet on the pages
        return None
    return int(found[0][0])


def _concatenated_rows(con: sqlite3.Connection, wanted: dict[int, str],
                       after: int | None = None) -> Iterator[tuple[np.ndarray, ...]]:
    """Batches of (topic ids, timestamps, payload buffer, starts, lengths), each fetched as one row of aggregates
    over the next rows in ``id`` order: ``group_concat`` of the ids, stamps and payload lengths (decimal text, read
    by numpy) and of the payloads themselves (one blob). Per message, sqlite does the work in C and Python none:
    about half the CPU of the rows fetched as tuples, and no driver to import (ADBC's import took pyarrow.dataset
    and pandas along; docs/benchmarks.md, "sqlite3 fetches"). A row whose types are not integer, integer, blob raises
    :class:`_DamagedRow`. ``after``: only the rows whose id is greater.
    """
    # A stamp or topic id that is not an integer ('soon', 1.5) is text that numpy refuses; a payload that is not a
    # blob would join unseen, so its type is counted (the one check paid per row).
    aggregates = ("count(*), total(typeof(data) != 'blob'), group_concat(id), group_concat(topic_id), "
                  "group_concat(timestamp), group_concat(length(data)), CAST(group_concat(data, '') AS BLOB)")
    limit = FIRST_BATCH_ROWS
    last = after
    while True:
        inner = _messages_sql(wanted, "id, topic_id, timestamp, data", last is not None, limit)
        row = con.execute(f"SELECT {aggregates} FROM ({inner})", () if last is None else (last,)).fetchone()
        count, bad, ids_text, tids, stamps, lengths_text, data = row
        if not count:
            return
        if bad:
            raise _DamagedRow(f"{int(bad)} of the next {count} rows hold a payload that is not a blob")
        ids = _decimal_list(ids_text, count)
        why = _unordered(ids, last)
        if why:  # the loop goes on only while the paging key strictly advances
            raise _out_of_order(why)
        last = int(ids[-1])
        tid_arr, stamp_arr, lengths = (_decimal_list(t, count) for t in (tids, stamps, lengths_text))
        buf = np.frombuffer(data, dtype=np.uint8) if data else np.empty(0, dtype=np.uint8)
        if int(lengths.sum()) != len(buf):
            raise _DamagedRow(f"payload lengths add up to {int(lengths.sum())} bytes, the payloads to {len(buf)}")
        starts = np.zeros(count, dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        yield tid_arr, stamp_arr, buf, starts, lengths
        limit = min(BATCH_ROWS, max(64, BATCH_BYTES * count // max(1, len(buf))))


def _decimal_list(text: str | None, count: int) -> np.ndarray:
    """The ``count`` integers of a comma-separated decimal list (a ``group_concat`` of integers)."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # numpy warns, and stops, at text that is not a number
        try:
            values = np.fromstring(text, dtype=np.int64, sep=",") if text else np.empty(0, dtype=np.int64)
        except (DeprecationWarning, ValueError) as err:
            raise _DamagedRow(f"a list of integers that numpy cannot read: {err}") from None
    if len(values) != count:
        raise _DamagedRow(f"{len(values)} values for {count} rows")
    return values


def _fetched_rows(con: sqlite3.Connection, wanted: dict[int, str],
                  payload: Any) -> Iterator[tuple[np.ndarray, ...]]:
    """The same batches from rows fetched as tuples by the sqlite3 module; ``payload`` maps each row's data."""
    cur = con.execute(_messages_sql(wanted, "id, topic_id, timestamp, data", False, None))
    last: int | None = None
    while True:
        rows = cur.fetchmany(BATCH_ROWS)
        if not rows:
            return
        ids, tids, stamps, datas = zip(*rows, strict=True)
        del rows
        id_arr = np.fromiter(ids, dtype=np.int64, count=len(ids))  # the primary key: always an integer
        why = _unordered(id_arr, last)
        if why:
            raise _out_of_order(why)
        last = int(id_arr[-1])
        try:
            datas = tuple(payload(d) for d in datas)
            lengths = np.fromiter(map(len, datas), dtype=np.int64, count=len(datas))
            buf = np.frombuffer(b"".join(datas), dtype=np.uint8)
            tid_arr = np.fromiter(tids, dtype=np.int64, count=len(tids))
            stamp_arr = np.fromiter(stamps, dtype=np.int64, count=len(stamps))
        except (TypeError, ValueError) as err:  # NULL, text or float where the schema has int / blob
            raise _DamagedRow(str(err)) from err
        starts = np.zeros(len(datas), dtype=np.int64)
        np.cumsum(lengths[:-1], out=starts[1:])
        del datas
        yield tid_arr, stamp_arr, buf, starts, lengths


BATCH_ROWS = 65536
FIRST_BATCH_ROWS = 4096  # then as many rows as hold ~BATCH_BYTES of payload, at most BATCH_ROWS
BATCH_BYTES = 16 << 20


class PageSalvage:
    """The message rows of one damaged storage file, found on its pages."""

    def __init__(self, rows: MessageRows, reason: str) -> None:
        self.rows = rows
        self.reason = reason

    def counted(self) -> dict[int, tuple[int, int | None, int | None]]:
        """topic id -> (rows, first, last timestamp), as the COUNT query gives them for an intact file."""
        out = {}
        for tid in np.unique(self.rows.topic_id).tolist():
            stamps = self.rows.log_ns[self.rows.topic_id == tid]
            out[tid] = (len(stamps), int(stamps.min()), int(stamps.max()))
        return out


def _batch(wanted: dict[int, str], tid: np.ndarray, log_ns: np.ndarray, buf: np.ndarray, starts: np.ndarray,
           lengths: np.ndarray) -> Batch:
    out = {}
    for i, topic in wanted.items():
        m = tid == i
        if m.any():
            rows = Rows(starts[m], lengths[m], log_ns[m])
            if topic in out:  # two ids of one topic (split bags renumber; one file may repeat)
                prev = out[topic]
                order = np.argsort(np.concatenate([prev.starts, rows.starts]), kind="stable")
                rows = Rows(*(np.concatenate([a, b])[order] for a, b in
                              ((prev.starts, rows.starts), (prev.lengths, rows.lengths), (prev.log_ns, rows.log_ns))))
            out[topic] = rows
    return Batch(buf, out)
