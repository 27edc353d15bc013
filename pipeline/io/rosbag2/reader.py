"""ROS 2 bags: a directory of sqlite3 or MCAP storage files, with or without ``metadata.yaml``.

Storage is read directly (the sqlite ``messages`` table parsed from its b-tree pages, or fetched in bulk through
sqlite: :mod:`.storage_sqlite3`; MCAP records walked or read by their indexes: :mod:`.storage_mcap`), so the counts
come from the storage itself (metadata.yaml's counts checked against the rows read, else ``COUNT(*)`` per topic;
MCAP records) and a split bag is one recording. Per-file compression (``*.db3.zstd``, ``*.mcap.zstd``) is undone
into a temporary directory that :meth:`Rosbag2Reader.close` removes; per-message compression is undone per payload.
"""

from __future__ import annotations

import contextlib
import logging
import re
import tempfile
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.errors import IngestError
from pipeline.io.base import Batch, ReadResult, SalvageInfo, TopicData, TopicInfo
from pipeline.io.fields import TypeRegistry
from pipeline.io.inflate import inflate_capped
from pipeline.io.mcap_records import MAGIC as MCAP_MAGIC
from pipeline.io.reader import RawReader
from pipeline.io.rosbag2.storage_mcap import McapStorage
from pipeline.io.rosbag2.storage_sqlite3 import Sqlite3Storage

if TYPE_CHECKING:
    from pipeline.io.mcap_index import IndexedFile
    from pipeline.io.rosbag2.storage_sqlite3 import PageSalvage

log = logging.getLogger(__name__)

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



class Rosbag2Reader(Sqlite3Storage, McapStorage, RawReader):
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
        self._pages: dict[Path, PageSalvage] = {}  # damaged storage files read from their intact pages

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


    # -- reading --------------------------------------------------------------------------------------------
    def _batches(self, topics: list[str]) -> Iterator[Batch]:
        wanted_topics = set(topics)
        for path, ids in zip(self.files, self._ids, strict=True):
            wanted = {i: t for i, t in ids.items() if t in wanted_topics}
            if not wanted:
                continue
            if self.storage == "sqlite3":
                yield from self._sqlite_batches(path, wanted)
            else:
                yield from self._mcap_batches(path, wanted)


def _load_metadata(meta: Path) -> dict[str, Any]:
    """``rosbag2_bagfile_information`` of a metadata.yaml, with the shapes the reader relies on checked."""
    import yaml  # here, not at the top: an MCAP file's ingest, whose configs come from a snapshot, needs no YAML

    def bad(why: str) -> IngestError:
        return IngestError(f"metadata.yaml is not a rosbag2 metadata file: {why}", file=meta)

    try:
        # libyaml's parser where PyYAML has it (far less CPU than the pure-Python one)
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
