"""Per-file compression of a ROS 2 bag (``*.db3.zstd``, ``*.mcap.zstd``) undone to temporary disk, with a cap.

A bag compresses a few times, never a thousand; a damaged or hostile 67-KB file can inflate to GiBs and fill
a small temporary directory. :func:`inflate_capped` writes at most :func:`inflate_cap` bytes (no parameter to
set: ``max(INFLATE_FLOOR_BYTES, INFLATE_RATIO * compressed size)``), checks a size that a frame header claims
against the cap and the free space before writing anything, and turns a full disk into an IngestError.
"""

from __future__ import annotations

import errno
import shutil
from pathlib import Path

from pipeline.errors import IngestError

# Per-file compression is undone to temporary disk, at most max(INFLATE_FLOOR_BYTES, INFLATE_RATIO * compressed
# size): a bag compresses a few times, never a thousand, while a damaged or hostile 67-KB file can inflate to GiBs.
INFLATE_RATIO = 1024
INFLATE_FLOOR_BYTES = 256 << 20
_PIECE = 1 << 20


def inflate_cap(compressed: int) -> int:
    """The most bytes a zstd-compressed storage file of ``compressed`` bytes may inflate to on disk."""
    return max(INFLATE_FLOOR_BYTES, INFLATE_RATIO * compressed)


def inflate_capped(src: Path, out: Path) -> None:
    """Decompress the zstd file ``src`` into ``out``, never writing more than :func:`inflate_cap` allows.

    A size claimed by a frame header is checked against the cap and the free space before anything is written;
    a stream that inflates past the cap stops there (the partial output is removed). Both are IngestErrors naming
    the file, the size and the cap; so is a full disk.
    """
    import zstandard

    compressed = src.stat().st_size
    cap = inflate_cap(compressed)
    why = f"at most {INFLATE_RATIO}x its {compressed} bytes or {INFLATE_FLOOR_BYTES} bytes"
    with open(src, "rb") as fh:
        head = fh.read(18)
    try:
        claimed = zstandard.get_frame_parameters(head).content_size
    except zstandard.ZstdError as err:
        raise IngestError(f"zstd file compression does not decompress: {err}", file=src) from err
    if claimed != zstandard.CONTENTSIZE_UNKNOWN:
        if claimed > cap:
            raise IngestError(f"zstd file compression claims {claimed} bytes uncompressed; the cap is {cap} "
                              f"({why})", file=src)
        free = shutil.disk_usage(out.parent).free
        if claimed > free:
            raise IngestError(f"zstd file compression claims {claimed} bytes uncompressed; the temporary directory "
                              f"{out.parent} has {free} bytes free", file=src)
    written = 0
    try:
        with open(src, "rb") as fh, open(out, "wb") as dst, \
                zstandard.ZstdDecompressor().stream_reader(fh, read_across_frames=True) as reader:
            while piece := reader.read(_PIECE):
                written += len(piece)
                if written > cap:
                    raise IngestError(f"zstd file compression inflates past the cap of {cap} bytes ({why}); "
                                      f"stopped after {written} bytes", file=src)
                dst.write(piece)
    except zstandard.ZstdError as err:
        out.unlink(missing_ok=True)
        raise IngestError(f"zstd file compression does not decompress: {err}", file=src) from err
    except OSError as err:
        out.unlink(missing_ok=True)
        if err.errno not in (errno.ENOSPC, errno.EDQUOT):
            raise  # file-system errors other than a full disk pass through
        raise IngestError(f"cannot inflate the zstd file into {out.parent}: {err}", file=src) from err
    except IngestError:
        out.unlink(missing_ok=True)
        raise
