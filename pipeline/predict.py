"""``auvid predict``'s work: predictions of loaded models (:mod:`pipeline.api`) on a table, or on a log that is first
run through ingest -> sync -> differentiate -> derive with the run's configs in a temporary directory.

The table needs, per model, the velocity columns of its DOFs (``u_mps`` ...) and its inputs: a coupled model's
card inputs (thruster speeds or ``tau_*``); a decoupled model's ``tau_*`` columns, from which the restoring
forces are subtracted as the damping balance does — from the ``g_*`` columns where the table has them (a derived
table does), else from ``roll_rad`` / ``pitch_rad`` and the vehicle config, else taken as zero (logged).

The output has ``t_ns`` and ``trial`` where the input has them, the measured accelerations where present, and per
model ``<model>/<output>`` (``ls/udot_mps2``) plus ``<model>/<output>/lower`` and ``/upper`` for a model with a
band (a coupled model's 90 % interval, a GP set's +- 2 sd: :attr:`pipeline.api.Model.interval_kind`). A row
whose inputs are not all finite is NaN. Parquet (with provenance) or CSV, written atomically.
"""

from __future__ import annotations

import logging
import shutil
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from pipeline import layout, physics
from pipeline.api import Model
from pipeline.config import Params, Vehicle
from pipeline.errors import PipelineError
from pipeline.tableio import atomic_path, write_parquet
from pipeline.vocabulary import DOFS, VELOCITY_COLUMNS, acceleration_column

log = logging.getLogger(__name__)

__all__ = ["PredictError", "derive_log", "predict_frame", "write_predictions", "OUTPUT_SUFFIXES"]

OUTPUT_SUFFIXES = (".parquet", ".csv")
_STAGES = ("ingest", "sync", "differentiate", "derive")


class PredictError(PipelineError):
    """The input cannot give predictions: a column a model needs is missing, a log that no stage could read."""


def _inputs(model: Model, frame: pd.DataFrame, source: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(nu, tau)`` of ``model`` from the table's columns; PredictError names the missing column."""
    states = [VELOCITY_COLUMNS[d] for d in model.dofs]
    needed = states + list(model.inputs)
    missing = [c for c in needed if c not in frame.columns]
    if missing:
        raise PredictError(f"column {missing[0]!r} (needed by model {model.name!r}: {needed}) is not in the table; "
                           f"available: {sorted(frame.columns)}", file=source, field=missing[0])
    nu = frame[states].to_numpy(float)
    tau = frame[list(model.inputs)].to_numpy(float)
    if model.kind == "decoupled":
        g_cols = [c.replace("tau_", "g_", 1) for c in model.inputs]
        if all(c in frame.columns for c in g_cols):
            tau = tau - frame[g_cols].to_numpy(float)
        elif {"roll_rad", "pitch_rad"} <= set(frame.columns) and model.vehicle is not None:
            g = physics.restoring_force(model.vehicle, frame["roll_rad"].to_numpy(float),
                                        frame["pitch_rad"].to_numpy(float))
            tau = tau - g[:, [DOFS.index(d) for d in model.dofs]]
        else:
            log.warning("%s: no g_* nor roll/pitch columns: restoring forces taken as zero for model %s", source,
                        model.name)
    return nu, tau


def predict_frame(models: Mapping[str, Model], frame: pd.DataFrame, source: str | Path = "<table>") -> pa.Table:
    """Every model's predictions on ``frame``'s rows (see the module's doc for the columns)."""
    columns: dict[str, Any] = {}
    if "t_ns" in frame.columns:
        columns["t_ns"] = pa.array(frame["t_ns"].to_numpy(np.int64), pa.int64())
    if "trial" in frame.columns:
        columns["trial"] = pa.array(frame["trial"].astype(str).tolist(), pa.string())
    prepared = {name: _inputs(m, frame, source) for name, m in models.items()}  # every column checked first
    for d in DOFS:
        acc = acceleration_column(d)
        if acc in frame.columns and any(d in m.dofs for m in models.values()):
            columns[acc] = frame[acc].to_numpy(float)
    for name, model in models.items():
        nu, tau = prepared[name]
        ok = np.isfinite(nu).all(axis=1) & np.isfinite(tau).all(axis=1)
        pred = np.full(nu.shape, np.nan)
        lo = hi = None
        if ok.any():
            nudot, lower, upper = model.predict(nu[ok], tau[ok], interval=True)
            pred[ok] = nudot
            if lower is not None:
                lo, hi = np.full(nu.shape, np.nan), np.full(nu.shape, np.nan)
                lo[ok], hi[ok] = lower, upper
        for j, out in enumerate(model.outputs):
            columns[f"{name}/{out}"] = pred[:, j]
            if lo is not None and hi is not None:
                columns[f"{name}/{out}/lower"], columns[f"{name}/{out}/upper"] = lo[:, j], hi[:, j]
    return pa.table(columns)


def derive_log(log_path: Path, vehicle: Vehicle, params: Params,
               progress_factory: Callable[[str], Any] | None = None,
               on_stage: Callable[[str, Any, float], None] | None = None) -> pd.DataFrame:
    """The derived table of one log: ingest -> sync -> differentiate -> derive in a temporary run directory
    (removed afterwards), serially. PredictError naming the log when a stage quarantines it or writes nothing."""
    import time

    from stages import common

    work = Path(tempfile.mkdtemp(prefix="auvid-predict-"))
    try:
        raw = work / layout.RAW
        raw.mkdir(parents=True)
        target = raw / log_path.name
        target.symlink_to(log_path.resolve(), target_is_directory=log_path.is_dir())
        for stage in _STAGES:
            progress = progress_factory(stage) if progress_factory else None
            if on_stage is not None:
                on_stage(stage, None, 0.0)
            start = time.perf_counter()
            try:
                result = common.run_stage(stage, work, vehicle, params, progress=progress, fan_out=False,
                                          **({"logs": [target]} if stage == "ingest" else {}))
            finally:
                if progress is not None and hasattr(progress, "close"):
                    progress.close()
            if on_stage is not None:
                on_stage(stage, result, time.perf_counter() - start)
            if result.quarantined:
                reasons = "; ".join(str(q.get("reason")) for q in result.quarantined)
                raise PredictError(f"{stage} quarantined the log: {reasons}", file=log_path)
        tables = sorted((work / layout.DERIVED).glob("*.parquet"))
        if not tables:
            raise PredictError("derive wrote no table for this log", file=log_path)
        frame = pd.concat([pq.read_table(p).to_pandas().assign(trial=p.stem) for p in tables], ignore_index=True)
        return frame
    finally:
        shutil.rmtree(work, ignore_errors=True)


def write_predictions(table: pa.Table, target: str | Path, provenance: dict[str, Any]) -> Path:
    """Parquet (with ``provenance`` in its metadata) or CSV, by ``target``'s suffix; atomically."""
    target = Path(target)
    if target.suffix.lower() == ".csv":
        with atomic_path(target) as tmp:
            pacsv.write_csv(table, tmp)
        return target
    if target.suffix.lower() != ".parquet":
        raise PredictError(f"unknown output format {target.suffix!r}; use one of {list(OUTPUT_SUFFIXES)}", file=target)
    return write_parquet(table, target, provenance)
