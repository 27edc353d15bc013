"""Tune the coupled 3-DOF SVR models: best hyperparameters per model and output + trace, searched on the train_test
block (``coupled.tuning: nested``) or the tuning split (``split``)."""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pipeline import store
from pipeline.config import Params, Vehicle
from pipeline.coupled import NOISE_STD_COLUMNS, model_inputs, table2, tune
from pipeline.layout import EVALUATION, MODELS
from pipeline.tableio import atomic_path, write_json
from stages.common import StageResult, stage_main

log = logging.getLogger(__name__)
NAME = "tune"


def hyperparameters_path(root: Path) -> Path:
    return Path(root) / MODELS / "coupled" / "hyperparameters.json"


def run(root: Path, vehicle: Vehicle, params: Params, progress: Callable[..., Any] | None = None) -> StageResult:
    """Search SVR hyperparameters (coupled study, paper 000): on the train_test block, the rows the final models
    are fitted on (``coupled.tuning: nested``, the default), or on the tuning split (``split``, the papers').
    ``progress``: each search's candidates (stages.common)."""
    cp = params.coupled
    block = "train_test" if cp.tuning == "nested" else "tuning"
    cols = sorted({c for m in cp.models for c in model_inputs(m, cp)} | set(cp.inputs) | set(cp.outputs))
    # a gray box's base is weighted by the smoother's SDs here as in train, so its residual is the one tuned on
    available = set(store.dataset(root).schema.names)
    cols += [c for c in NOISE_STD_COLUMNS if c in available]
    frame = store.load(root, vehicle=vehicle.name, split=block, columns=[*cols, "split"])
    hyper, trace = tune(frame, cp, n_jobs=cp.n_jobs, split=block, progress=progress)
    out_eval = Path(root) / EVALUATION / "coupled"
    doc = {"vehicle": vehicle.name, "search": cp.search, "seed": cp.seed, "inputs": cp.inputs,
           "outputs": cp.outputs, "tuning": cp.tuning, "tuned_on": block, "n_tuning_rows": len(frame),
           "hyperparameters": hyper}
    outputs = [write_json(doc, hyperparameters_path(root)), write_json(trace, out_eval / "search_trace.json"),
               write_json(hyper, out_eval / "table2.json")]
    with atomic_path(out_eval / "table2.md") as tmp:
        tmp.write_text(table2(hyper, cp.outputs, cp.inputs))
    outputs.append(out_eval / "table2.md")
    fits = sum(r["n_fits"] for per in trace.values() for r in per.values())
    return StageResult(NAME, outputs=outputs, summary={"n_tuning_rows": len(frame), "svr_fits": fits})


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
