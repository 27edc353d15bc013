"""Plot data for ``dvc plots``: the model plots (R² per model, learning curves, free-run error vs horizon).

Each function takes what a stage wrote (parsed JSON, or None where the stage did not run) and returns flat rows,
one dict per point, with the same keys in every row; the report stage writes them as
``reports/plots/<name>.json`` and ``dvc.yaml`` names their x and y fields. No row names a trial or model in a key
(those are values: ``model``, ``series``), so the plot definitions hold for any trials and any model lists.
Series plots (``series`` + x + y) use the template ``pipeline/report/dvc_series.json``: one line per series.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from pipeline import layout

#: The template of the series plots, relative to the project root (where ``dvc plots`` runs).
SERIES_TEMPLATE = "pipeline/report/dvc_series.json"


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def _load(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _dof_key(dof: str) -> tuple[int, str]:
    return ("uvwpqr".find(dof) if len(dof) == 1 and dof in "uvwpqr" else 9, dof)


def coupled_r2(table3: Any) -> list[dict[str, Any]]:
    """Table III's final check: each coupled model's R² on the unseen trial per output, and its CV test R²."""
    rows = []
    for model, entry in sorted((table3 or {}).items()) if isinstance(table3, dict) else []:
        if not isinstance(entry, dict) or "failed" in entry:
            continue
        cv, final = entry.get("cv") or {}, entry.get("final") or {}
        for output in sorted(set(cv) | set(final)):
            r2 = _number((final.get(output) or {}).get("r2"))
            cv_r2 = _number(((cv.get(output) or {}).get("test_r2") or {}).get("mean"))
            if r2 is None and cv_r2 is None:
                continue
            rows.append({"model": f"{model} · {output}", "final_r2": r2, "cv_test_r2": cv_r2})
    return rows


def damping_r2(metrics: Any) -> list[dict[str, Any]]:
    """Table I: each damping model's CV test R² (and MAE) per DOF."""
    results = metrics.get("results") if isinstance(metrics, dict) else None
    rows = []
    for dof in sorted(results, key=_dof_key) if isinstance(results, dict) else []:
        for model, r in sorted((results[dof] or {}).items()):
            cv = r.get("cv") if isinstance(r, dict) else None
            r2 = _number((cv or {}).get("test_r2_mean"))
            if r2 is not None:
                rows.append({"model": f"{dof} · {model}", "cv_test_r2": r2,
                             "cv_test_mae": _number(cv.get("test_mae_mean"))})
    return rows


def learning_curves(metrics: Any) -> list[dict[str, Any]]:
    """Paper 001's learning curves: validation (and training) MAE of the damping against training rows, one
    series per DOF and model."""
    results = metrics.get("results") if isinstance(metrics, dict) else None
    rows = []
    for dof in sorted(results, key=_dof_key) if isinstance(results, dict) else []:
        for model, r in sorted((results[dof] or {}).items()):
            curve = r.get("learning_curve") if isinstance(r, dict) else None
            if not isinstance(curve, dict):
                continue
            sizes = curve.get("train_sizes") or []
            test = curve.get("test_mae_mean") or []
            train = curve.get("train_mae_mean") or [None] * len(sizes)
            for n, te, tr in zip(sizes, test, train, strict=False):
                if _number(n) is not None and _number(te) is not None:
                    rows.append({"series": f"{dof} · {model}", "train_samples": int(n), "test_mae": _number(te),
                                 "train_mae": _number(tr)})
    return rows


def free_run_error(horizons: dict[str, Any]) -> list[dict[str, Any]]:
    """Free-run velocity error against the rollout horizon: ``{trial: horizons.json}`` -> one series per trial,
    model and DOF (MAE at the horizon's end, over every window start)."""
    rows = []
    for trial, doc in sorted(horizons.items()):
        for model, per_h in sorted(doc.items()) if isinstance(doc, dict) else []:
            if not isinstance(per_h, dict):
                continue
            points = []
            for h, entry in per_h.items():
                try:
                    horizon = float(h)
                except ValueError:
                    continue
                for dof, mae in ((entry or {}).get("mae_end") or {}).items():
                    if _number(mae) is not None:
                        points.append((dof, horizon, _number(mae)))
            for dof, horizon, mae in sorted(points, key=lambda p: (_dof_key(p[0]), p[1])):
                rows.append({"series": f"{trial} · {model} · {dof}", "horizon_s": horizon, "mae": mae})
    return rows


def model_plots(root: Path) -> dict[str, list[dict[str, Any]]]:
    """The model plots of the run in ``root`` (name -> rows); a plot whose stage did not run has no rows."""
    root = Path(root)
    evaluation = root / layout.EVALUATION
    decoupled = _load(evaluation / "decoupled" / "metrics.json")
    base = root / layout.SIMULATION
    horizons = {p.name: _load(p / "horizons.json") for p in sorted(base.iterdir())
                if p.is_dir() and (p / "horizons.json").is_file()} if base.is_dir() else {}
    return {"coupled_r2": coupled_r2(_load(evaluation / "coupled" / "table3.json")),
            "damping_r2": damping_r2(decoupled),
            "learning_curves": learning_curves(decoupled),
            "free_run_error": free_run_error(horizons)}
