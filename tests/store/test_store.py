from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
import pytest

from pipeline.config.params import FeaturesParams
from pipeline.errors import SchemaError
from pipeline.store import FIXED_COLUMNS, PARTITIONING, assign_split, load, prune, schema_document, write_trial
from pipeline.tableio import read_meta

ROOT = Path(__file__).resolve().parents[2]


def _derived(n: int, t0_ns: int = 0, seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    frame = pd.DataFrame({"t_ns": t0_ns + np.arange(n, dtype=np.int64) * 50_000_000,
                          "segment": np.zeros(n, np.int32)})
    for name, _ in FIXED_COLUMNS[3:]:
        frame[name] = rng.normal(size=n)
    frame["depth_m"] = 1.0
    frame["n1_rpm"] = rng.normal(size=n)
    frame["T_left_N"] = rng.normal(size=n)
    return frame


def _write(root: Path, params: FeaturesParams) -> list[Path]:
    return [write_trial(root, "testbot", "trial02", _derived(30, seed=2), params, {"config_hash": "c"}),
            write_trial(root, "testbot", "01", _derived(10, t0_ns=10**9, seed=1), params, {"config_hash": "c"}),
            write_trial(root, "alpha", "7", _derived(5, seed=3), params, {"config_hash": "c"})]


def test_schema_file_is_generated_from_code() -> None:
    committed = ROOT / "schemas" / "features.schema.json"
    assert committed.exists(), "run python -m pipeline.store"
    assert json.loads(committed.read_text()) == schema_document(), "stale: run python -m pipeline.store"


def test_split_labels() -> None:
    t = np.arange(10, dtype=np.int64) * 10
    params = FeaturesParams(tuning_fraction=0.2, test_trials=["t9"])
    assert assign_split(t, "t1", params).tolist() == ["tuning"] * 2 + ["train_test"] * 8
    assert assign_split(t, "t9", params).tolist() == ["test"] * 10


def test_partition_strings_survive_and_order_is_stable(tmp_path: Path) -> None:
    paths = _write(tmp_path, FeaturesParams(tuning_fraction=0.2))
    assert paths[1] == tmp_path / "data/features/vehicle=testbot/trial=01/part-0.parquet"
    frame = load(tmp_path)
    assert list(frame.columns[:4]) == ["vehicle", "trial", "t_ns", "segment"]
    assert frame["trial"].unique().tolist() == ["7", "01", "trial02"]  # vehicle first, then trial as a string
    assert frame["vehicle"].unique().tolist() == ["alpha", "testbot"]
    assert all(isinstance(v, str) for v in frame["trial"])
    for (_, _), group in frame.groupby(["vehicle", "trial"], sort=False):
        assert group["t_ns"].is_monotonic_increasing
    one = load(tmp_path, vehicle="testbot", trials=["01"], columns=["u_mps", "split"])
    assert list(one.columns) == ["vehicle", "trial", "u_mps", "split"]
    assert len(one) == 10 and set(one["trial"]) == {"01"}
    assert one["u_mps"].to_numpy() == pytest.approx(_derived(10, seed=1)["u_mps"].to_numpy(), abs=0)
    tuning = load(tmp_path, split="tuning")
    assert tuning.groupby("trial").size().to_dict() == {"01": 2, "7": 1, "trial02": 6}


def test_test_trials_and_plain_parquet_readers(tmp_path: Path) -> None:
    _write(tmp_path, FeaturesParams(test_trials=["01"]))
    assert set(load(tmp_path, split="test")["trial"]) == {"01"}
    # pyarrow.dataset with hive partitioning reads it as plain Parquet too
    plain = ds.dataset(tmp_path / "data/features", format="parquet",
                       partitioning=ds.partitioning(PARTITIONING, flavor="hive"))
    table = plain.to_table(filter=ds.field("trial") == "01")
    assert table.num_rows == 10
    assert table.schema.field("trial").type == pa.string()
    assert set(table.column("split").to_pylist()) == {"test"}


def test_rewrite_is_byte_identical_and_carries_provenance(tmp_path: Path) -> None:
    first = [p.read_bytes() for p in _write(tmp_path, FeaturesParams())]
    second = [p.read_bytes() for p in _write(tmp_path, FeaturesParams())]
    assert first == second
    meta = read_meta(tmp_path / "data/features/vehicle=testbot/trial=01/part-0.parquet")
    assert meta["trial"] == "01" and meta["vehicle"] == "testbot" and meta["config_hash"] == "c"
    assert meta["split_counts"] == {"train_test": 8, "tuning": 2}


def test_unknown_column_and_prune(tmp_path: Path) -> None:
    bad = _derived(5).assign(mystery=1.0)
    with pytest.raises(SchemaError, match="mystery"):
        write_trial(tmp_path, "testbot", "x", bad, FeaturesParams(), {})
    _write(tmp_path, FeaturesParams())
    removed = prune(tmp_path, "testbot", ["01"])
    assert [p.name for p in removed] == ["trial=trial02"]
    assert set(load(tmp_path)["trial"]) == {"01", "7"}
    with pytest.raises(SchemaError, match="nope"):
        load(tmp_path, columns=["nope"])


def test_duckdb_and_polars_read_the_store_as_plain_parquet(tmp_path: Path) -> None:
    import duckdb
    import polars as pl

    _write(tmp_path, FeaturesParams(tuning_fraction=0.2))
    pattern = str(tmp_path / "data/features/*/*/*.parquet")
    expected = load(tmp_path, vehicle="testbot", trials=["01"])

    rows = duckdb.sql(
        f"SELECT trial, t_ns, u_mps, split FROM read_parquet('{pattern}', hive_partitioning = true, "
        "hive_types = {'vehicle': VARCHAR, 'trial': VARCHAR}) "
        "WHERE vehicle = 'testbot' AND trial = '01' ORDER BY t_ns").fetchall()
    assert [r[0] for r in rows] == ["01"] * 10  # the partition string survives, not the integer 1
    assert [r[1] for r in rows] == expected["t_ns"].tolist()
    assert [r[2] for r in rows] == expected["u_mps"].tolist()
    assert [r[3] for r in rows] == expected["split"].tolist()

    frame = (pl.scan_parquet(pattern, hive_partitioning=True, hive_schema={"vehicle": pl.String, "trial": pl.String})
             .filter((pl.col("vehicle") == "testbot") & (pl.col("trial") == "01")).sort("t_ns").collect())
    assert frame["trial"].to_list() == ["01"] * 10
    assert frame["u_mps"].to_list() == expected["u_mps"].tolist()
    assert frame["split"].to_list() == expected["split"].tolist()
