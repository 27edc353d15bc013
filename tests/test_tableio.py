from __future__ import annotations

from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipeline import SCHEMA_VERSION, __version__
from pipeline.errors import SchemaError
from pipeline.tableio import atomic_path, read_meta, read_parquet, write_parquet


def _table() -> pa.Table:
    return pa.table({"t_ns": np.arange(5, dtype=np.int64) * 50_000_000, "u_mps": np.linspace(0, 1, 5)})


def test_write_is_byte_identical_and_self_describing(tmp_path: Path) -> None:
    a = write_parquet(_table(), tmp_path / "a.parquet", {"trial": "t1", "topic": "/dvl"})
    b = write_parquet(_table(), tmp_path / "b.parquet", {"topic": "/dvl", "trial": "t1"})
    assert a.read_bytes() == b.read_bytes()
    table, meta = read_parquet(a)
    assert table.column("u_mps").to_pylist() == pytest.approx([0, 0.25, 0.5, 0.75, 1.0])
    assert meta == {"schema_version": SCHEMA_VERSION, "package_version": __version__, "trial": "t1", "topic": "/dvl"}
    assert read_meta(a)["topic"] == "/dvl"


def test_failed_write_leaves_target_untouched(tmp_path: Path) -> None:
    target = tmp_path / "out.parquet"
    write_parquet(_table(), target, {})
    before = target.read_bytes()
    with pytest.raises(RuntimeError), atomic_path(target) as tmp:
        tmp.write_bytes(b"half")
        raise RuntimeError("crash mid-write")
    assert target.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["out.parquet"]


def test_foreign_parquet_is_a_schema_error(tmp_path: Path) -> None:
    import pyarrow.parquet as pq

    pq.write_table(_table(), tmp_path / "x.parquet")
    with pytest.raises(SchemaError, match="no auvid metadata"):
        read_meta(tmp_path / "x.parquet")
