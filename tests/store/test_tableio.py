from __future__ import annotations

import errno
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pytest

from pipeline import SCHEMA_VERSION, __version__
from pipeline.errors import SchemaError
from pipeline.tableio import atomic_path, read_meta, read_parquet, write_json, write_parquet


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


def test_every_column_type_comes_back_bit_for_bit(tmp_path: Path) -> None:
    """Byte-stream-split floats and delta-packed integers give back the same bits: NaN payloads, -0.0, the
    smallest subnormal, the integer extremes (deltas that overflow), nulls; other types stay plain."""
    i64, u64 = np.iinfo(np.int64), np.iinfo(np.uint64)
    payload_nan = np.array([0x7FF8_0000_0000_1234], dtype=np.uint64).view(np.float64)[0]
    floats = np.array([payload_nan, -0.0, np.inf, -np.inf, 5e-324, 1.0, -2.5])
    table = pa.table({
        "t_ns": pa.array([i64.min, i64.max, 0, i64.min, -1, None, 7], pa.int64()),
        "n": pa.array([u64.max, 0, u64.max, 2**63, 1, None, 3], pa.uint64()),
        "k": pa.array([-128, 127, None, 0, -1, 5, 6], pa.int8()),
        "x": pa.array(floats),
        "y": pa.array(floats.astype(np.float32)),
        "stamp": pa.array([1, None, i64.max, -5, 0, 2, 3], pa.timestamp("ns")),
        "ok": pa.array([True, None, False, True, True, False, True]),
        "name": pa.array(["a", None, "c", "", "e", "f", "g"]),
        "v": pa.array([[1.0], [2.0, 3.0], None, [], [4.0], [5.0], [6.0]], pa.list_(pa.float64())),
    })
    path = write_parquet(table, tmp_path / "all.parquet", {})
    back, _ = read_parquet(path)
    assert back.schema.remove_metadata() == table.schema
    for name in ("x", "y"):
        want, got = table[name].to_numpy(), back[name].to_numpy()
        assert got.view(np.uint8).tobytes() == want.view(np.uint8).tobytes(), name
    for name in ("t_ns", "n", "k", "stamp", "ok", "name", "v"):
        assert back[name].equals(table[name]), name

    import pyarrow.parquet as pq

    meta = pq.ParquetFile(path).metadata.row_group(0)
    encodings = {meta.column(i).path_in_schema: meta.column(i).encodings for i in range(meta.num_columns)}
    assert "BYTE_STREAM_SPLIT" in encodings["x"] and "BYTE_STREAM_SPLIT" in encodings["y"]
    assert all("DELTA_BINARY_PACKED" in encodings[c] for c in ("t_ns", "n", "k", "stamp"))
    assert all("PLAIN" in encodings[c] for c in ("ok", "name", "v.list.element"))


def test_sensor_streams_take_fewer_bytes_than_plain_encoding(tmp_path: Path) -> None:
    """A ten-minute 120 Hz IMU-like stream (clock stamps with jitter, noisy smooth signals): the encodings cut
    the file well below what the same compression gives on plain-encoded columns."""
    import pyarrow.parquet as pq

    rng = np.random.default_rng(7)
    n = 72_000
    t_ns = np.arange(n, dtype=np.int64) * 8_333_333 + rng.integers(-20_000, 20_000, n)
    phase = 2 * np.pi * 0.1 * t_ns / 1e9
    table = pa.table({"t_ns": t_ns, "r_radps": 0.3 * np.sin(phase) + rng.normal(0, 1e-3, n),
                      "ax_mps2": 0.05 * np.cos(phase) + rng.normal(0, 2e-2, n)})
    ours = write_parquet(table, tmp_path / "ours.parquet", {})
    pq.write_table(table, tmp_path / "plain.parquet", compression="zstd", compression_level=1, use_dictionary=False)
    assert ours.stat().st_size < 0.8 * (tmp_path / "plain.parquet").stat().st_size


def _disk_full(*_args: object, **_kwargs: object) -> None:
    raise OSError(errno.ENOSPC, "No space left on device")  # as a write(2) reports it: no file name


def test_a_full_disk_names_the_file_being_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    target = tmp_path / "data" / "evaluation" / "metrics.json"
    write_json({"old": 1}, target)
    monkeypatch.setattr(Path, "write_text", _disk_full)
    with pytest.raises(OSError) as info:
        write_json({"new": 2}, target)
    assert info.value.errno == errno.ENOSPC and info.value.filename == str(target)
    assert "No space left on device" in str(info.value) and str(target) in str(info.value)
    monkeypatch.undo()
    assert json.loads(target.read_text()) == {"old": 1} and sorted(p.name for p in target.parent.iterdir()) == [
        "metrics.json"]


def test_arrow_s_disk_full_error_names_the_parquet_file(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import pyarrow.parquet as pq

    def arrow_full(*_args: object, **_kwargs: object) -> None:
        raise OSError("[Errno 28] Error writing bytes to file. Detail: [errno 28] No space left on device")

    monkeypatch.setattr(pq, "write_table", arrow_full)
    target = tmp_path / "t.parquet"
    with pytest.raises(OSError, match="No space left on device") as info:
        write_parquet(_table(), target, {"stage": "test"})
    assert info.value.filename == str(target) and list(tmp_path.iterdir()) == []


def test_the_cli_says_which_file_the_full_disk_stopped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    from pipeline import cli
    from tests.cli.helpers import FakeDag, make_run_dir

    dag = FakeDag().install(monkeypatch)
    root = make_run_dir(tmp_path)
    target = root / "data" / "evaluation" / "coupled" / "table2.json"

    def tune(root: Path, vehicle: object, params: object) -> object:
        write_json({"hyperparameters": {}}, target)
        raise AssertionError("unreachable")

    dag.modules["tune"].run = tune
    monkeypatch.setattr(Path, "write_text", _disk_full)
    code = cli.main(["tune", "--root", str(root), "--vehicle", str(root / "vehicle.yaml"), "-q"])
    monkeypatch.undo()
    assert code == 3
    err = capsys.readouterr().err
    assert "No space left on device" in err and str(target) in err
