"""Verdicts the report and ``reports/headline.json`` share: one display name per model, which models failed on
an output (train R² below 0: worse than the mean on the rows it was fitted on; a free run that diverged, in the
whole-trial run or in any bridging window, or is worse than the mean), which 2σ bands miss their coverage
(outside 90–98 %: over-confident below, too wide above; marked, not failed: the mean may still be the best), and
the "best" among the models that did not fail, the reference (least squares) included.

Both the HTML summary (``pipeline.report.studies``) and the DVC metric (``stages.report.headline``) pick with
these functions, so the two name the same model.
"""

from __future__ import annotations

import math
from typing import Any

#: ``{simulated model key: {DOF or ALL: [(kind, why)]}}``; kind "failed" or "band" (both left out of "best")
Marks = dict[str, dict[str, list[tuple[str, str]]]]

# paper 000's labels (pipeline.report.coupled.MODEL_LABELS, repeated so the report imports no model code)
COUPLED_LABELS = {"rbf_svr": "RBF-SVR", "two_weights_svr": "2-weights-SVR", "wdse_svr": "WDSE-SVR",
                  "gertler_hagen": "Gertler–Hagen", "mcfarland_whitcomb": "McFarland–Whitcomb",
                  "fossen": "Fossen", "graybox": "Gray-box (MW + WDSE)", "graybox_gh": "Gray-box (GH + WDSE)",
                  "graybox_fossen": "Gray-box (Fossen + WDSE)", "abkowitz": "Abkowitz",
                  "graybox_abkowitz": "Gray-box (Abkowitz + WDSE)"}
# paper 001's damping models
DAMPING_LABELS = {"ls": "LS", "mlp": "MLP", "krr": "KRR", "svr": "SVR", "gp": "GP", "hold_last": "hold last DVL"}
COUPLED_PREFIX = "coupled_"  # how the simulate stage names a coupled model beside the damping models

TRAIN_FAILED = "failed: train R² < 0"
WORSE_THAN_MEAN = "worse than the mean"
BAND_COVERAGE = (0.90, 0.98)  # a 2σ band should hold ~95 % of the measured samples
OVER_CONFIDENT = "over-confident"
TOO_WIDE = "too wide"
ALL = "*"  # a mark on every DOF (a diverged run)
#: the coupled outputs' DOF (a coupled model's free run on DOF u speaks for its u̇)
OUTPUT_DOF = {f"{d}dot_{u}": d for d, u in (("u", "mps2"), ("v", "mps2"), ("w", "mps2"), ("p", "radps2"),
                                            ("q", "radps2"), ("r", "radps2"))}


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


def best_coupled(final_r2: dict[str, dict[str, Any]], table3: Any, marks: Marks | None = None
                 ) -> dict[str, tuple[str, float]]:
    """Per output, the model with the highest R² on the unseen trial, among the models whose train R² on it is
    not below 0 and whose free run did not fail on its DOF (``final_r2``: ``{model: {output: r2}}``; ``table3``:
    Table III's JSON, or None; ``marks``: :func:`simulation_marks`)."""
    best: dict[str, tuple[str, float]] = {}
    t3 = table3 if isinstance(table3, dict) else {}
    for model in sorted(final_r2):
        for output, value in final_r2[model].items():
            r2 = number(value)
            if r2 is None or coupled_train_failed(t3.get(model), output) or disqualified(
                    marks, COUPLED_PREFIX + model, OUTPUT_DOF.get(output, output)):
                continue
            if output not in best or (r2, model) > (best[output][1], best[output][0]):
                best[output] = (model, r2)
    return best


def best_damping(per_model: dict[str, Any], dof: str = "", marks: Marks | None = None) -> tuple[str, float] | None:
    """The damping model with the lowest CV test MAE, least squares included, among those that did not fail (to
    fit, on their training rows, or in a free run on ``dof``: ``marks``, :func:`simulation_marks`)."""
    maes = {m: number(((r.get("cv") or {}) if isinstance(r, dict) else {}).get("test_mae_mean"))
            for m, r in per_model.items() if isinstance(r, dict) and "failed" not in r and not damping_train_failed(r)
            and not disqualified(marks, m, dof)}
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


