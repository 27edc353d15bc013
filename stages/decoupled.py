"""Decoupled damping stage (paper 001): feature store -> data/models/decoupled/ + data/evaluation/decoupled/.

Reads the ``tuning`` split (hyperparameter search only) and the ``train_test`` split (unshuffled k-fold CV,
learning curves, timings, final fit); ``decoupled.trials`` names, per DOF, the trials that excite it alone (paper
001's protocol; ``pipeline.sim.Controls(excite="surge")`` makes such trials), otherwise every trial is used.
Writes per (DOF, model) ``<dof>_<model>.joblib`` and its card
``<dof>_<model>.card.json`` (:mod:`pipeline.models.card`: lineage, hyperparameters, scores, versions, the pickle's
sha256), and ``metrics.json`` (deterministic),
``timings.json`` (wall-clock, varies run to run), ``curves.json``, ``table.md``, ``learning_curves.png``,
``timings.png``, ``damping.png``. Each (DOF, model) is written as soon as it finishes (its joblib and card, and
the tables so far); one that fails is logged, named in ``metrics.json`` and ``table.md`` and in the result's
quarantine list (exit code 1), and the others go on.
"""

from __future__ import annotations

import logging
import platform
from collections.abc import Callable
from pathlib import Path
from typing import Any

import joblib
import numpy as np
import sklearn

from pipeline import __version__, layout, store
from pipeline.config import Params, Vehicle, config_hash
from pipeline.decoupled import (
    ModelResult,
    StudyResult,
    damping_curves,
    dof_columns,
    plot_damping,
    plot_learning_curves,
    plot_timings,
    run_study,
    table_markdown,
)
from pipeline.errors import ModelError
from pipeline.models.card import card_path, save_model
from pipeline.models.decoupled import describe
from pipeline.tableio import atomic_path, write_json
from stages.common import StageResult, stage_main

NAME = "decoupled"
log = logging.getLogger(__name__)


def models_dir(root: Path) -> Path:
    return Path(root) / layout.MODELS / "decoupled"


def evaluation_dir(root: Path) -> Path:
    return Path(root) / layout.EVALUATION / "decoupled"


def versions() -> dict[str, str]:
    return {"auvid": __version__, "scikit-learn": sklearn.__version__, "numpy": np.__version__,
            "joblib": joblib.__version__, "python": platform.python_version()}


def write_models(study: StudyResult, root: Path, lineage: dict[str, Any]) -> list[Path]:
    """One joblib file and one card per (DOF, model); the card names the file's inputs and output."""
    out = []
    for r in study.results:
        x_col, y_col = dof_columns(r.dof)
        card = {"kind": "decoupled_damping", "dof": r.dof, "model": r.model, "inputs": [x_col], "output": y_col,
                "hyperparameters": r.best_params, "learned": describe(r.model, r.estimator),
                "search_mae": r.search_mae, "scores": r.cv, "lineage": lineage, "versions": versions()}
        # the card records the pickle's sha256: the simulate stage loads the model only through it
        out += list(save_model(r.estimator, models_dir(root) / f"{r.dof}_{r.model}.joblib", card))
    return out


def run(root: Path, vehicle: Vehicle, params: Params, progress: Callable[..., Any] | None = None) -> StageResult:
    """Learn d_i(nu_i) per DOF with LS, MLP, KRR, SVR and GP; score, time and save them. ``progress``: one unit
    per (DOF, model) finished or failed (stages.common)."""
    root = Path(root)
    p = params.decoupled
    columns = ["t_ns", "segment", "split"] + [c for d in p.dofs for c in dof_columns(d)]
    tuning = store.load(root, vehicle=vehicle.name, split="tuning", columns=columns)
    train_test = store.load(root, vehicle=vehicle.name, split="train_test", columns=columns)
    if train_test.empty or tuning.empty:
        raise ModelError(f"the feature store has {len(tuning)} tuning and {len(train_test)} train_test rows for "
                         f"vehicle {vehicle.name!r}; both are needed", file=layout.features_dir(root))
    lineage = {"vehicle": vehicle.name, "vehicle_hash": config_hash(vehicle), "params_hash": config_hash(p),
               "params": p.model_dump(), "trials": sorted(set(tuning["trial"]) | set(train_test["trial"])),
               "rows": {"tuning": len(tuning), "train_test": len(train_test)}}
    ev = evaluation_dir(root)
    outputs: list[Path] = []
    done = StudyResult([])

    n_units = len(p.dofs) * len(p.models)
    if progress is not None:
        progress(0, n_units, "searching, cross-validating")

    def finished(result: ModelResult | None, failure: dict[str, str] | None) -> None:
        """Write this (DOF, model) at once (or drop a stale file of it), then the tables of what is done."""
        if result is not None:
            done.results.append(result)
            outputs.extend(write_models(StudyResult([result]), root, lineage))
        elif failure is not None:
            done.failed.append(failure)
            stem = models_dir(root) / f"{failure['dof']}_{failure['model']}"
            for stale in (stem.with_suffix(".joblib"), card_path(stem.with_suffix(".joblib"))):
                if stale.exists():
                    log.warning("removing %s of an earlier run: %s/%s failed this time", stale, failure["dof"],
                                failure["model"])
                    stale.unlink()
        write_tables(done, lineage, ev)
        if progress is not None:
            name = f"{result.dof}/{result.model}" if result is not None else f"{failure['dof']}/{failure['model']}"
            progress(len(done.results) + len(done.failed), n_units, name)

    study = run_study(tuning, train_test, dofs=p.dofs, models=p.models, folds=p.folds, search=p.search,
                      gp_max_samples=p.gp_max_samples, max_samples=p.max_samples, curve_points=p.curve_points,
                      seed=p.seed, dof_trials=p.trials, gp_warp=p.gp_warp, on_result=finished)
    if not study.results:
        raise ModelError("every decoupled model failed: " + "; ".join(
            f"{f['dof']}/{f['model']}: {f['reason']}" for f in study.failed))
    outputs += write_tables(study, lineage, ev)
    ranges = {d: (float(train_test[dof_columns(d)[0]].min()), float(train_test[dof_columns(d)[0]].max()))
              for d in p.dofs}
    outputs.append(write_json(damping_curves(study, ranges), ev / "curves.json"))
    outputs.append(plot_learning_curves(study, ev / "learning_curves.png"))
    outputs.append(plot_timings(study.timings(), ev / "timings.png"))
    outputs.append(plot_damping(study, train_test, ev / "damping.png"))
    summary = {f"{r.dof}/{r.model}": round(r.cv["test_mae_mean"], 4) for r in study.results}
    quarantined = [{**f, "file": str(models_dir(root) / f"{f['dof']}_{f['model']}.joblib"),
                    "reason": f"model {f['dof']}/{f['model']} failed ({f['error']}): {f['reason']}"}
                   for f in study.failed]
    return StageResult(stage=NAME, outputs=outputs, quarantined=quarantined,
                       summary={"cv_test_mae": summary, "failed": [f"{f['dof']}/{f['model']}" for f in study.failed]})


def write_tables(study: StudyResult, lineage: dict[str, Any], ev: Path) -> list[Path]:
    """metrics.json (with the failed models), timings.json and table.md of what the study has so far (atomic)."""
    out = [write_json({"lineage": lineage, "results": study.metrics()}, ev / "metrics.json"),
           write_json(study.timings(), ev / "timings.json")]
    with atomic_path(ev / "table.md") as tmp:
        tmp.write_text(table_markdown(study))
    return [*out, ev / "table.md"]


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
