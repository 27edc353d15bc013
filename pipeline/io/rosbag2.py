"""ROS 2 bags: a directory of sqlite3 or MCAP storage files, with or without ``metadata.yaml``.

Storage is read directly (the sqlite ``messages`` table parsed from its b-tree pages by :mod:`.sqlite_btree`, or
fetched in bulk through sqlite; MCAP records walked by :mod:`pipeline.io.mcap_reader`), so the counts come from the
storage itself (metadata.yaml's counts checked against the rows read, else ``COUNT(*)`` per topic; MCAP records)
and a split bag is one recording. Per-file compression (``*.db3.zstd``, ``*.mcap.zstd``) is undone into a
temporary directory that :meth:`Rosbag2Reader.close` removes; per-message compression is undone per payload.
"""

from __future__ import annotations

import contextlib
import logging
import re
import tempfile
import warnings
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np

from pipeline.errors import IngestError
from pipeline.io.base import (
    Batch,
    Batcher,
    RawReader,
    ReadResult,
    Restart,
    Rows,
    SalvageInfo,
    TopicData,
    TopicInfo,
    stream_walk,
)
from pipeline.io.fields import TypeRegistry, normalize_msgtype
from pipeline.io.inflate import inflate_capped
from pipeline.io.mcap_reader import MAGIC as MCAP_MAGIC
from pipeline.io.mcap_reader import Damaged, salvage_info, walk

if TYPE_CHECKING:
    import sqlite3

    from pipeline.io.mcap_index import IndexedFile
    from pipeline.io.sqlite_pages import MessageRows

log = logging.getLogger(__name__)

SQLITE_MAGIC = b"SQLite format 3\x00"
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
_STORAGE = re.compile(r"\.(db3|mcap)(\.zstd)?$")


def _natural(path: Path) -> list[Any]:
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name)]


def storage_files(directory: Path) -> list[Path]:
    """Storage files of a bag directory without metadata: ``*.db3``/``*.mcap`` (maybe ``.zstd``), natural order."""
    return sorted((p for p in directory.iterdir() if p.is_file() and _STORAGE.search(p.name)), key=_natural)


def _magic(path: Path) -> bytes:
    with open(path, "rb") as fh:
        return fh.read(16)


