"""Decoupled damping stage (paper 001): feature store -> data/models/decoupled/ + data/evaluation/decoupled/.

Reads the ``tuning`` split (hyperparameter search only) and the ``train_test`` split (unshuffled k-fold CV,
learning curves, timings, final fit); ``decoupled.trials`` names, per DOF, the trials that excite it alone (paper
001's protocol; ``pipeline.sim.Controls(excite="surge")`` makes such trials), otherwise every trial is used.
Writes per (DOF, model) ``<dof>_<model>.joblib`` and its card ``<dof>_<model>.card.json``
(:mod:`pipeline.models.card`: lineage, hyperparameters, scores, versions, the pickle's sha256), and ``metrics.json``
(deterministic), ``timings.json`` (wall-clock, varies run to run), ``curves.json``, ``table.md``,
``learning_curves.png``, ``timings.png``, ``damping.png``. Each card and ``metrics.json`` hold the model's 90 %
prediction interval (``interval``: split conformal on the blocked CV's out-of-fold residuals) and, where the store
has a test split, its coverage there (``test``; the GP's 2-sigma band too; nothing is chosen on it). Each (DOF,
model) is written as soon as it finishes (its joblib and card, and the tables so far); one that fails is logged,
named in ``metrics.json`` and ``table.md`` and in the result's quarantine list (exit code 1), and the others go on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pipeline import layout, store
from pipeline.config import Params, Vehicle
from pipeline.errors import ModelError
from pipeline.models.card import card_path, save_model
from pipeline.report.decoupled import plot_damping, plot_learning_curves, plot_timings, table_markdown
from pipeline.studies.decoupled import ModelResult, StudyResult, decoupled_stage, run_lineage, stage_columns
from pipeline.tableio import atomic_path, remove_stale_temps, write_json
from stages.common import StageResult, stage_main

NAME = "decoupled"
log = logging.getLogger(__name__)


def models_dir(root: Path) -> Path:
    return Path(root) / layout.MODELS / "decoupled"


def evaluation_dir(root: Path) -> Path:
    return Path(root) / layout.EVALUATION / "decoupled"


def run(root: Path, vehicle: Vehicle, params: Params, progress: Callable[..., Any] | None = None) -> StageResult:
    """Learn d_i(nu_i) per DOF with LS, MLP, KRR, SVR and GP; score, time and save them. ``progress``: one unit
    per (DOF, model) finished or failed (stages.common)."""
    root = Path(root)
    for directory in (models_dir(root), evaluation_dir(root)):
        remove_stale_temps(directory)
    p = params.decoupled
    columns = stage_columns(p, store.dataset(root).schema.names)
    tuning = store.load(root, vehicle=vehicle.name, split="tuning", columns=columns)
    train_test = store.load(root, vehicle=vehicle.name, split="train_test", columns=columns)
    # the unseen trials: only the intervals' coverage is measured on them, nothing is chosen
    test = store.load(root, vehicle=vehicle.name, split="test", columns=columns)
    if train_test.empty or tuning.empty:
        raise ModelError(f"the feature store has {len(tuning)} tuning and {len(train_test)} train_test rows for "
                         f"vehicle {vehicle.name!r}; both are needed", file=layout.features_dir(root))
    lineage = run_lineage(vehicle, p, tuning, train_test)
    ev = evaluation_dir(root)
    saved: dict[tuple[str, str], tuple[Path, ...]] = {}
    done = StudyResult([])

    n_units = len(p.dofs) * len(p.models)
    if progress is not None:
        progress(0, n_units, "searching, cross-validating")

    def finished(result: ModelResult | None, failure: dict[str, str] | None, card: dict[str, Any] | None) -> None:
        """Write this (DOF, model) and its card at once (or drop a stale file of it), then the tables of what is
        done."""
        if result is not None:
            done.results.append(result)
            target = models_dir(root) / f"{result.dof}_{result.model}.joblib"
            # the card records the pickle's sha256: the simulate stage loads the model only through it
            saved[result.dof, result.model] = save_model(result.estimator, target, card)
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

    study, curves = decoupled_stage(tuning, train_test, p, lineage=lineage, on_result=finished,
                                    test=None if test.empty else test)
    # in the study's order: the (DOF, model) units finish in any order on several workers
    outputs = [path for r in study.results for path in saved[r.dof, r.model]]
    outputs += write_tables(study, lineage, ev)
    outputs.append(write_json(curves, ev / "curves.json"))
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
