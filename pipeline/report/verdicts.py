"""Verdicts the report and ``reports/headline.json`` share: one display name per model, which models failed on
an output (train R² below 0: worse than the mean on the rows it was fitted on; a free run that diverged or is
worse than the mean), and the "best" among the models that did not fail, the reference (least squares) included.

Both the HTML summary (``pipeline.report.studies``) and the DVC metric (``stages.report.headline``) pick with
these functions, so the two name the same model.
"""

from __future__ import annotations

import math
from typing import Any

# paper 000's labels (pipeline.report.coupled.MODEL_LABELS, repeated so the report imports no model code)
COUPLED_LABELS = {"rbf_svr": "RBF-SVR", "two_weights_svr": "2-weights-SVR", "wdse_svr": "WDSE-SVR",
                  "gertler_hagen": "Gertler–Hagen", "mcfarland_whitcomb": "McFarland–Whitcomb",
                  "graybox": "gray-box"}
# paper 001's damping models
DAMPING_LABELS = {"ls": "LS", "mlp": "MLP", "krr": "KRR", "svr": "SVR", "gp": "GP", "hold_last": "hold last DVL"}
COUPLED_PREFIX = "coupled_"  # how the simulate stage names a coupled model beside the damping models

TRAIN_FAILED = "failed: train R² < 0"
WORSE_THAN_MEAN = "worse than the mean"


def label(model: Any) -> str:
    """The name a reader sees: ``wdse_svr`` and ``coupled_wdse_svr`` are both ``WDSE-SVR``, ``gp`` is ``GP``."""
    key = str(model)
    if key in COUPLED_LABELS:
        return COUPLED_LABELS[key]
    if key in DAMPING_LABELS:
        return DAMPING_LABELS[key]
    if key.startswith(COUPLED_PREFIX) and key[len(COUPLED_PREFIX):] in COUPLED_LABELS:
        return COUPLED_LABELS[key[len(COUPLED_PREFIX):]]
    return key


def number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(
        value) else None


def coupled_train_failed(entry: Any, output: str) -> bool:
    """Table III's entry of a coupled model: is its mean CV train R² on ``output`` below 0?"""
    cv = entry.get("cv") if isinstance(entry, dict) else None
    train = ((cv or {}).get(output) or {}).get("train_r2") if isinstance(cv, dict) else None
    mean = number(train.get("mean")) if isinstance(train, dict) else None
    return mean is not None and mean < 0


def damping_train_failed(result: Any) -> bool:
    """A damping model's result (decoupled metrics.json): is its mean CV train R² below 0?"""
    cv = result.get("cv") if isinstance(result, dict) else None
    mean = number((cv or {}).get("train_r2_mean")) if isinstance(cv, dict) else None
    return mean is not None and mean < 0


def best_coupled(final_r2: dict[str, dict[str, Any]], table3: Any) -> dict[str, tuple[str, float]]:
    """Per output, the model with the highest R² on the unseen trial, among the models whose train R² on it is
    not below 0 (``final_r2``: ``{model: {output: r2}}``; ``table3``: Table III's JSON, or None)."""
    best: dict[str, tuple[str, float]] = {}
    t3 = table3 if isinstance(table3, dict) else {}
    for model in sorted(final_r2):
        for output, value in final_r2[model].items():
            r2 = number(value)
            if r2 is None or coupled_train_failed(t3.get(model), output):
                continue
            if output not in best or (r2, model) > (best[output][1], best[output][0]):
                best[output] = (model, r2)
    return best


def best_damping(per_model: dict[str, Any]) -> tuple[str, float] | None:
    """The damping model with the lowest CV test MAE, least squares included, among those that did not fail."""
    maes = {m: number(((r.get("cv") or {}) if isinstance(r, dict) else {}).get("test_mae_mean"))
            for m, r in per_model.items() if isinstance(r, dict) and "failed" not in r and not damping_train_failed(r)}
    maes = {m: v for m, v in maes.items() if v is not None}
    if not maes:
        return None
    model = min(sorted(maes), key=maes.__getitem__)
    return model, maes[model]


def free_run_status(run: dict[str, Any]) -> str:
    """The free run's status as the table shows it: the simulate stage's status, or, where it reads "ok" but the
    run's R² on a DOF is below 0, "worse than the mean (v)"."""
    status = str(run.get("status"))
    worse = worse_dofs(run)
    if worse and status == "ok":
        return f"{WORSE_THAN_MEAN} ({', '.join(worse)})"
    return status


def worse_dofs(run: dict[str, Any]) -> list[str]:
    """The DOFs on which a free run's R² is below 0."""
    metrics = run.get("metrics") if isinstance(run.get("metrics"), dict) else {}
    worse = [d for d, m in metrics.items() if isinstance(m, dict) and (number(m.get("r2")) or 0.0) < 0]
    return sorted(worse, key=lambda d: ("uvwpqr".find(d) if len(d) == 1 and d in "uvwpqr" else 9, d))
