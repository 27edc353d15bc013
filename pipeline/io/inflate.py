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


_ZSTD_MAGIC = 0xFD2FB528
_SKIPPABLE = 0x184D2A50  # ... 0x184D2A5F


def frames(src: Path) -> tuple[int | None, int | None]:
    """(the content size the zstd frames of ``src`` claim in all, None if a frame does not say; the offset where
    the stream is cut short, None if its last frame is whole), from the frame and block headers alone.

    zstandard inflates a cut stream without an error; the headers say whether the last frame ended."""
    total: int | None = 0
    with open(src, "rb") as fh:
        size = fh.seek(0, 2)
        pos = 0
        while pos < size:
            fh.seek(pos)
            head = fh.read(18)
            if len(head) < 4:
                return total, pos
            magic = int.from_bytes(head[:4], "little")
            if magic & 0xFFFFFFF0 == _SKIPPABLE:
                if len(head) < 8:
                    return total, pos
                pos += 8 + int.from_bytes(head[4:8], "little")
                continue
            if magic != _ZSTD_MAGIC or len(head) < 6:
                return total, pos  # not a frame where one should start: the decoder reports the damage
            desc = head[4]
            fcs_flag, single, checksum, dict_flag = desc >> 6, desc >> 5 & 1, desc >> 2 & 1, desc & 3
            fcs_size = (1 if single else 0, 2, 4, 8)[fcs_flag]
            at = 5 + (0 if single else 1) + (0, 1, 2, 4)[dict_flag]
            if len(head) < at + fcs_size:
                return total, pos
            if fcs_size and total is not None:
                content = int.from_bytes(head[at:at + fcs_size], "little") + (256 if fcs_size == 2 else 0)
                total += content
            else:
                total = None
            block = pos + at + fcs_size
            while True:
                fh.seek(block)
                raw = fh.read(3)
                if len(raw) < 3:
                    return total, pos
                bh = int.from_bytes(raw, "little")
                last, kind, bsize = bh & 1, bh >> 1 & 3, bh >> 3
                block += 3 + (1 if kind == 1 else bsize)
                if block > size:
                    return total, pos
                if last:
                    break
            pos = block + 4 * checksum
            if pos > size:
                return total, pos - 4 * checksum
    return total, None


def inflate_capped(src: Path, out: Path) -> str | None:
    """Decompress the zstd file ``src`` into ``out``, never writing more than :func:`inflate_cap` allows; what
    to report when the stream is cut short (it inflates to what its whole blocks hold), else None.

    The sizes that frame headers claim are checked against the cap and the free space before anything is
    written; a stream that inflates past the cap stops there (the partial output is removed). Both are
    IngestErrors naming the file, the size and the cap; so is a full disk.
    """
    import zstandard

    compressed = src.stat().st_size
    cap = inflate_cap(compressed)
    why = f"at most {INFLATE_RATIO}x its {compressed} bytes or {INFLATE_FLOOR_BYTES} bytes"
    claimed, cut = frames(src)
    if claimed is not None:
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
    if cut is None:
        return None
    return (f"{src.name}: zstd stream cut short (the frame at byte {cut} does not end before the file does, at "
            f"byte {compressed}; zstd inflates whole blocks of up to 128 KiB)")
