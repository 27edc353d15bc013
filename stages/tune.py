"""Tune the coupled 3-DOF SVR models: best hyperparameters per model and output + trace, searched on the train_test
block (``coupled.tuning: nested``) or the tuning split (``split``)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pipeline import layout, store
from pipeline.config import Params, Vehicle, coupled_skip_reason
from pipeline.layout import EVALUATION, MODELS
from pipeline.report.coupled import table2
from pipeline.skips import clear_skip
from pipeline.studies.coupled import model_inputs, rigid_body_uvr, tune_columns, tune_stage, tuning_block
from pipeline.studies.coverage import study_coverage
from pipeline.tableio import atomic_path, remove_stale_temps, write_json
from stages.common import StageResult, skipped_result, stage_main

log = logging.getLogger(__name__)
NAME = "tune"


def hyperparameters_path(root: Path) -> Path:
    return Path(root) / MODELS / "coupled" / "hyperparameters.json"


def run(root: Path, vehicle: Vehicle, params: Params, progress: Callable[..., Any] | None = None) -> StageResult:
    """Search SVR hyperparameters (coupled study, paper 000): on the train_test block, the rows the final models
    are fitted on (``coupled.tuning: nested``, the default), or on the tuning split (``split``, the papers').
    ``progress``: each search's candidates (stages.common). A vehicle without the study's DOFs (a heave-only ROV)
    skips it: :func:`pipeline.config.coupled_skip_reason`, :mod:`pipeline.skips`."""
    directories = [Path(root) / MODELS / "coupled", Path(root) / EVALUATION / "coupled"]
    for directory in directories:
        remove_stale_temps(directory)
    reason = coupled_skip_reason(vehicle, params)
    if reason is not None:
        return skipped_result(NAME, directories, ("tune", "train"), reason)
    clear_skip(directories)
    cp = params.coupled
    coverage = write_json(_coverage(root, vehicle, params), layout.coverage_path(root))
    columns = tune_columns(cp, set(store.dataset(root).schema.names))
    frame = store.load(root, vehicle=vehicle.name, split=tuning_block(cp), columns=columns)
    doc, trace = tune_stage(frame, cp, vehicle=vehicle.name, progress=progress,
                            rigid_body_mass=rigid_body_uvr(vehicle.rigid_body))
    hyper = doc["hyperparameters"]
    out_eval = Path(root) / EVALUATION / "coupled"
    outputs = [coverage, write_json(doc, hyperparameters_path(root)),
               write_json(trace, out_eval / "search_trace.json"), write_json(hyper, out_eval / "table2.json")]
    with atomic_path(out_eval / "table2.md") as tmp:
        tmp.write_text(table2(hyper, cp.outputs, cp.inputs))
    outputs.append(out_eval / "table2.md")
    fits = sum(r["n_fits"] for per in trace.values() for r in per.values())
    return StageResult(NAME, outputs=outputs, summary={"n_tuning_rows": len(frame), "svr_fits": fits})


def _coverage(root: Path, vehicle: Vehicle, params: Params) -> dict[str, Any]:
    """Extrapolation and excitation diagnostics before any model is trained: each test trial's rows against the
    train_test rows (those the final models are fitted on), on every configured model's inputs that the store has
    (a missing one is the tune's error to report)."""
    available = set(store.dataset(root).schema.names)
    inputs = {m: [c for c in model_inputs(m, params.coupled) if c in available] for m in params.coupled.models}
    columns = sorted({c for cols in inputs.values() for c in cols})
    frame = store.load(root, vehicle=vehicle.name, split=["train_test", "test"],
                       columns=["split", "t_ns", *columns])
    return study_coverage(frame[frame["split"] == "train_test"], frame[frame["split"] == "test"], inputs)


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
