"""MCAP's record vocabulary, shared by the record walker (:mod:`.mcap_reader`) and the index reader
(:mod:`.mcap_index`): the magic, the opcodes, what a walk finds (:class:`Walk`), and a chunk's decompression with
the check that its claimed size can be true."""

from __future__ import annotations

import io
from dataclasses import dataclass, field

from pipeline.io.dedup import Seen
from pipeline.io.errors import Damaged, oversized_chunk

MAGIC = b"\x89MCAP0\r\n"
OP_HEADER, OP_FOOTER, OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06
OP_MESSAGE_INDEX, OP_STATISTICS, OP_DATA_END = 0x07, 0x0B, 0x0F


@dataclass
class Channel:
    id: int
    topic: str
    encoding: str
    schema_id: int


@dataclass
class Walk:
    """What a walk over one MCAP file found."""

    schemas: dict[int, tuple[str, str, str]] = field(default_factory=dict)  # id -> (name, encoding, text)
    channels: dict[int, Channel] = field(default_factory=dict)
    counts: dict[int, int] = field(default_factory=dict)
    first: dict[int, int] = field(default_factory=dict)
    last: dict[int, int] = field(default_factory=dict)
    stats_counts: dict[int, int] | None = None
    damage: Damaged | None = None
    kept: int = 0
    seen: Seen = field(default_factory=Seen)  # chunks and messages met twice, dropped
    private: int = 0  # records with a private opcode (0x80-0xff), skipped as the spec says; no ROS writer makes them
    private_at: int = -1


# The most a chunk can inflate: LZ4 frames at most ~255x, zstd ~32768x (a 3-byte RLE block header per 128 KiB).
_MAX_RATIO = {"": 1, "lz4": 256, "zstd": 1 << 15}


def implausible_chunk(compression: str, rlen: int, usize: int) -> str | None:
    """Why a chunk's claimed uncompressed size cannot be true for its compressed length, or None.

    Checked before anything is allocated: a damaged size field (2**40, 2**64 - 1) must not become a buffer.
    """
    too_large = oversized_chunk(usize)
    if too_large is not None:
        return too_large
    ratio = _MAX_RATIO.get(compression)
    if ratio is None:
        return None  # an unknown compression is reported where it is decompressed
    if compression == "" and usize != rlen:
        return f"uncompressed chunk claims {usize} bytes but holds {rlen}"
    if usize > ratio * rlen + 1024:
        return (f"chunk claims {usize} bytes uncompressed from {rlen} compressed ({compression} inflates at most "
                f"{ratio}x)")
    return None


def decompress(compression: str, data: bytes, size: int, *, partial: bool) -> bytes:
    """A chunk's records, inflated (``partial``: as much as a cut stream gives, for salvage, never more than the
    ``size`` the chunk claims: a cut stream has no end to check the claim against)."""
    if compression == "":
        return data
    if partial and size <= 0:
        return b""
    if compression == "zstd":
        import zstandard

        if partial:
            parts: list[bytes] = []
            with zstandard.ZstdDecompressor().stream_reader(io.BytesIO(data)) as reader:
                while size > 0 and (piece := reader.read(min(size, 1 << 20))):
                    parts.append(piece)
                    size -= len(piece)
            return b"".join(parts)
        return zstandard.ZstdDecompressor().decompress(data, max_output_size=max(size, 1))
    if compression == "lz4":
        import lz4.frame

        if partial:
            return lz4.frame.LZ4FrameDecompressor().decompress(data, max_length=size)
        return lz4.frame.decompress(data)
    raise Damaged(f"unknown chunk compression {compression!r}", 0)