class Rosbag2Reader(RawReader):
    """A ROS 2 bag directory (``format`` is ``ros2-sqlite3`` or ``ros2-mcap``)."""

    def __init__(self, path: str | Path, files: list[Path] | None = None) -> None:
        super().__init__(path)
        self.metadata: dict[str, Any] = {}
        meta = self.path / "metadata.yaml"
        if files is not None:
            pass
        elif meta.is_file():
            self.metadata = _load_metadata(meta)
            files = [self._locate(p) for p in self.metadata.get("relative_file_paths") or []]
        else:
            files = storage_files(self.path)
        self.compression_mode = str(self.metadata.get("compression_mode") or "").upper()
        self.compression_format = str(self.metadata.get("compression_format") or "")
        if not files:
            raise IngestError(
                "no storage files: expected metadata.yaml or *.db3 / *.mcap (optionally .zstd) files", file=self.path)
        self._tmp: tempfile.TemporaryDirectory[str] | None = None
        self._cut_streams: list[str] = []  # per-file zstd streams cut short (reported with the read)
        self._origin: dict[str, Path] = {}  # inflated temporary file -> the .zstd file it came from
        self.files = [self._plain(p) for p in files]
        kinds = {("mcap" if _magic(p).startswith(MCAP_MAGIC) else "sqlite3") for p in self.files}
        if len(kinds) != 1:
            raise IngestError(f"storage files of mixed formats: {sorted(kinds)}", file=self.path)
        self.storage = kinds.pop()
        self.format = f"ros2-{self.storage}"
        self._ids: list[dict[int, str]] = []     # per file: topic id / channel id -> topic
        self._provisional: set[str] = set()       # topics whose count is metadata.yaml's, not yet checked by a read
        self._indexes: list[IndexedFile | None] = []  # per MCAP file: its chunk indexes, when intact and indexed
        self._no_index = False
        self._row_fetch = False  # rows as tuples through the sqlite3 module (tests compare the fetches)
        self._page_fetch = True  # rows parsed from the messages table's pages (sqlite_btree), else sqlite's aggregates
        self._short: dict[str, tuple[int, int]] = {}  # topic -> (metadata.yaml's count, the storage's): rows lost
        self._pages: dict[Path, _PageSalvage] = {}  # damaged storage files read from their intact pages

    @classmethod
    def from_files(cls, files: list[Path]) -> Rosbag2Reader:
        """A single storage file (``.db3``, ``.db3.zstd``) read as a bag of one file."""
        return cls(files[0], files=list(files))

    def _locate(self, rel: str) -> Path:
        path = self.path / rel
        if not path.resolve().is_relative_to(self.path.resolve()):  # '../../etc/passwd', an absolute path
            raise IngestError(f"metadata.yaml lists storage file {rel!r} outside the bag directory; a bag's files "
                              "lie in it", file=self.path)
        for cand in (path, path.with_name(path.name + ".zstd"), path.with_name(path.name.removesuffix(".zstd"))):
            if cand.is_file():
                return cand
        raise IngestError(f"storage file {rel!r} listed in metadata.yaml is missing", file=self.path)

    def _plain(self, path: Path) -> Path:
        """Undo per-file compression (zstd) into a temporary directory."""
        if _magic(path)[:4] != ZSTD_MAGIC:
            return path

        if self._tmp is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="auvid-ros2-")
        out = Path(self._tmp.name) / path.name.removesuffix(".zstd")
        cut = inflate_capped(path, out)  # capped: a small damaged file must not fill the disk
        self._origin[str(out)] = path
        if cut is not None:
            log.warning("%s", cut)
            self._cut_streams.append(cut)
        return out

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def _decompress(self, payload: bytes, path: Path | None = None) -> bytes:
        if self.compression_mode == "MESSAGE" and self.compression_format == "zstd":
            import zstandard

            try:  # streaming: allocates what the payload inflates to, not what its header claims
                return zstandard.ZstdDecompressor().decompressobj().decompress(payload)
            except zstandard.ZstdError as err:
                raise IngestError(f"a zstd-compressed message does not decompress: {err}",
                                  file=path or self.path) from err
        return payload

    # -- scanning -------------------------------------------------------------------------------------------
    def catalog(self) -> dict[str, TopicInfo]:
        """Topics; for sqlite storage with a metadata.yaml that lists every topic's count, those counts (checked
        against the rows :meth:`read` fetches) instead of a scan of every row, and first / last unknown until read.
        """
        if self._infos is None:
            with self._named_originals():
                self._scan(quick=True)
        assert self._infos is not None
        return dict(self._infos)

    def topics(self) -> dict[str, TopicInfo]:
        if self._infos is None or self._provisional:
            with self._named_originals():
                self._scan()
        assert self._infos is not None
        return dict(self._infos)

    @contextlib.contextmanager
    def _named_originals(self) -> Iterator[None]:
        """An IngestError about a file inflated to temporary disk names the ``.zstd`` file it came from."""
        try:
            yield
        except IngestError as err:
            src = self._origin.get(err.file or "")
            if src is None:
                raise
            cut = "".join(f"; {c}" for c in self._cut_streams if c.startswith(f"{src.name}:"))
            raise IngestError(f"{err.reason} (in the storage inflated from it{cut})", file=src, topic=err.topic,
                              field=err.field) from err

    def _listed_counts(self) -> dict[str, int] | None:
        counts = {}
        for entry in self.metadata.get("topics_with_message_count") or []:
            name, want = entry["topic_metadata"].get("name"), entry.get("message_count")
            if not isinstance(name, str) or not isinstance(want, int) or want < 0:
                return None
            counts[name] = counts.get(name, 0) + want
        return counts or None

    def _scan(self, quick: bool = False) -> None:
        listed = self._listed_counts() if quick and self.storage == "sqlite3" else None
        self._types = TypeRegistry(ros1=False, user=self.user_types)
        totals: dict[str, list[Any]] = {}   # topic -> [msgtype, count, first, last, encoding]

        def add(topic: str, msgtype: str, enc: str, count: int, first: int | None, last: int | None) -> None:
            cur = totals.setdefault(topic, [msgtype, 0, None, None, enc])
            cur[1] += count
            if first is not None:
                cur[2] = first if cur[2] is None else min(cur[2], first)
            if last is not None:
                cur[3] = last if cur[3] is None else max(cur[3], last)

        self._ids, self._indexes = [], []
        for path in self.files:
            ids: dict[int, str] = {}
            if self.storage == "sqlite3":
                self._scan_sqlite(path, ids, add, stats=listed is None)
            else:
                self._scan_mcap(path, ids, add)
            self._ids.append(ids)
        if listed is not None and not set(totals) <= set(listed):
            self._scan()  # metadata.yaml does not list every topic of the storage: count the rows
            return
        self._provisional = set(totals) if listed is not None else set()
        self._infos = {}
        for topic, (msgtype, count, first, last, enc) in totals.items():
            if listed is not None:
                count = listed[topic]
            self._infos[topic] = TopicInfo(topic, msgtype, count, first, last, self._types.has_header(msgtype))
            self._encoding[topic] = "cdr" if enc.lower() == "cdr" else enc
        if listed is None:
            self._check_metadata()

    def _recount(self, topic: str, read: int, listed: int) -> int:
        if topic in self._provisional:
            self.topics()  # the exact scan; it compares every topic with metadata.yaml
        # after the exact scan (maybe done for another topic of this read) the catalog holds the storage's counts
        assert self._infos is not None
        return self._infos[topic].count if topic in self._infos else 0

    def _disagrees(self, topic: str, listed: int, have: int) -> None:
        log.warning("%s: metadata.yaml says topic %s has %s messages; the storage holds %s", self.path, topic,
                    listed, have)
        if have < listed:
            self._short[topic] = (listed, have)

    def read(self, requests: dict[str, list[str]]) -> ReadResult:
        """As :meth:`RawReader.read`; rows that metadata.yaml counts but the storage lacks (damaged sqlite pages
        drop them without an error) are a loss, reported like a salvage."""
        with self._named_originals():
            result = super().read(requests)
        short = {t: c for t, c in self._short.items() if t in result.topics}
        if short and result.salvage is None:
            lost = "; ".join(f"{t}: {have} of {listed}" for t, (listed, have) in sorted(short.items()))
            result.salvage = SalvageInfo(
                kept=sum(d.read for d in result.topics.values()), stopped_at_byte=None,
                reason=f"the storage holds fewer messages than metadata.yaml lists ({lost})")
        if self._cut_streams:  # a cut .zstd inflates without an error: say so, whatever the storage shows
            cut = "; ".join(self._cut_streams)
            result.salvage = SalvageInfo(sum(d.read for d in result.topics.values()), None, cut) \
                if result.salvage is None else replace(result.salvage, reason=f"{cut}; {result.salvage.reason}")
        return result

    def _was_read(self, topic: str, data: TopicData) -> None:
        if topic in self._provisional and self._infos is not None and data.read == self._infos[topic].count:
            info = self._infos[topic]
            first = int(data.log_ns.min()) if data.read else None
            last = int(data.log_ns.max()) if data.read else None
            self._infos[topic] = TopicInfo(topic, info.msgtype, info.count, first, last, info.has_header)
            self._provisional.discard(topic)

    def _check_metadata(self) -> None:
        assert self._infos is not None
        for entry in self.metadata.get("topics_with_message_count") or []:
            name, want = entry["topic_metadata"].get("name"), entry.get("message_count")
            have = self._infos[name].count if name in self._infos else 0
            if isinstance(want, int) and want != have:
                self._disagrees(name, want, have)

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

    def _salvage_sqlite(self, path: Path, ids: dict[int, str], err: sqlite3.DatabaseError) -> _PageSalvage:
        """Read the message rows of a damaged storage file from its intact pages (:mod:`.sqlite_pages`)."""
        from pipeline.io.sqlite_pages import SqlitePages, message_rows

        log.warning("%s: sqlite cannot read the messages table (%s); reading the rows from the intact pages",
                    path, err)
        with SqlitePages(path) as pages:
            rows = message_rows(pages, set(ids))
        damaged = f"; {rows.bad_cells} damaged cell(s) skipped" if rows.bad_cells else ""
        found = _PageSalvage(rows, f"{path.name}: {err}; kept the {len(rows.rowid)} message row(s) on intact "
                                   f"pages{damaged}")
        self._pages[path] = found
        log.warning("%s", found.reason)
        first = next(iter(self._pages.values()))
        self.salvage = SalvageInfo(  # every damaged file of a split bag
            kept=sum(len(p.rows.rowid) for p in self._pages.values()), stopped_at_byte=first.rows.cut_at,
            reason="; ".join(p.reason for p in self._pages.values()))
        return found

    def _walk_mcap(self, path: Path, on_message: Any = None, wanted: set[int] | None = None) -> Any:
        try:
            w = walk(path, on_message, wanted, tolerant=self.salvage is not None)
        except Damaged as dmg:
            if on_message is not None:
                raise IngestError(f"storage file changed while reading: {dmg}", file=path) from dmg
            log.warning("%s is damaged (%s); reading it by the salvage path", path, dmg)
            w = walk(path, None, None, tolerant=True)
            w.damage = dmg
        if w.damage is not None or w.seen.count:
            info = salvage_info(path, w)
            info.reason = f"{path.name}: {info.reason}"
            self.salvage = info
        return w

    def _scan_mcap(self, path: Path, ids: dict[int, str], add: Any) -> None:
        from pipeline.io.mcap_index import index_walk

        index = None if self._no_index or self.salvage is not None else index_walk(path)
        self._indexes.append(index)
        w = index.walk if index is not None else self._walk_mcap(path)
        for cid, ch in sorted(w.channels.items()):
            name, enc, text = w.schemas.get(ch.schema_id, ("", "", ""))
            msgtype = normalize_msgtype(name)
            if name:
                self._types.add(msgtype, enc, text)  # type: ignore[union-attr]
            ids[cid] = ch.topic
            count = w.counts.get(cid, 0)
            if w.stats_counts is not None and self.salvage is None:
                count = w.stats_counts.get(cid, count)
            add(ch.topic, msgtype, ch.encoding, count, w.first.get(cid), w.last.get(cid))

    # -- reading --------------------------------------------------------------------------------------------
    def _batches(self, topics: list[str]) -> Iterator[Batch]:
        wanted_topics = set(topics)
        for path, ids in zip(self.files, self._ids, strict=True):
            wanted = {i: t for i, t in ids.items() if t in wanted_topics}
            if not wanted:
                continue
            if self.storage == "sqlite3":
                yield from self._sqlite_batches(path, wanted)
                continue
            index = self._indexes[self.files.index(path)]
            if index is not None and self.compression_mode != "MESSAGE":
                from pipeline.io.mcap_index import chunk_batches

                try:
                    yield from chunk_batches(path, index, wanted)
                except Damaged as dmg:
                    log.warning("%s is damaged (%s); reading it by the salvage path", path, dmg)
                    self._no_index = True
                    self._infos = None
                    self._encoding = {}
                    raise Restart from dmg
                continue
            def walk_wanted(emit: Any, path: Path = path, wanted: dict[int, str] = wanted) -> None:
                def on_message(cid: int, log_ns: int, payload: bytes | None) -> None:
                    if payload is not None:
                        emit(wanted[cid], log_ns, self._decompress(payload, path))

                self._walk_mcap(path, on_message, set(wanted))

            yield from stream_walk(walk_wanted)

    def _page_batches(self, path: Path, wanted: dict[int, str]) -> Iterator[Batch]:
        """The rows of a damaged storage file, from its intact pages, in rowid order."""
        from pipeline.io.sqlite_pages import Malformed, SqlitePages, message_payloads

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
        many rows at once (:mod:`.sqlite_btree`: ~0.1 s of CPU for 912k rows), as long as they hold what that
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


