"""The MCAP storage of a ROS 2 bag: each file's topics from its chunk indexes when intact, else from a record
walk (:mod:`pipeline.io.mcap_reader`, salvaging a damaged file), and its batches by the same two paths."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pipeline.errors import IngestError
from pipeline.io.base import Batch, SalvageInfo, stream_walk
from pipeline.io.errors import Damaged, Restart
from pipeline.io.fields import TypeRegistry, normalize_msgtype
from pipeline.io.mcap_reader import salvage_info, walk

if TYPE_CHECKING:
    from pipeline.io.mcap_index import IndexedFile

log = logging.getLogger(__name__)


class McapStorage:
    """The MCAP half of :class:`pipeline.io.rosbag2.reader.Rosbag2Reader` (a mixin: the reader holds the state
    and undoes per-message compression, ``_decompress``)."""

    files: list[Path]
    salvage: SalvageInfo | None
    compression_mode: str
    _types: TypeRegistry | None
    _infos: dict[str, Any] | None
    _encoding: dict[str, str]
    _indexes: list[IndexedFile | None]
    _no_index: bool

    def _walk_mcap(self, path: Path, on_message: Any = None, wanted: set[int] | None = None) -> Any:
        try:
            w = walk(path, on_message, wanted, tolerant=self.salvage is not None)
        except Damaged as dmg:
            if on_message is not None:
                raise IngestError(f"storage file changed while reading: {dmg}", file=path) from dmg
            log.warning("%s is damaged (%s); reading it by the salvage path", path, dmg)
            w = walk(path, None, None, tolerant=True)
            w.damage = dmg
        if w.damage is not None or w.seen.count or w.private:
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

    def _mcap_batches(self, path: Path, wanted: dict[int, str]) -> Iterator[Batch]:
        """The wanted channels' payloads of one MCAP storage file: by its chunk indexes, else by a record walk."""
        index = self._indexes[self.files.index(path)]
        if index is not None and self.compression_mode != "MESSAGE":
            from pipeline.io.mcap_index import chunk_batches, private_records

            try:
                yield from chunk_batches(path, index, wanted)
            except Damaged as dmg:
                log.warning("%s is damaged (%s); reading it by the salvage path", path, dmg)
                self._no_index = True
                self._infos = None
                self._encoding = {}
                raise Restart from dmg
            if private_records(index):  # skipped, as the spec says, and reported as the record walk does
                info = salvage_info(path, index.walk)
                info.reason = f"{path.name}: {info.reason}"
                self.salvage = info
            return
        def walk_wanted(emit: Any, path: Path = path, wanted: dict[int, str] = wanted) -> None:
            def on_message(cid: int, log_ns: int, payload: bytes | None) -> None:
                if payload is not None:
                    emit(wanted[cid], log_ns, self._decompress(payload, path))

            self._walk_mcap(path, on_message, set(wanted))

        yield from stream_walk(walk_wanted)

