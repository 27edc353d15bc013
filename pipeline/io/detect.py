"""``open_log(path)``: choose the reader by content (magic bytes), never by extension.

Text has no magic bytes: a file none of the binary formats claims is a text table (one trial, named after the
file) when its name says text (:data:`TEXT_FILE_SUFFIXES`) and its first bytes are text (no NUL byte unless
after a UTF-16 / UTF-32 byte-order mark; or gzip). A directory of text files is one trial too.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

from pipeline.errors import IngestError
from pipeline.io.base import LogReader
from pipeline.io.mcap_records import MAGIC as MCAP_MAGIC
from pipeline.io.msgdefs import UserTypes
from pipeline.io.reader import RawReader
from pipeline.io.rosbag1_records import MAGIC as ROS1_MAGIC
from pipeline.io.rosbag2.reader import ZSTD_MAGIC, storage_files
from pipeline.io.sqlite_format import MAGIC as SQLITE_MAGIC

if TYPE_CHECKING:  # the text reader is imported where a text log is opened
    from pipeline.io.text import TextLimits

log = logging.getLogger(__name__)

TEXT_SUFFIXES = (".csv", ".tsv", ".txt", ".dat", ".csv.gz", ".tsv.gz", ".txt.gz")
#: the names a loose text table may have (what the text reader reads in a directory)
TEXT_FILE_SUFFIXES = (".csv", ".tsv", ".txt", ".dat", ".log", ".gz")
TEXT_TRIAL = (f"a text trial is one file ({', '.join(TEXT_FILE_SUFFIXES)}) or one directory of such files")
EXPECTED = (f"expected one of the magic bytes {MCAP_MAGIC!r} (MCAP), {ROS1_MAGIC!r} (ROS 1 bag), "
            f"{SQLITE_MAGIC!r} (ROS 2 sqlite3), {ZSTD_MAGIC!r} (zstd-compressed ROS 2 storage), "
            f"a directory (ROS 2 bag), or text: {TEXT_TRIAL}")
_GZIP_MAGIC = b"\x1f\x8b"
_BOMS = (b"\xff\xfe", b"\xfe\xff", b"\x00\x00\xfe\xff")  # UTF-16 LE / BE (UTF-32 LE starts as 16 LE), 32 BE
_TEXT_HEAD = 4096


def sniff(path: Path) -> str:
    """The kind of log at ``path``: mcap, ros1, ros2-dir, ros2-file, csv-dir, csv-file; IngestError if none."""
    if not path.exists():
        raise IngestError(f"no such file or directory; {EXPECTED}", file=path)
    if path.is_dir():
        if (path / "metadata.yaml").is_file() or storage_files(path):
            return "ros2-dir"
        if any(p.is_file() and p.name.lower().endswith(TEXT_SUFFIXES) for p in path.iterdir()):
            return "csv-dir"
        found = sorted(p.name for p in path.iterdir())[:20]
        raise IngestError(f"directory holds nothing readable (found {found}); {EXPECTED}", file=path)
    with open(path, "rb") as fh:
        head = fh.read(_TEXT_HEAD)
    if not head:
        raise IngestError(f"empty file (0 bytes); {EXPECTED}", file=path)
    if head.startswith(MCAP_MAGIC):
        return "mcap"
    if head.startswith(ROS1_MAGIC):
        return "ros1"
    if head.startswith(SQLITE_MAGIC) or head.startswith(ZSTD_MAGIC):
        return "ros2-file"
    if path.name.lower().endswith(TEXT_FILE_SUFFIXES):
        if head.startswith(_GZIP_MAGIC) or b"\x00" not in head or head.startswith(_BOMS):
            return "csv-file"
        raise IngestError(f"named as text but the file holds binary data (a NUL byte at {head.index(0)}, no "
                          f"byte-order mark); it starts with {head[:16]!r}; {EXPECTED}", file=path)
    raise IngestError(f"unknown format: the file starts with {head[:16]!r}; {EXPECTED}", file=path)


def open_log(path: str | Path, definitions: UserTypes | None = None, *,
             text_limits: TextLimits | None = None) -> LogReader:
    """Open any supported log; the reader lists topics and reads requested fields (:mod:`pipeline.io.base`).

    ``definitions``: the user's message definitions (:func:`pipeline.io.msgdefs.load_user_types`), used for the
    types the log does not embed. ``text_limits``: what a text file may hold (default: :class:`TextLimits`'s).
    """
    path = Path(path)
    kind = sniff(path)
    if kind in ("csv-dir", "csv-file"):
        from pipeline.io.text import open_text

        if text_limits is None:
            return open_text(path)
        return open_text(path, max_bytes=text_limits.max_bytes, max_lines=text_limits.max_lines,
                         max_line_bytes=text_limits.max_line_bytes)
    reader: RawReader
    if kind == "mcap":
        from pipeline.io.mcap_reader import McapReader

        reader = McapReader(path)
    elif kind == "ros1":
        from pipeline.io.rosbag1 import Rosbag1Reader

        reader = Rosbag1Reader(path)
    else:
        from pipeline.io.rosbag2.reader import Rosbag2Reader

        reader = Rosbag2Reader.from_files([path]) if kind == "ros2-file" else Rosbag2Reader(path)
    if definitions is not None:
        reader.use_definitions(definitions)
    return reader
