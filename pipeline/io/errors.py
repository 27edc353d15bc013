"""The exceptions that pass between io's modules (readers, indexes, page parsers); none leaves the package.

What reaches a caller is :class:`pipeline.errors.IngestError`; these say, inside io, why a reader changes path:
damage found (:class:`Damaged`, then :class:`Restart` on the salvage path), pages the vectorized sqlite read
does not take (:class:`NotPlain`), a damaged sqlite cell (:class:`Malformed`).
"""

from __future__ import annotations

#: The most a chunk (MCAP, ROS 1) may claim uncompressed: writers make chunks of 0.75 to 4 MiB (rosbag's 768 KiB,
#: the mcap writers' 1 MiB, rosbag2's 4 MiB); a larger claim is a damaged size field or a bomb, reported as
#: :class:`Damaged` before anything is allocated or inflated.
MAX_CHUNK_BYTES = 256 << 20


def oversized_chunk(usize: int) -> str | None:
    """Why a chunk's claimed uncompressed size is refused, or None."""
    if usize > MAX_CHUNK_BYTES:
        return (f"chunk claims {usize} bytes uncompressed, more than the {MAX_CHUNK_BYTES >> 20} MiB a chunk may "
                "hold")
    return None


class Damaged(Exception):
    """The file is damaged at byte ``at``."""

    def __init__(self, reason: str, at: int) -> None:
        super().__init__(f"{reason} at byte {at}")
        self.reason = reason
        self.at = at


class Restart(Exception):
    """The reader found damage while reading and switched to its salvage path; read again from the start."""


class NotPlain(Exception):
    """Something on the pages that the vectorized read does not take; sqlite should read the rest."""


class Malformed(Exception):
    """A cell or record that the file's bytes cannot hold."""
