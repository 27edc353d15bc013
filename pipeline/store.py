"""The feature store: derived tables of all trials as one hive-partitioned Parquet dataset.

Layout: ``data/features/vehicle=<vehicle>/trial=<trial>/part-0.parquet`` (names percent-encoded, which
pyarrow, DuckDB and Polars decode). The partition columns are not stored in the files; readers take them
from the path **as strings** (``trial=01`` stays "01": :data:`PARTITIONING` is explicit). Each file holds
``t_ns``, ``segment``, ``split`` and the derived columns, rows in ``t_ns`` order, written by
:func:`pipeline.tableio.write_parquet` (atomic, byte-identical for identical inputs) with provenance
(sources and their sha256, config and params hashes) in its metadata.

``split``: trials in ``features.test_trials`` are ``test``; otherwise rows in the first
``tuning_fraction`` of the trial's time span (first to last kept sample) are ``tuning``, the rest
``train_test``.

The columns are described by ``schemas/features.schema.json``, generated from :func:`schema_document`
(``python -m pipeline.store [DIR]``); :func:`features_table` checks every table against it before writing.
"""

from __future__ import annotations

import json
import logging
import re
import shutil
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.parquet as pq

from pipeline import SCHEMA_VERSION
from pipeline.config.params import FeaturesParams
from pipeline.derive import derived_columns
from pipeline.errors import ConfigError, SchemaError
from pipeline.layout import features_dir
from pipeline.tableio import write_parquet
from pipeline.vocabulary import (
    ACCELERATION,
    ATTITUDE,
    DOFS,
    SMOOTH,
    VELOCITY,
    accel_std_column,
    cov_column,
    force_columns,
    meas_column,
    std_column,
)

if TYPE_CHECKING:
    from pipeline.config.vehicle import Vehicle

log = logging.getLogger(__name__)

PARTITIONING = pa.schema([("vehicle", pa.string()), ("trial", pa.string())])
SPLITS = ("tuning", "train_test", "test")
PART_FILE = "part-0.parquet"
SCHEMA_FILE = "features.schema.json"

_TERMS = ("tau", "Mnudot", "Cnu", "g", "d")
FIXED_COLUMNS: list[tuple[str, pa.DataType]] = (
    [("t_ns", pa.int64()), ("segment", pa.int32()), ("split", pa.string())]
    + [(c, pa.float64()) for c in (*VELOCITY, *SMOOTH, *ACCELERATION, *ATTITUDE)]
    + [(c, pa.float64()) for prefix in _TERMS for c in force_columns(prefix)]
)
OPTIONAL_COLUMNS: list[tuple[str, pa.DataType]] = [("depth_m", pa.float64())]
PATTERN_COLUMNS: list[tuple[str, pa.DataType, str]] = [
    (r"^T_[A-Za-z0-9_\-]+_N$", pa.float64(), "thrust of one thruster (T_<thruster>_N)"),
    (r"^[A-Za-z0-9_]+_rpm$", pa.float64(), "propeller speed signal of one thruster"),
    (r"^[uvwpqr]_smooth_std_(mps|radps)$", pa.float64(), "SD of the smoothed velocity (kalman method)"),
    (r"^[uvwpqr]dot_std_(mps2|radps2)$", pa.float64(), "SD of the estimated acceleration (kalman method)"),
    (r"^[uvwpqr]_[uvwpqr]dot_cov_(m2ps3|rad2ps3)$", pa.float64(),
     "covariance of the smoothed velocity and the acceleration of one DOF (kalman method; 0 for the grid methods)"),
    (r"^[uvwpqr]_meas_(mps|radps)$", pa.float64(),
     "measured velocity on the grid, NaN where none (kalman method; u_mps ... are then the estimate)"),
    (r"^d_std_[uvwpqr]_(N|Nm)$", pa.float64(), "first-order SD of the damping target (kalman method)"),
]
INPUT_COLUMNS_DOC = (
    "The vehicle config's actuator and control-input signals (Vehicle.actuator_signals(): each thruster's speed, "
    "PWM or thrust signal, each control surface's angle), named as in the config with their unit suffix; the "
    "features stage passes them, so a rudder angle reaches the learned models.")


def schema_document() -> dict[str, Any]:
    """The JSON description of the feature store (what ``schemas/features.schema.json`` holds)."""
    return {
        "title": "auvid feature store",
        "schema_version": SCHEMA_VERSION,
        "layout": "data/features/vehicle=<vehicle>/trial=<trial>/" + PART_FILE,
        "partitioning": {"flavor": "hive", "segment_encoding": "uri",
                         "fields": [{"name": f.name, "type": str(f.type)} for f in PARTITIONING]},
        "row_order": ["vehicle", "trial", "t_ns"],
        "splits": list(SPLITS),
        "columns": [{"name": n, "type": str(t)} for n, t in FIXED_COLUMNS],
        "optional_columns": [{"name": n, "type": str(t)} for n, t in OPTIONAL_COLUMNS],
        "pattern_columns": [{"pattern": p, "type": str(t), "description": d} for p, t, d in PATTERN_COLUMNS],
        "input_columns": {"type": "double", "description": INPUT_COLUMNS_DOC},
    }


