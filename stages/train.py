"""Train and evaluate the coupled 3-DOF models: blocked CV on train_test, final check on the test trial(s).

Writes per model a joblib + model card under data/models/coupled/, and Table III (md + JSON), per-fold scores,
the Fig. 4-like box plot and metrics.json under data/evaluation/coupled/.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from urllib.parse import quote

from pipeline import store
from pipeline.config import Params, Vehicle, config_hash
from pipeline.coupled import EXPLICIT_MODELS, evaluate_models, fold_boxplot, model_inputs, table3
from pipeline.errors import ModelError
from pipeline.layout import EVALUATION, MODELS, features_dir
from pipeline.models.card import lineage, save_model
from pipeline.tableio import atomic_path, write_json
from stages.common import StageResult, stage_main
from stages.tune import hyperparameters_path

log = logging.getLogger(__name__)
NAME = "train"


def run(root: Path, vehicle: Vehicle, params: Params) -> StageResult:
    """Blocked CV, final check, models with cards, tables and figures (coupled study, paper 000)."""
    root = Path(root)
    cp = params.coupled
    hp = hyperparameters_path(root)
    if not hp.exists() and any(m not in EXPLICIT_MODELS for m in cp.models):
        raise ModelError("no tuned hyperparameters; run stages.tune first", file=hp)
    hyper = json.loads(hp.read_text())["hyperparameters"] if hp.exists() else {}
    cols = ["t_ns", *sorted({c for m in cp.models for c in model_inputs(m, cp)} | set(cp.outputs))]
    tt = store.load(root, vehicle=vehicle.name, split="train_test", columns=cols)
    te = store.load(root, vehicle=vehicle.name, split="test", columns=cols)
    tuning_keys = store.load(root, vehicle=vehicle.name, split="tuning", columns=["t_ns"])
    results = evaluate_models(tt, te, hyper, cp, tuning_keys=tuning_keys[["trial", "t_ns"]], n_jobs=cp.n_jobs)

    files = sorted(features_dir(root).glob(f"vehicle={quote(vehicle.name, safe='')}/trial=*/part-0.parquet"))
    data_lineage = lineage(files, root)
    out_models, out_eval = root / MODELS / "coupled", root / EVALUATION / "coupled"
    outputs: list[Path] = []
    for model, res in results.items():
        card = {"model": model, "study": "coupled 3-DOF (paper 000)", "vehicle": vehicle.name,
                "inputs": model_inputs(model, cp), "outputs": cp.outputs,
                "hyperparameters": hyper.get(model, {"solver": "tls"}), "seed": cp.seed,
                "params_hash": config_hash(cp), "data_lineage": data_lineage,
                "trained_on": {"split": "train_test", "rows": len(tt), "trials": sorted(tt["trial"].unique())},
                "scores": {"cv": res["summary"], "final_check": res["final"],
                           "final_check_trials": sorted(te["trial"].unique())}}
        if hasattr(res["estimator"], "coefficients"):
            card["coefficients"] = res["estimator"].coefficients()
        outputs += list(save_model(res["estimator"], out_models / f"{model}.joblib", card))
    md, doc = table3(results, cp.outputs)
    with atomic_path(out_eval / "table3.md") as tmp:
        tmp.write_text(md)
    folds = {m: [{k: v for k, v in f.items() if not k.endswith("time_s")} for f in r["folds"]]
             for m, r in results.items()}
    timings = {m: {"fit_time_s": [f["fit_time_s"] for f in r["folds"]]} for m, r in results.items()}
    metrics = {m: {out: {"cv_test_r2": s["test_r2"]["mean"], "cv_test_r2_sd": s["test_r2"]["sd"],
                         "final_r2": (r["final"] or {}).get(out, {}).get("r2")}
                   for out, s in r["summary"].items()} for m, r in results.items()}
    outputs += [out_eval / "table3.md", write_json(doc, out_eval / "table3.json"),
                write_json(folds, out_eval / "fold_scores.json"), write_json(timings, out_eval / "timings.json"),
                write_json(metrics, out_eval / "metrics.json")]
    fold_boxplot(results, cp.outputs, out_eval / "fold_test_r2.png")
    outputs.append(out_eval / "fold_test_r2.png")
    return StageResult(NAME, outputs=outputs, summary={"metrics": metrics})


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