def _load_metadata(meta: Path) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of a metadata.yaml, with the shapes the reader relies on checked."""
    import yaml  # here, not at the top: an MCAP file's ingest, whose configs come from a snapshot, needs no YAML

    def bad(why: str) -> IngestError:
        return IngestError(f"metadata.yaml is not a rosbag2 metadata file: {why}", file=meta)

    try:
        # libyaml's parser where PyYAML has it (~8x less CPU than the pure-Python one)
        doc = yaml.load(meta.read_text(encoding="utf-8"), Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader)) or {}
    except (yaml.YAMLError, UnicodeDecodeError, RecursionError) as err:
        raise bad(str(err)) from err
    info = doc.get("rosbag2_bagfile_information") if isinstance(doc, dict) else None
    if not isinstance(info, dict):
        raise bad("no mapping 'rosbag2_bagfile_information' at the top")
    paths = info.get("relative_file_paths") or []
    if not isinstance(paths, list) or not all(isinstance(p, str) for p in paths):
        raise bad(f"relative_file_paths must be a list of strings, found {paths!r:.200}")
    entries = info.get("topics_with_message_count") or []
    if not isinstance(entries, list) or not all(
            isinstance(e, dict) and isinstance(e.get("topic_metadata"), dict) for e in entries):
        raise bad("topics_with_message_count must be a list of mappings with a 'topic_metadata' mapping")
    return info


def _read_only_uri(path: Path) -> str:
    """The sqlite URI that opens ``path`` read-only and never writes beside it (no journal, no -wal file).

    The path is percent-encoded: a '?', '#' or '%' in a directory name would otherwise end the file name early
    and open (or create) another file.
    """
    return f"file:{quote(str(Path(path).resolve()), safe='/')}?mode=ro&immutable=1"


class _DamagedRow(Exception):
    """A row of table ``messages`` whose topic_id or timestamp is not an integer, or whose data is not a blob."""


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
    from pipeline.io.sqlite_btree import NotPlain, row_batches

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
    ~0.6 s of CPU for 912k messages against 1.1 s for the rows fetched as tuples, and no driver to import (ADBC's
    import took pyarrow.dataset and pandas along). A row whose types are not integer, integer, blob raises
    :class:`_DamagedRow`. ``after``: only the rows whose id is greater.
    """
    # A stamp or topic id that is not an integer ('soon', 1.5) is text that numpy refuses; a payload that is not a
    # blob would join unseen, so its type is counted (the one check paid per row: ~15 % of the fetch).
    aggregates = ("count(*), max(id), total(typeof(data) != 'blob'), group_concat(topic_id), "
                  "group_concat(timestamp), group_concat(length(data)), CAST(group_concat(data, '') AS BLOB)")
    limit = FIRST_BATCH_ROWS
    last = after
    while True:
        inner = _messages_sql(wanted, "id, topic_id, timestamp, data", last is not None, limit)
        row = con.execute(f"SELECT {aggregates} FROM ({inner})", () if last is None else (last,)).fetchone()
        count, last, bad, tids, stamps, lengths_text, data = row
        if not count:
            return
        if bad:
            raise _DamagedRow(f"{int(bad)} of the next {count} rows hold a payload that is not a blob")
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
    cur = con.execute(_messages_sql(wanted, "topic_id, timestamp, data", False, None))
    while True:
        rows = cur.fetchmany(BATCH_ROWS)
        if not rows:
            return
        tids, stamps, datas = zip(*rows, strict=True)
        del rows
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


class _PageSalvage:
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
