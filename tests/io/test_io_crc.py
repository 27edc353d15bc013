"""The CRC-32 the readers check MCAP chunks with: zlib's values whichever implementation computes them (ISA-L's when
the optional package ``isal`` is installed), for every bytes-like object the readers pass."""

from __future__ import annotations

import mmap
import zlib
from pathlib import Path

import numpy as np
import pytest

from pipeline.io.dedup import crc


def test_crc_is_zlibs_on_every_buffer_the_readers_pass(tmp_path: Path) -> None:
    data = np.random.default_rng(0).integers(0, 256, 1 << 16, dtype=np.uint8)
    raw = data.tobytes()
    for part in (raw, memoryview(raw)[5:999], data[7:40_000], data[:0], b"123456789"):
        assert crc(part) == zlib.crc32(part)
    assert crc(b"123456789") == 0xCBF43926  # the CRC-32 check value
    path = tmp_path / "f"
    path.write_bytes(raw)
    with open(path, "rb") as fh, mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as mm:
        assert crc(mm) == zlib.crc32(raw)


def test_isal_when_installed_gives_zlibs_values() -> None:
    isal_zlib = pytest.importorskip("isal.isal_zlib")
    data = np.random.default_rng(1).integers(0, 256, 1 << 20, dtype=np.uint8)
    assert isal_zlib.crc32(data[3:]) == zlib.crc32(data[3:])