def store_columns(vehicle: Vehicle, method: str) -> list[str]:
    """The columns every partition of the store holds, known from the vehicle config and ``differentiate.method``
    before any stage runs (no data read): the kinematics table (velocities, smoothed velocities, accelerations,
    their SDs and covariances, the measured velocities, attitude, ``depth_m`` if configured, the actuator
    signals), then what the derive stage adds. A test runs the example's stages and compares; ``auvid run`` checks
    ``coupled.inputs`` / ``outputs`` against it before its first stage."""
    kalman = method == "kalman"
    cols = ["t_ns", "segment", "split", *VELOCITY, *SMOOTH, *ACCELERATION]
    if kalman:  # the smoother's SDs (the grid filters give none)
        cols += [std_column(d) for d in DOFS] + [accel_std_column(d) for d in DOFS]
    cols += [cov_column(d) for d in DOFS]
    if kalman:
        cols += [meas_column(d) for d in DOFS]
    cols += ATTITUDE + (["depth_m"] if vehicle.sensors.depth is not None else []) + vehicle.actuator_signals()
    cols += derived_columns(vehicle)
    if kalman:  # derive's first-order SD of the damping target, from the smoother's SDs
        cols += force_columns("d_std")
    return cols


def write_schema(directory: str | Path = "schemas") -> Path:
    target = Path(directory) / SCHEMA_FILE
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_text(json.dumps(schema_document(), indent=2, sort_keys=True) + "\n")
    return target


def _column_type(name: str) -> pa.DataType | None:
    for n, t in (*FIXED_COLUMNS, *OPTIONAL_COLUMNS):
        if n == name:
            return t
    for pattern, t, _ in PATTERN_COLUMNS:
        if re.match(pattern, name):
            return t
    return None


def check_test_trials(params: FeaturesParams, derived: Sequence[str], seen: Iterable[str] = ()) -> list[str]:
    """The test trials that have a derived table. Every name in ``features.test_trials`` must be a trial of the run:
    one with a derived table (``derived``) or one the run has seen and quarantined earlier (``seen``: ingested or
    raw); a name matching neither is a ConfigError listing the trials (a ROS 2 bag directory ``trial_test_ros2``
    is trial ``trial_test_ros2``, not ``trial_test``). A seen but quarantined test trial is a warning: the final
    check runs without it."""
    seen = set(seen)
    unknown = [t for t in params.test_trials if t not in derived and t not in seen]
    if unknown:
        raise ConfigError(f"features.test_trials names {unknown}, which match no trial of this run; its trials: "
                          f"{sorted(set(derived) | seen)}", field="features.test_trials")
    for name in params.test_trials:
        if name not in derived:
            log.warning("features: test trial %s has no derived table (quarantined before features); the final "
                        "check runs without it", name)
    return [t for t in params.test_trials if t in derived]


def assign_split(t_ns: np.ndarray, trial: str, params: FeaturesParams) -> np.ndarray:
    """Split label per row: ``test`` for test trials, else ``tuning`` for the first fraction of the time span."""
    t = np.asarray(t_ns, dtype=np.int64)
    if trial in params.test_trials:
        return np.full(len(t), "test", dtype=object)
    if len(t) == 0:
        return np.empty(0, dtype=object)
    start, end = int(t.min()), int(t.max())
    cut = start + params.tuning_fraction * (end - start)
    return np.where(t < cut, "tuning", "train_test").astype(object)


def features_table(derived: pd.DataFrame, trial: str, params: FeaturesParams, inputs: Sequence[str] = ()
                   ) -> pa.Table:
    """The table stored for one trial: t_ns, segment, split, the derived columns; checked against the schema.
    ``inputs``: the vehicle's actuator and control-input signals (input columns of the schema); each must be
    present."""
    frame = derived.sort_values("t_ns", kind="mergesort").reset_index(drop=True) if "t_ns" in derived else derived
    missing = [n for n, _ in FIXED_COLUMNS if n != "split" and n not in frame.columns]
    if missing:
        raise SchemaError(f"derived table of trial {trial!r} lacks {missing}", field=missing[0])
    missing = [n for n in inputs if n not in frame.columns]
    if missing:
        raise SchemaError(f"derived table of trial {trial!r} lacks the configured input signal(s) {missing}",
                          field=missing[0])
    arrays: dict[str, pa.Array] = {
        "t_ns": pa.array(frame["t_ns"].to_numpy(dtype=np.int64), pa.int64()),
        "segment": pa.array(frame["segment"].to_numpy(dtype=np.int32), pa.int32()),
        "split": pa.array(list(assign_split(frame["t_ns"].to_numpy(), trial, params)), pa.string()),
    }
    for name in frame.columns:
        if name in arrays:
            continue
        if name in ("vehicle", "trial"):
            raise SchemaError(f"column {name!r} is a partition key and cannot be a data column", field=name)
        kind = pa.float64() if name in inputs else _column_type(name)
        if kind is None:
            raise SchemaError(f"column {name!r} of trial {trial!r} is not in {SCHEMA_FILE} "
                              "(fixed, optional or pattern columns)", field=name)
        arrays[name] = pa.array(frame[name].to_numpy(dtype=np.float64), kind)
    return pa.table(arrays)


