"""Stage report: everything under ``data/`` -> ``reports/report.html`` (self-contained), ``reports/metrics.json``
(every score of the run), ``reports/headline.json`` (a handful of numbers for ``dvc metrics``: the best coupled
model's R² on the unseen trial per output, the best damping model's MAE against least squares per DOF, the best
free-run MAE per DOF), ``reports/plots/*.json`` (for ``dvc plots``: data quality, and the model plots of
``pipeline.report.plots``: R² per model, learning curves, free-run error vs horizon) and ``reports/figures/*.png``.

``python -m stages.report --root RUN --vehicle vehicle.yaml``.
"""

from __future__ import annotations

import json
import logging
import math
import re
from pathlib import Path
from typing import Any

from pipeline import layout
from pipeline.config import Params, Vehicle
from pipeline.report import verdicts
from pipeline.report.build import build
from pipeline.report.freeruns import simulation_doc
from pipeline.tableio import atomic_path, remove_stale_temps, write_json
from stages.common import StageResult, stage_main

log = logging.getLogger(__name__)

NAME = "report"


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_")


def _load(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None


def _number(value: Any) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


def headline(coupled: Any, decoupled: Any, simulation: Any, table3: Any = None) -> dict[str, Any]:
    """The few numbers ``dvc metrics`` shows, from the stages' metrics files (each may be missing: ``None``).

    ``coupled``: ``{model: {output: {final_r2, ...}}}``; ``decoupled``: ``{"results": {dof: {model: {"cv":
    {"test_mae_mean"}}}}}``; ``simulation``: ``{trial: {"free_run": [{model, status, metrics: {dof: {mae}}}]}}``.
    Diverged free runs are left out (their error covers only the part before they diverged), and so is a model
    that failed (``pipeline.report.verdicts``: train R² below 0 on that output (``table3``: Table III's JSON), a
    free run that diverged, in the whole trial or in a bridging window, or is worse than the mean on that DOF):
    the report's summary picks with the same functions."""
    out: dict[str, Any] = {}
    marks = verdicts.simulation_marks(simulation)
    finals = {m: {o: sc.get("final_r2") for o, sc in per_output.items() if isinstance(sc, dict)}
              for m, per_output in (coupled or {}).items() if isinstance(per_output, dict)}
    best = verdicts.best_coupled(finals, table3, marks)
    if best:
        out["coupled_final_r2"] = {o: {"best": round(r2, 6), "model": m} for o, (m, r2) in sorted(best.items())}
    damping: dict[str, Any] = {}
    results = decoupled.get("results", {}) if isinstance(decoupled, dict) else {}
    for dof, per_model in (results if isinstance(results, dict) else {}).items():
        chosen = verdicts.best_damping(per_model, dof, marks) if isinstance(per_model, dict) else None
        if chosen is not None:
            model, mae = chosen
            row: dict[str, Any] = {"best_mae": round(mae, 6), "model": model}
            ls = _number(((per_model.get("ls") or {}).get("cv") or {}).get("test_mae_mean")) if isinstance(
                per_model.get("ls"), dict) else None
            if ls is not None:
                row["ls_mae"] = round(ls, 6)
                if ls > 0:
                    row["vs_ls"] = round(mae / ls, 4)
            damping[dof] = row
    if damping:
        out["damping_mae"] = damping
    free: dict[str, list[tuple[float, str]]] = {}
    for trial_doc in (simulation if isinstance(simulation, dict) else {}).values():
        runs = trial_doc.get("free_run") if isinstance(trial_doc, dict) else None
        per_dof: dict[str, tuple[float, str]] = {}
        for run_ in runs if isinstance(runs, list) else []:
            if not isinstance(run_, dict) or run_.get("status") != "ok":
                continue
            for dof, m in (run_.get("metrics") or {}).items():
                failed = verdicts.failures(marks, str(run_.get("model")), dof)
                mae = _number(m.get("mae")) if isinstance(m, dict) and not failed else None
                if mae is not None and (dof not in per_dof or mae < per_dof[dof][0]):
                    per_dof[dof] = (mae, str(run_.get("model")))
        for dof, value in per_dof.items():
            free.setdefault(dof, []).append(value)
    if free:  # the mean over the unseen trials of the best model's MAE on each
        out["free_run_mae"] = {d: {"best": round(sum(v for v, _ in vals) / len(vals), 6),
                                   "model": vals[0][1] if len({m for _, m in vals}) == 1 else "mixed"}
                               for d, vals in free.items()}
    return out


def run(root: Path, vehicle: Vehicle, params: Params) -> StageResult:
    """Build the self-contained HTML report, metrics.json and the plot data of the run."""
    root = Path(root)
    remove_stale_temps(root / layout.REPORTS, recursive=True)
    report = build(root, vehicle, params)
    out = root / layout.REPORTS
    outputs = []
    with atomic_path(out / "report.html") as tmp:
        tmp.write_text(report.html, encoding="utf-8")
        tmp.chmod(0o644)  # a report is for reading (mkstemp makes 0600)
    outputs.append(out / "report.html")
    outputs.append(write_json(report.metrics, out / "metrics.json"))
    outputs.append(write_json(headline(_load(root / layout.EVALUATION / "coupled" / "metrics.json"),
                                       _load(root / layout.EVALUATION / "decoupled" / "metrics.json"),
                                       simulation_doc(root),
                                       _load(root / layout.EVALUATION / "coupled" / "table3.json")),
                              out / "headline.json"))
    for name, rows in sorted(report.plots.items()):
        outputs.append(write_json(rows, out / "plots" / f"{name}.json"))
    for path in outputs:
        path.chmod(0o644)
    figdir = out / "figures"
    wanted = {f"{_safe(name)}" + ("" if name.endswith(".png") else ".png") for name in report.figures}
    if figdir.is_dir():
        for old in figdir.glob("*.png"):
            if old.name not in wanted:
                old.unlink()
    for name, png in sorted(report.figures.items()):
        target = figdir / (_safe(name) + ("" if name.endswith(".png") else ".png"))
        with atomic_path(target) as tmp:
            tmp.write_bytes(png)
            tmp.chmod(0o644)
        outputs.append(target)
    log.info("report: %s", out / "report.html")
    return StageResult(stage=NAME, outputs=outputs, summary={"report": str(out / "report.html"),
                                                             "figures": len(report.figures)})


def main(argv: list[str] | None = None) -> int:
    return stage_main(NAME, run, argv)


if __name__ == "__main__":
    raise SystemExit(main())
