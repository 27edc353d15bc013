"""A candidate against the version it would replace, model by model: ``auvid retrain`` writes the current
version's scores into the candidate's run (:func:`write_baseline`, ``data/evaluation/baseline.json``) before the
stages run, and the report shows, per output and model, the current score, the candidate's and which is better.

The scores compared are those the two runs share a meaning for: each coupled model's R² on the holdout (the
train stage's metrics.json, Table III's final check; retraining keeps the holdout fixed; a model whose train R²
is below 0 there loses) and each damping model's CV test MAE per DOF.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from pipeline import layout
from pipeline.report import html as H
from pipeline.report import verdicts
from pipeline.tableio import write_json

log = logging.getLogger(__name__)

BASELINE = f"{layout.EVALUATION}/baseline.json"
OUTPUT_LABELS = {"udot_mps2": "u̇ [m/s²]", "vdot_mps2": "v̇ [m/s²]", "rdot_radps2": "ṙ [rad/s²]"}


def _load(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def scores(root: Path) -> list[dict[str, Any]]:
    """Every comparable score of a run: ``{"output", "model", "score", "metric", "higher_is_better",
    "failed"}`` (failed: train R² below 0 there)."""
    root = Path(root)
    out: list[dict[str, Any]] = []
    t3 = _load(root / layout.EVALUATION / "coupled" / "table3.json")
    t3 = t3 if isinstance(t3, dict) else {}
    coupled = _load(root / layout.EVALUATION / "coupled" / "metrics.json")  # what retraining scores too
    for model, per_output in sorted(coupled.items()) if isinstance(coupled, dict) else []:
        for output, f in sorted(per_output.items()) if isinstance(per_output, dict) else []:
            r2 = verdicts.number(f.get("final_r2")) if isinstance(f, dict) else None
            if r2 is not None:
                out.append({"output": output, "model": model, "score": r2, "metric": "R² on the holdout",
                            "higher_is_better": True,
                            "failed": verdicts.coupled_train_failed(t3.get(model), output)})
    dec = _load(root / layout.EVALUATION / "decoupled" / "metrics.json")
    results = dec.get("results") if isinstance(dec, dict) else None
    for dof, per_model in sorted(results.items()) if isinstance(results, dict) else []:
        for model, r in sorted(per_model.items()) if isinstance(per_model, dict) else []:
            mae = verdicts.number(((r.get("cv") or {}) if isinstance(r, dict) else {}).get("test_mae_mean"))
            if mae is not None:
                out.append({"output": f"d_{dof}", "model": model, "score": mae, "metric": "CV test MAE",
                            "higher_is_better": False, "failed": verdicts.damping_train_failed(r)})
    return out


def write_baseline(run_root: Path, current_dir: Path, version: str) -> Path:
    """Record the current version's scores (its run under ``current_dir``) in the candidate's run."""
    return write_json({"version": version, "scores": scores(current_dir)}, Path(run_root) / BASELINE)


def rows(baseline: list[dict[str, Any]], candidate: list[dict[str, Any]], version: str) -> list[dict[str, Any]]:
    """Per output and model: the current score, the candidate's, and which is better (a failed model loses)."""
    old = {(s["output"], s["model"]): s for s in baseline}
    new = {(s["output"], s["model"]): s for s in candidate}
    out = []
    for key in sorted(set(old) | set(new)):
        a, b = old.get(key), new.get(key)
        if a is None or b is None:
            better = "candidate (new model)" if a is None else f"{version} (not in the candidate)"
        elif a["failed"] != b["failed"]:
            better = f"{version} (candidate failed)" if b["failed"] else "candidate (current failed)"
        elif a["score"] == b["score"]:
            better = "same"
        else:
            higher = (a or b)["higher_is_better"]
            better = "candidate" if (b["score"] > a["score"]) == higher else version
        s = a or b
        out.append({"output": OUTPUT_LABELS.get(key[0], key[0]), "model": verdicts.label(key[1]),
                    "score": s["metric"] + ("" if s["higher_is_better"] else " (lower is better)"),
                    f"current ({version})": None if a is None else a["score"],
                    "candidate": None if b is None else b["score"], "better": better})
    return out


def section(root: Path) -> str:
    """The comparison's table, or "" when the run is not a retraining candidate (no baseline)."""
    doc = _load(Path(root) / BASELINE)
    if not isinstance(doc, dict) or not isinstance(doc.get("scores"), list):
        return ""
    version = str(doc.get("version") or "current")
    table = rows(doc["scores"], scores(root), version)
    wins = sum(r["better"].startswith("candidate") for r in table)
    losses = sum(r["better"].startswith(version) for r in table)
    return ("<h3>Candidate against the current version</h3>"
            + H.table(table, caption=f"This run is a retraining candidate: each model's score beside the current "
                                     f"version {version}'s, on the same holdout; the candidate is better on {wins} "
                                     f"and worse on {losses} of {len(table)} (a model failed on its training rows "
                                     "loses); promotion is decided on the holdout score (docs/retraining.md)"))