def partition_dir(root: str | Path, vehicle: str, trial: str) -> Path:
    return features_dir(Path(root)) / f"vehicle={quote(vehicle, safe='')}" / f"trial={quote(trial, safe='')}"


def write_trial(root: str | Path, vehicle: str, trial: str, derived: pd.DataFrame, params: FeaturesParams,
                provenance: dict[str, Any], inputs: Sequence[str] = ()) -> Path:
    """Write one trial's partition atomically; returns the file written (``inputs``: see :func:`features_table`)."""
    table = features_table(derived, trial, params, inputs)
    counts = {s: int(n) for s, n in zip(*np.unique(table.column("split").to_numpy(zero_copy_only=False),
                                                   return_counts=True), strict=True)}
    meta = {"vehicle": vehicle, "trial": trial, "features_schema": SCHEMA_FILE, "split_counts": counts,
            **provenance}
    target = partition_dir(root, vehicle, trial) / PART_FILE
    write_parquet(table, target, meta)
    log.debug("features: %s/%s, %d rows %s", vehicle, trial, table.num_rows, counts)
    return target


def prune(root: str | Path, vehicle: str, keep: Iterable[str]) -> list[Path]:
    """Remove this vehicle's partitions of trials not in ``keep`` (trials whose derived table is gone)."""
    base = partition_dir(root, vehicle, "x").parent
    wanted = {f"trial={quote(t, safe='')}" for t in keep}
    removed = []
    if base.is_dir():
        for child in sorted(base.iterdir()):
            if child.is_dir() and child.name.startswith("trial=") and child.name not in wanted:
                shutil.rmtree(child)
                removed.append(child)
    return removed


def _files(base: Path) -> list[Path]:
    return sorted(base.glob(f"vehicle=*/trial=*/{PART_FILE}"))


def dataset(root: str | Path) -> ds.Dataset:
    """The store as a pyarrow dataset with string partition columns and the union of the files' schemas."""
    base = features_dir(Path(root))
    files = _files(base)
    if not files:
        raise SchemaError("the feature store is empty (run the features stage)", file=base)
    schema = pa.unify_schemas([pq.read_schema(f).remove_metadata() for f in files] + [PARTITIONING])
    return ds.dataset([str(f) for f in files], schema=schema, format="parquet",
                      partitioning=ds.partitioning(PARTITIONING, flavor="hive"), partition_base_dir=str(base))


def _as_list(value: str | Iterable[str] | None) -> list[str] | None:
    if value is None:
        return None
    return [value] if isinstance(value, str) else list(value)


def load(root: str | Path, vehicle: str | Iterable[str] | None = None, trials: str | Iterable[str] | None = None,
         split: str | Iterable[str] | None = None, columns: list[str] | None = None) -> pd.DataFrame:
    """Rows of the store as a DataFrame in stable (vehicle, trial, t_ns) order, partition columns as strings.

    ``columns``: the data columns wanted (``vehicle`` and ``trial`` always come first); None: all.
    """
    data = dataset(root)
    splits = _as_list(split)
    if splits is not None and set(splits) - set(SPLITS):
        raise ValueError(f"unknown split(s) {sorted(set(splits) - set(SPLITS))}; expected {SPLITS}")
    condition = None
    for name, values in (("vehicle", _as_list(vehicle)), ("trial", _as_list(trials)), ("split", splits)):
        if values is not None:
            term = ds.field(name).isin(values)
            condition = term if condition is None else condition & term
    names = list(data.schema.names) if columns is None else list(columns)
    unknown = [c for c in names if c not in data.schema.names]
    if unknown:
        raise SchemaError(f"column(s) {unknown} not in the feature store; available: {data.schema.names}",
                          field=unknown[0])
    wanted = ["vehicle", "trial"] + [c for c in names if c not in ("vehicle", "trial")]
    read = wanted + ([] if "t_ns" in wanted else ["t_ns"])
    table = data.to_table(columns=read, filter=condition)
    frame = table.to_pandas()
    frame = frame.sort_values(["vehicle", "trial", "t_ns"], kind="mergesort").reset_index(drop=True)
    return frame[wanted]


if __name__ == "__main__":
    import sys

    print(write_schema(sys.argv[1] if len(sys.argv) > 1 else "schemas"))
