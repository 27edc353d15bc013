"""Train and evaluate the coupled 3-DOF models: blocked CV on train_test, final check on the test trial(s).

Writes per model a joblib + model card under data/models/coupled/, and Table III (md + JSON), per-fold scores and
metrics.json under data/evaluation/coupled/ (the report draws Fig. 4, the folds' box plot, from the scores). Each
model's files and its rows of the tables are written as soon as that model finishes; a model that fails is logged,
named in Table III and metrics.json (``{model: {"failed": reason}}``) and in the result's quarantine list (exit code
1), and the others go on (a stale joblib of it from an earlier run is removed, so the simulate stage cannot pick
it up).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any
from urllib.parse import quote

from pipeline import store
from pipeline.config import Params, Vehicle, coupled_skip_reason
from pipeline.config.params import EXPLICIT_MODELS
from pipeline.errors import ModelError
from pipeline.layout import EVALUATION, MODELS, features_dir
from pipeline.models.card import card_path, lineage, save_model
from pipeline.report.coupled import table3
from pipeline.skips import clear_skip
from pipeline.studies.coupled import rigid_body_uvr, train_columns
from pipeline.studies.training import train_stage
from pipeline.tableio import atomic_path, remove_stale_temps, write_json
from stages.common import StageResult, skipped_result, stage_main
from stages.tune import hyperparameters_path

log = logging.getLogger(__name__)
NAME = "train"


def run(root: Path, vehicle: Vehicle, params: Params, progress: Callable[..., Any] | None = None) -> StageResult:
    """Blocked CV, final check, models with cards, tables and figures (coupled study, paper 000). ``progress``:
    CV folds and final fits (stages.common). Skipped, as the tune stage, on a vehicle without the study's DOFs."""
    root = Path(root)
    directories = [root / MODELS / "coupled", root / EVALUATION / "coupled"]
    for directory in directories:
        remove_stale_temps(directory)
    reason = coupled_skip_reason(vehicle, params)
    if reason is not None:
        return skipped_result(NAME, directories, ("tune", "train"), reason)
    clear_skip(directories)
    cp = params.coupled
    hp = hyperparameters_path(root)
    if not hp.exists() and any(m not in EXPLICIT_MODELS for m in cp.models):
        raise ModelError("no tuned hyperparameters; run stages.tune first", file=hp)
    tuned = json.loads(hp.read_text()) if hp.exists() else {}
    if tuned and tuned.get("tuning", "split") != cp.tuning and any(m not in EXPLICIT_MODELS for m in cp.models):
        raise ModelError(f"hyperparameters were tuned with coupled.tuning={tuned.get('tuning', 'split')!r}, params "
                         f"now say {cp.tuning!r}; run stages.tune again", file=hp)
    hyper = tuned.get("hyperparameters", {})
    cols = train_columns(cp, set(store.dataset(root).schema.names))
    tt = store.load(root, vehicle=vehicle.name, split="train_test", columns=cols)
    te = store.load(root, vehicle=vehicle.name, split="test", columns=cols)
    tuning_keys = store.load(root, vehicle=vehicle.name, split="tuning", columns=["t_ns"])
    files = sorted(features_dir(root).glob(f"vehicle={quote(vehicle.name, safe='')}/trial=*/part-0.parquet"))
    data_lineage = lineage(files, root)
    out_models, out_eval = root / MODELS / "coupled", root / EVALUATION / "coupled"
    saved: dict[str, list[Path]] = {}
    results: dict[str, Any] = {}
    failed: dict[str, dict[str, str]] = {}

    def in_order(by_model: dict[str, Any]) -> dict[str, Any]:  # models finish in any order on several workers
        return {m: by_model[m] for m in cp.models if m in by_model}

    def finished(model: str, res: dict[str, Any] | None, card: dict[str, Any] | None) -> None:
        """Write this model's joblib + card (or drop a stale one if it failed) and the tables so far."""
        target = out_models / f"{model}.joblib"
        if res is None:
            for stale in (target, card_path(target)):
                if stale.exists():
                    log.warning("removing %s of an earlier run: %s failed this time", stale, model)
                    stale.unlink()
        else:
            results[model] = res
            saved[model] = save_model(res["estimator"], target, card)
        write_tables(in_order(results), in_order(failed), cp.outputs, out_eval)

    train_stage(tt, te, tuning_keys, hyper, cp, vehicle=vehicle.name, data_lineage=data_lineage, failures=failed,
                on_model=finished, progress=progress, rigid_body_mass=rigid_body_uvr(vehicle.rigid_body))
    results, failed = in_order(results), in_order(failed)
    (out_eval / "fold_test_r2.png").unlink(missing_ok=True)  # an older version's Fig. 4: the report draws it now
    outputs = [path for paths in in_order(saved).values() for path in paths]
    outputs += write_tables(results, failed, cp.outputs, out_eval)
    quarantined = [{**entry, "file": str(out_models / f"{model}.joblib"),
                    "reason": f"model {model!r} failed ({entry['error']}): {entry['reason']}"}
                   for model, entry in failed.items()]
    return StageResult(NAME, outputs=outputs, quarantined=quarantined,
                       summary={"metrics": metrics(results, failed), "failed": sorted(failed)})


def write_tables(results: dict[str, Any], failed: dict[str, dict[str, str]], outputs: list[str],
                 out_eval: Path) -> list[Path]:
    """Table III, per-fold scores, timings and metrics.json of the models finished so far (atomic rewrites)."""
    md, doc = table3(results, outputs, failed)
    with atomic_path(out_eval / "table3.md") as tmp:
        tmp.write_text(md)
    folds = {m: [{k: v for k, v in f.items() if not k.endswith("time_s")} for f in r["folds"]]
             for m, r in results.items()}
    timings = {m: {"fit_time_s": [f["fit_time_s"] for f in r["folds"]]} for m, r in results.items()}
    return [out_eval / "table3.md", write_json(doc, out_eval / "table3.json"),
            write_json(folds, out_eval / "fold_scores.json"), write_json(timings, out_eval / "timings.json"),
            write_json(metrics(results, failed), out_eval / "metrics.json")]


def metrics(results: dict[str, Any], failed: dict[str, dict[str, str]]) -> dict[str, Any]:
    """metrics.json: per model and output the CV test R² (mean, SD) and the final check's, the 90 % interval's
    typical half-width and its share of the test trials' targets inside; the failed models' reasons."""
    out: dict[str, Any] = {
        m: {o: {"cv_test_r2": s["test_r2"]["mean"], "cv_test_r2_sd": s["test_r2"]["sd"],
                "final_r2": (r["final"] or {}).get(o, {}).get("r2"),
                "interval_half_width": (r.get("interval") or {}).get(o, {}).get("half_width"),
                "final_interval_coverage": (r["final"] or {}).get(o, {}).get("interval_coverage")}
            for o, s in r["summary"].items()}
        for m, r in results.items()}
    out.update({m: {"failed": f"{e['error']}: {e['reason']}"} for m, e in failed.items()})
    return out


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