def band_verdict(coverage: Any) -> str:
    """"over-confident" (below 90 %), "too wide" (above 98 %) or "" for a 2σ band's share of measured samples."""
    share = number(coverage)
    if share is None:
        return ""
    return OVER_CONFIDENT if share < BAND_COVERAGE[0] else TOO_WIDE if share > BAND_COVERAGE[1] else ""


def band_text(dof: str, coverage: float) -> str:
    """'2σ band over-confident on v (covers 46 %, target 90–98 %)'."""
    return (f"2σ band {band_verdict(coverage)} on {dof} (covers {coverage:.0%}, target "
            f"{BAND_COVERAGE[0]:.0%}–{BAND_COVERAGE[1]:.0%})")


def simulation_marks(simulation: Any) -> Marks:
    """What the simulate stage's runs say against each model, over every unseen trial (``simulation``:
    ``{trial: {"free_run": [...], "bridging": [...]}}``, the stage's metrics.json): a free run that diverged
    (every DOF), is worse than the mean on a DOF, or diverged in a bridging window (failed); a band outside its
    coverage on a DOF (marked only)."""
    marks: Marks = {}

    def add(model: Any, dof: str, kind: str, why: str) -> None:
        entry = marks.setdefault(str(model), {}).setdefault(dof, [])
        if (kind, why) not in entry:
            entry.append((kind, why))

    for trial, doc in sorted((simulation if isinstance(simulation, dict) else {}).items()):
        for run in (doc.get("free_run") or []) if isinstance(doc, dict) else []:
            if not isinstance(run, dict):
                continue
            if run.get("status") == "diverged":
                at = number(run.get("diverged_at_s"))
                add(run.get("model"), ALL, "failed", f"free run on {trial}: diverged"
                    + (f" at {at:.3g} s" if at is not None else ""))
            for dof in worse_dofs(run):
                add(run.get("model"), dof, "failed", f"free run on {trial}: {WORSE_THAN_MEAN} ({dof})")
            cover = run.get("band_coverage") if isinstance(run.get("band_coverage"), dict) else {}
            for dof, share in cover.items():
                if band_verdict(share):
                    add(run.get("model"), dof, "band", f"free run on {trial}: {band_text(dof, float(share))}")
        for row in (doc.get("bridging") or []) if isinstance(doc, dict) else []:
            if isinstance(row, dict) and (number(row.get("n_diverged")) or 0) > 0:
                w = number(row.get("window_s"))
                add(row.get("model"), ALL, "failed", f"bridging on {trial}: diverged in {row['n_diverged']} of "
                                                     f"{row.get('n_windows')} windows"
                                                     + (f" of {w:g} s" if w is not None else ""))
    return marks


def notes(marks: Marks | None, model: str, dof: str | None = None, kind: str | None = None) -> list[str]:
    """The marks against ``model`` on ``dof`` (every DOF when None), of one ``kind`` or all."""
    per = (marks or {}).get(str(model)) or {}
    found = [w for d, entries in per.items() if dof is None or d in (dof, ALL) for k, w in entries
             if kind is None or k == kind]
    return list(dict.fromkeys(found))


def failures(marks: Marks | None, model: str, dof: str | None = None) -> list[str]:
    """Why ``model`` failed in a free run on ``dof`` (any DOF when None); [] when it did not."""
    return notes(marks, model, dof, "failed")


def disqualified(marks: Marks | None, model: str, dof: str | None = None) -> list[str]:
    """Why ``model`` is left out of "best" on ``dof``: a failed free run, or a band outside its coverage (a model
    that says it is surer than it is does not get recommended)."""
    return failures(marks, model, dof) + notes(marks, model, dof, "band")


def verdict(train_failed: bool, marks: Marks | None, model: str, dof: str | None = None) -> str:
    """A table's verdict cell: "ok", or every reason (failed ones first) joined by "; "."""
    found = ([TRAIN_FAILED] if train_failed else []) + failures(marks, model, dof) + notes(marks, model, dof, "band")
    return "; ".join(found) or "ok"
