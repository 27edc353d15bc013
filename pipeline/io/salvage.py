"""Salvage of MCAP files and ROS 1 bags cut short (power loss) or damaged.

The readers fall back to this path by themselves when the normal walk finds damage (their
``ReadResult.salvage`` is then set). :func:`salvage` runs it on purpose: it streams the records, keeps every
complete message before the damage, and reports how many it kept and the byte offset of the first record it
could not read. A chunk that the cut went through keeps the complete messages that decompress from its head.
"""

from __future__ import annotations

import logging
from pathlib import Path

from pipeline.errors import IngestError
from pipeline.io import mcap_reader, rosbag1
from pipeline.io.base import SalvageInfo
from pipeline.io.detect import sniff

log = logging.getLogger(__name__)


def salvage(path: str | Path) -> SalvageInfo:
    """Walk a damaged MCAP file or ROS 1 bag tolerantly; say what survives and where the walk stopped."""
    path = Path(path)
    kind = sniff(path)
    if kind == "mcap":
        result = mcap_reader.walk(path, tolerant=True)
    elif kind == "ros1":
        result = rosbag1.walk(path, tolerant=True)  # type: ignore[assignment]
    else:
        raise IngestError(f"salvage reads MCAP files and ROS 1 bags, not {kind}", file=path)
    dmg = result.damage
    info = mcap_reader.salvage_info(path, result) if kind == "mcap" else \
        rosbag1.salvage_info(path, result)  # type: ignore[arg-type]
    if dmg is not None:
        log.warning("%s: salvage kept %d messages, stopped at byte %s: %s", path, info.kept, info.stopped_at_byte,
                    info.reason)
    return info


def open_salvaged(path: str | Path) -> mcap_reader.McapReader | rosbag1.Rosbag1Reader:
    """A reader that reads ``path`` by the salvage path from the start."""
    path = Path(path)
    kind = sniff(path)
    if kind == "mcap":
        reader = mcap_reader.McapReader(path)
        reader._tolerant = True  # noqa: SLF001 - same package
        return reader
    if kind == "ros1":
        bag = rosbag1.Rosbag1Reader(path)
        bag._tolerant = True  # noqa: SLF001 - same package
        bag.salvage = SalvageInfo(0, None, "salvage requested")
        return bag
    raise IngestError(f"salvage reads MCAP files and ROS 1 bags, not {kind}", file=path)
