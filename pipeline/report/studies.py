"""The papers' artefacts as a document: the coupled study (paper 000), the damping study (paper 001), the free runs
and the headline box, each read from the JSON the stages wrote (docs/contracts.md) and shown once, with a caption.

Every renderer returns its HTML and the names of the files it used (relative to the run root); the build shows the
remaining files of a stage's directory with the generic renderer, so nothing a stage wrote is lost and nothing is
shown twice.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pipeline import layout
from pipeline.report import coupled as report_coupled
from pipeline.report import figures, verdicts
from pipeline.report import html as H
from pipeline.skips import SKIPPED, read_skip

log = logging.getLogger(__name__)

COUPLED = f"{layout.EVALUATION}/coupled"
DECOUPLED = f"{layout.EVALUATION}/decoupled"
LABELS = verdicts.COUPLED_LABELS  # paper 000's labels
SVRS = ("rbf_svr", "two_weights_svr", "wdse_svr")
OUTPUT_LABELS = {"udot_mps2": "u̇ [m/s²]", "vdot_mps2": "v̇ [m/s²]", "rdot_radps2": "ṙ [rad/s²]"}
DAMPING_UNIT = {"u": "N", "v": "N", "r": "N·m"}
VELOCITY_UNIT = {"u": "m/s", "v": "m/s", "r": "rad/s"}
DAMPING_ORDER = ("ls", "mlp", "krr", "svr", "gp")  # paper 001's order


@dataclass
class Part:
    """HTML of a study's section, the files it used (run-relative paths) and what the headline box needs."""
    html: str = ""
    used: set[str] = field(default_factory=set)
    headline: list[dict[str, Any]] = field(default_factory=list)
    failed: list[dict[str, Any]] = field(default_factory=list)
    protocol: str = ""
    verdicts: list[str] = field(default_factory=list)  # "model on output (why)": failed, left out of "best"
    bands: list[str] = field(default_factory=list)  # "model: 2σ band over-confident on v (...)": marked only
    outputs: list[str] = field(default_factory=list)  # the coupled study's outputs
    skipped: str = ""  # why the study's stages had nothing to do on this run (pipeline.skips), or ""
    buoyancy: list[str] = field(default_factory=list)  # "B − W = 2.034 ± 0.044 N (1 SD) ...": heave with a constant


def label(model: str) -> str:
    return verdicts.label(model)


def read(root: Path, rel: str, used: set[str]) -> Any:
    path = root / rel
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        log.warning("report: cannot read %s: %s", path, err)
        return None
    used.add(rel)
    return doc


def href(rel: str) -> str:
    """A run-relative path as seen from reports/report.html."""
    return "../" + rel


def png(root: Path, rel: str, used: set[str], figs: dict[str, bytes], key: str) -> bytes | None:
    path = root / rel
    if not path.is_file():
        return None
    used.add(rel)
    data = path.read_bytes()
    figs[key] = data
    return data


# ------------------------------------------------------------------------------------------- paper 000 (coupled)

CV_SPREAD_FLOOR = 0.005  # a fold spread below it (three folds alike to the third digit) is no spread

def protocol_line(hyper_doc: dict[str, Any] | None) -> str:
    """Which tuning protocol produced the tables (``hyperparameters.json``: ``tuning`` / ``tuned_on``)."""
    if not hyper_doc:
        return "Tuning protocol: unknown (no data/models/coupled/hyperparameters.json)."
    mode = hyper_doc.get("tuning", "split")
    block = hyper_doc.get("tuned_on", "tuning" if mode == "split" else "train_test")
    rows = hyper_doc.get("n_tuning_rows")
    where = f"on the {block} block" + (f" ({rows} rows)" if rows is not None else "")
    if mode == "nested":
        subsample = hyper_doc.get("max_samples")
        if subsample is not None and rows is not None and rows > subsample:
            where += f", each candidate scored on {subsample} of them evenly spaced in time"
        fold_evals = hyper_doc.get("fold_evals")
        if fold_evals is not None and hyper_doc.get("search", "fast") == "fast":
            folds = (f"in the cross-validation each fold re-tuned on its own training blocks by a local search of at "
                     f"most {fold_evals} candidates started from Table II's hyperparameters (chosen on rows that "
                     "include the fold's test block: a start, not the answer; docs/models.md)")
        else:
            folds = ("in the cross-validation each fold searched its own training blocks again, so no test block "
                     "chose the hyperparameters it is scored with")
        return (f"Tuning protocol: nested (coupled.tuning: nested, the default). Table II was searched {where}; "
                f"{folds}. This is not the papers' protocol.{search_folds_line(hyper_doc)}")
    return (f"Tuning protocol: split (coupled.tuning: split, the papers' protocol). Hyperparameters were searched "
            f"once {where} and kept fixed for the cross-validation and the final model.{search_folds_line(hyper_doc)}")


def search_folds_line(hyper_doc: dict[str, Any]) -> str:
    """How the searches' folds cut their rows (``hyperparameters.json``: ``search_folds``, ``tuning_cv``), as a
    sentence with a leading space; '' for a file from before the key."""
    used, mode = hyper_doc.get("search_folds"), hyper_doc.get("tuning_cv")
    if not used:
        return ""
    how = {"trials": "folds that hold out whole training trials (leave-one-trial-out)",
           "blocked": "blocked folds: contiguous blocks of the training trials' rows together, so most folds test on "
                      "another part of a trial they were fitted on"}
    said = " and ".join(how.get(u, u) for u in used)
    return f" Each search scored its candidates on {said} (coupled.tuning_cv: {mode})."


def _named(values: dict[str, Any], inputs: Sequence[str]) -> dict[str, Any]:
    """WDSE's ``gammas`` list as one ``gamma_<input>`` entry per input (when the lengths agree)."""
    out = {k: v for k, v in values.items() if k != "gammas"}
    gammas = values.get("gammas")
    if isinstance(gammas, list) and len(gammas) == len(inputs):
        out.update({f"gamma_{name}": g for name, g in zip(inputs, gammas, strict=True)})
    elif gammas is not None:
        out["gammas"] = gammas
    return out


def search_notes(trace: dict[str, Any], outputs: Sequence[str]) -> str:
    """The searches of Table II that kept their warm start (the simpler kernel's optimum: why, from the search's
    ``note``) or whose budget ran out before their local steps converged (``search_trace.json``); '' if none."""
    rows = []
    for model in sorted(trace, key=lambda m: (list(LABELS).index(m) if m in LABELS else 99, m)):
        per_out = trace[model] if isinstance(trace[model], dict) else {}
        for out in [o for o in outputs if isinstance(per_out.get(o), dict)]:
            res = per_out[out]
            if not (res.get("warm_start_kept") or res.get("budget_exhausted")):
                continue
            rows.append({"regressor": label(model), "output": OUTPUT_LABELS.get(out, out),
                         "tuning R²": res.get("best_score"), "candidates": res.get("n_candidates"),
                         "warm start kept": res.get("note") if res.get("warm_start_kept") else "no",
                         "budget ran out": "yes: still moving when it stopped" if res.get("budget_exhausted")
                         else "no: converged"})
    if not rows:
        return ""
    return H.table(rows, caption="Searches to read with care: a search that kept its warm start (the simpler "
                                 "kernel's optimum, so the richer kernel adds nothing there) and a search whose "
                                 "budget of candidates ran out before its local steps converged (coupled.max_evals; "
                                 "a larger budget may find better hyperparameters)")


def _table2(doc: dict[str, Any], outputs: Sequence[str], inputs: Sequence[str]) -> str:
    rows = []
    for model in sorted(doc, key=lambda m: (list(LABELS).index(m) if m in LABELS else 99, m)):
        per_out = doc[model]
        if not isinstance(per_out, dict):
            continue
        per_out = {o: _named(v, inputs) if isinstance(v, dict) else v for o, v in per_out.items()}
        names = list(dict.fromkeys(k for out in outputs for k in (per_out.get(out) or {})))
        for i, name in enumerate(names):
            rows.append({"regressor": label(model) if i == 0 else "", "hyperparameter": name,
                         **{OUTPUT_LABELS.get(o, o): (per_out.get(o) or {}).get(name) for o in outputs}})
    return H.table(rows, caption="Table II — hyperparameters (paper 000): the SVRs' hyperparameters per output "
                                 "(γ on standardized inputs; C and ε in the output's unit; C as chosen on C_rows "
                                 "rows, a fit on n rows uses C·(C_rows/n)^coupled.c_rate); a gray box's "
                                 "residual: kept on an output only where its search's blocked-CV R² on the "
                                 "base's residual is above coupled.residual_min_cv_r2, else that output is the "
                                 "base alone")


def coupled_verdict(entry: Any, marks: verdicts.Marks | None, model: str, output: str | None = None) -> str:
    """A coupled model's verdict on ``output`` (every output when None): its train R², its free runs."""
    cv = entry.get("cv") if isinstance(entry, dict) else None
    outs = [output] if output else list(cv) if isinstance(cv, dict) else []
    train = any(verdicts.coupled_train_failed(entry, o) for o in outs)
    dof = verdicts.OUTPUT_DOF.get(output, output) if output else None
    return verdicts.verdict(train, marks, verdicts.COUPLED_PREFIX + model, dof)


def coupled_failed(entry: Any, marks: verdicts.Marks | None, model: str, output: str) -> bool:
    """Is a coupled model failed on ``output`` (train R² below 0, or a free run that failed on its DOF)?"""
    return verdicts.coupled_train_failed(entry, output) or bool(
        verdicts.failures(marks, verdicts.COUPLED_PREFIX + model, verdicts.OUTPUT_DOF.get(output, output)))


def _table3(doc: dict[str, Any], outputs: Sequence[str], marks: verdicts.Marks | None = None
            ) -> tuple[str, list[dict[str, Any]]]:
    rows, failed = [], []
    for model in sorted(doc, key=lambda m: (list(LABELS).index(m) if m in LABELS else 99, m)):
        entry = doc[model]
        if not isinstance(entry, dict):
            continue
        if "failed" in entry:
            failed.append({"model": label(model), **(entry["failed"] if isinstance(entry["failed"], dict)
                                                     else {"reason": entry["failed"]})})
            continue
        cv, final = entry.get("cv", {}), entry.get("final", {})
        for i, out in enumerate(o for o in outputs if o in cv or o in final):
            c, f = cv.get(out, {}), final.get(out, {})
            rows.append({"model": label(model) if i == 0 else "", "output": OUTPUT_LABELS.get(out, out),
                         "CV test R² (mean ± sd)": H.mean_sd(c.get("test_r2", {}).get("mean"),
                                                             c.get("test_r2", {}).get("sd")),
                         "CV test MAE (mean ± sd)": H.mean_sd(c.get("test_mae", {}).get("mean"),
                                                              c.get("test_mae", {}).get("sd"), 4),
                         "CV train R² (mean ± sd)": H.mean_sd(c.get("train_r2", {}).get("mean"),
                                                              c.get("train_r2", {}).get("sd")),
                         "final check R² (unseen trial)": f.get("r2"), "final check MAE": f.get("mae"),
                         "90 % interval ±": report_coupled.interval_text((entry.get("interval") or {}).get(out)),
                         "inside 90 % (unseen trial)": None if not isinstance(f.get("interval_coverage"), float)
                         else f"{f['interval_coverage']:.0%}",
                         "verdict": coupled_verdict(entry, marks, model, out)})
    html = H.table(rows, caption="Table III — cross-validation and final check (paper 000): blocked k-fold CV on "
                                 "the train_test block (mean ± sd over folds), then the model fitted on all of it "
                                 "scored on the unseen test trial(s); verdict “failed: train R² < 0”: worse than "
                                 "the mean on its own training rows; a free run that diverged or is worse than the "
                                 "mean on the output's DOF is named too; either leaves the model out of “best”. "
                                 "90 % interval: prediction p ± a + b·abs(p), split conformal on the CV's "
                                 "out-of-fold |residuals|, their spread growing with abs(p) (with two or more "
                                 "training trials, the wider of that and the quantile of fits without whole "
                                 "trials); inside: the share of the unseen trial's measured targets within it, "
                                 "85–95 % expected")
    return html, failed


def residual_note(doc: dict[str, Any], outputs: Sequence[str]) -> str:
    """Per gray box, its test R² against its own base's on the CV's folds and held-out trials, per output, with the
    verdict where ``coupled.residual_fold_check`` drew one; '' when no model has that comparison."""
    lines = []
    for model, entry in doc.items():
        record = entry.get("residual") if isinstance(entry, dict) else None
        if isinstance(record, dict) and record:
            per_out = "; ".join(f"{OUTPUT_LABELS.get(o, o)}: {(record[o] or {}).get('verdict')}"
                                for o in outputs if o in record)
            dropped = any(str((record[o] or {}).get("verdict", "")).startswith("dropped") for o in record)
            lines.append(f"<p>{H.esc(label(model))} against its own base, on the CV's folds and on each held-out "
                         f"training trial: {H.esc(per_out)}."
                         + (" Where dropped, that output is the base's prediction alone, in every score above and "
                            "in the saved model (coupled.residual_fold_check)." if dropped else "") + "</p>")
    return "".join(lines)


def cv_against_unseen(doc: dict[str, Any], outputs: Sequence[str], trace: Any = None) -> str:
    """A warning table of the models and outputs whose unseen trial's R² lies outside their CV's fold spread (the
    CV test R²'s mean ± its SD over folds, at least ± 0.005), beside the search's own CV score (tuning R²,
    ``search_trace.json``) where the model has one; '' when none parts. A CV whose folds cut one trial's motion
    into blocks sees that trial's excitation in every fold; the next trial may not repeat it."""
    rows = []
    for model in sorted(doc, key=lambda m: (list(LABELS).index(m) if m in LABELS else 99, m)):
        entry = doc[model]
        if not isinstance(entry, dict) or not isinstance(entry.get("final"), dict):
            continue
        for out in outputs:
            test = ((entry.get("cv") or {}).get(out) or {}).get("test_r2") or {}
            unseen = (entry["final"].get(out) or {}).get("r2")
            mean, sd = test.get("mean"), test.get("sd")
            if not all(isinstance(v, (int, float)) for v in (mean, sd, unseen)):
                continue
            gap = unseen - mean
            if abs(gap) <= max(sd, CV_SPREAD_FLOOR):
                continue
            search = ((trace or {}).get(model) or {}).get(out) if isinstance(trace, dict) else None
            rows.append({"model": label(model), "output": OUTPUT_LABELS.get(out, out),
                         "search's CV R²": (search or {}).get("best_score") if isinstance(search, dict) else None,
                         "CV test R² (mean ± sd)": H.mean_sd(mean, sd), "unseen trial R²": unseen,
                         "unseen − CV": f"{gap:+.3f} ({abs(gap) / max(sd, CV_SPREAD_FLOOR):.1f} × the spread)",
                         "reads as": "optimistic CV: the unseen trial does worse than the folds" if gap < 0
                         else "the unseen trial does better than the folds"})
    if not rows:
        return ""
    worse = sum(r["unseen − CV"].startswith("-") for r in rows)
    return (f"<p class='warn'>{worse} of {len(rows)} model–output pair(s) score on the unseen trial below their "
            "cross-validation's fold spread: their CV score promised more than the next trial gave (see the "
            "table). Folds cut from the training trials see those trials' excitation in every fold; a training "
            "trial excited like the unseen one, or several training trials, narrows the gap.</p>"
            + H.table(rows, caption="CV against the unseen trial: the pairs whose unseen trial's R² lies outside "
                                    "the CV test R²'s mean ± sd over folds (at least ± 0.005)"))


def _best_per_output(doc: dict[str, Any], outputs: Sequence[str], marks: verdicts.Marks | None = None
                     ) -> dict[str, tuple[str, float]]:
    """Per output, the best final R² among the models not failed on it (verdicts.best_coupled)."""
    finals = {m: {o: (e["final"].get(o) or {}).get("r2") for o in outputs if isinstance(e["final"].get(o), dict)}
              for m, e in doc.items() if isinstance(e, dict) and isinstance(e.get("final"), dict)}
    best = verdicts.best_coupled(finals, doc, marks)
    return {o: best[o] for o in outputs if o in best}


def _train_failures(doc: dict[str, Any], outputs: Sequence[str]) -> list[str]:
    """'Gertler–Hagen on ṙ [rad/s²] (train R² -3.38)' for each model and output whose train R² is below 0."""
    notes = []
    for model, entry in doc.items():
        for out in outputs:
            if verdicts.coupled_train_failed(entry, out):
                mean = entry["cv"][out]["train_r2"]["mean"]
                notes.append(f"{label(model)} on {OUTPUT_LABELS.get(out, out)} (train R² {mean:.3g})")
    return notes


def ranking_note(best: dict[str, tuple[str, float]], hyper_doc: dict[str, Any] | None) -> str:
    """One sentence where the measured ranking contradicts paper 000 (an SVR, WDSE-SVR first, best on every
    output), and why that happens on realistic data."""
    contra = {out: model for out, (model, _) in best.items() if model not in SVRS}
    if not contra:
        return ""
    which = ", ".join(f"{OUTPUT_LABELS.get(o, o)}: {label(m)}" for o, m in contra.items())
    mode = (hyper_doc or {}).get("tuning", "split")
    why = ("Under the papers' split protocol the SVRs' hyperparameters come from a short tuning block whose CV "
           "does not rank them the way the whole training set needs them; coupled.tuning: nested (the default) "
           "searches on the rows each model is fitted on." if mode == "split" else
           "These tables come from nested tuning, which removes that cause (the SVRs are tuned on the rows they "
           "are fitted on); what can remain is extrapolation: an explicit model's parametric structure carries "
           "over to states of the unseen trial that a kernel model fitted on a few minutes of data has not seen.")
    return (f"<p class='note'><b>Differs from paper 000:</b> there the SVRs (WDSE-SVR first) beat the explicit "
            f"models; here an explicit model is best on the unseen trial for {H.esc(which)}. {H.esc(why)} "
            "See docs/models.md, “On realistic data”.</p>")


def coefficient_tables(root: Path, used: set[str]) -> str:
    """Per physics model whose card has them (Fossen, Gertler-Hagen, McFarland-Whitcomb), its coefficients with
    their block-bootstrap intervals."""
    parts = []
    for path in sorted((root / layout.MODELS / "coupled").glob("*.card.json")):
        card = read(root, str(path.relative_to(root)), used)
        ci = (card or {}).get("coefficient_intervals") if isinstance(card, dict) else None
        if not isinstance(ci, dict) or not ci.get("intervals") or str(card.get("model", "")).startswith("graybox"):
            continue  # a gray box's are its base's, shown with the base
        values = card.get("coefficients") or {}
        rows = [{"coefficient": k, "value": values.get(k), "low": lo, "high": hi}  # the masses (..dot) first
                for k, (lo, hi) in sorted(ci["intervals"].items(), key=lambda kv: (not kv[0].endswith("dot"), kv[0]))]
        level, fossen = float(ci.get("level", 0.9)), card.get("model") == "fossen"
        parts.append(H.table(rows, caption=(
            f"{label(card['model'])}: identified coefficients{' (SNAME)' if fossen else ''} with {level:.0%} "
            f"intervals: {ci.get('method', 'a block bootstrap')} ({ci.get('replicates')} replicates, "
            f"{ci.get('blocks')} blocks of {ci.get('block_rows')} rows)"
            + ("; the selected terms held fixed, a term not listed was not selected" if fossen else "")
            + (". The errors' correlation asks for longer blocks than the rows allow: these intervals are likely "
               "too narrow" if ci.get("blocks_too_short") else ""))))
    return "".join(parts)


def fold_figure(root: Path, t3: Any, outputs: Sequence[str], used: set[str], figs: dict[str, bytes],
                marks: verdicts.Marks | None) -> str:
    """Fig. 4 drawn from fold_scores.json with the report's verdicts (failed models red, an axis clipped at R² −1
    with each model cut off named); nothing where there are no fold scores."""
    folds = read(root, f"{COUPLED}/fold_scores.json", used)
    scores = report_coupled.fold_scores(folds, outputs) if isinstance(folds, dict) else {}
    caption = "Fig. 4 — test R² per CV fold (paper 000): one box per model and output; higher is better"
    if not scores:
        return ""
    t3 = t3 if isinstance(t3, dict) else {}
    failed = {(m, o): coupled_verdict(t3.get(m), marks, m, o) for m in scores for o in outputs
              if coupled_failed(t3.get(m), marks, m, o)}
    fig, off_scale = report_coupled.fold_figure(scores, outputs, failed)
    data = figures.png_bytes(fig)
    figs["coupled_fold_test_r2.png"] = data
    marked = sorted({f"{label(m)} on {OUTPUT_LABELS.get(o, o)}" for m, o in failed})
    caption += ("; red: failed (" + "; ".join(marked) + ")" if marked else "")
    caption += ("; off scale (axis clipped at R² −1): " + "; ".join(off_scale) if off_scale else "")
    return H.image(data, "fold test R² per model", caption)


def skipped_part(root: Path, directories: Sequence[str], what: str) -> Part | None:
    """The section of a study whose stages skipped (the marker in the first of ``directories``, run-relative),
    saying why; None when they ran."""
    doc = read_skip(root / directories[0])
    if doc is None:
        return None
    part = Part(skipped=doc["skipped"])
    part.used |= {f"{d}/{SKIPPED}" for d in directories}
    stages = [str(s) for s in doc.get("stages") or []]
    named = f" (stage{'s' if len(stages) > 1 else ''} {', '.join(stages)})" if stages else ""
    part.html = (f"<p class='warn'>{H.esc(what)} skipped{H.esc(named)}"
                 + f": {H.esc(doc['skipped'])}.</p>" + H.links([(href(f"{directories[0]}/{SKIPPED}"), SKIPPED)]))
    return part


def coupled(root: Path, figs: dict[str, bytes], marks: verdicts.Marks | None = None) -> Part:
    skipped = skipped_part(root, [COUPLED, f"{layout.MODELS}/coupled"], "The coupled study (paper 000) was")
    if skipped is not None:
        return skipped
    part = Part()
    used = part.used
    hyper_doc = read(root, f"{layout.MODELS}/coupled/hyperparameters.json", used)
    t2 = read(root, f"{COUPLED}/table2.json", used)
    t3 = read(root, f"{COUPLED}/table3.json", used)
    timings = read(root, f"{COUPLED}/timings.json", used)
    if t2 is None and t3 is None and hyper_doc is None:
        return part
    outputs = list((hyper_doc or {}).get("outputs") or [])
    if not outputs:
        found = [o for e in (t3 or {}).values() if isinstance(e, dict) for o in e.get("final", {})]
        outputs = list(dict.fromkeys(o for o in OUTPUT_LABELS if o in found)) or sorted(set(found))
    part.protocol = protocol_line(hyper_doc)
    part.outputs = list(outputs)
    parts = [f"<p class='box'>{H.esc(part.protocol)}</p>"]
    if isinstance(t2, dict) and t2:
        parts.append(_table2(t2, outputs, list((hyper_doc or {}).get("inputs") or [])))
    trace = read(root, f"{COUPLED}/search_trace.json", used)
    if isinstance(trace, dict):
        parts.append(search_notes(trace, outputs))
    used.add(f"{COUPLED}/table2.md")
    failed: list[dict[str, Any]] = []
    if isinstance(t3, dict):
        html, failed = _table3(t3, outputs, marks)
        parts += [html, residual_note(t3, outputs)]
        best = _best_per_output(t3, outputs, marks)
        parts.append(ranking_note(best, hyper_doc))
        parts.append(cv_against_unseen(t3, outputs, trace))
        parts.append(coefficient_tables(root, used))
        part.headline = [{"output": OUTPUT_LABELS.get(o, o), "best model": label(m),
                          "R² on the unseen trial": r2} for o, (m, r2) in best.items()]
        part.verdicts = _train_failures(t3, outputs)
    used.add(f"{COUPLED}/table3.md")
    if failed:
        part.failed = [{"study": "coupled", **f} for f in failed]
        parts.append("<p class='warn'>Failed, not in Table III (see Quarantine and failures).</p>")
    parts.append(fold_figure(root, t3, outputs, used, figs, marks))
    if isinstance(timings, dict) and timings:
        rows = []
        for model, t in timings.items():
            fits = [v for v in (t or {}).get("fit_time_s", []) if isinstance(v, (int, float))]
            if fits:
                rows.append({"model": label(model), "folds": len(fits), "mean fit time [s]": sum(fits) / len(fits),
                             "longest fit [s]": max(fits),
                             "verdict": coupled_verdict((t3 or {}).get(model) if isinstance(t3, dict) else None,
                                                        marks, model)})
        parts.append(H.table(rows, caption="Fit time per CV fold (wall clock on this machine)"))
    rels = [f"{layout.MODELS}/coupled/hyperparameters.json"] + [
        f"{COUPLED}/{n}" for n in ("table2.json", "table3.json", "fold_scores.json", "search_trace.json",
                                   "metrics.json", "timings.json")]
    used.update(r for r in rels if (root / r).is_file())
    parts.append(H.links([(href(r), Path(r).name) for r in rels if (root / r).is_file()]))
    part.html = "".join(parts)
    return part


# --------------------------------------------------------------------------------------- paper 001 (decoupled)

def slowest_candidate(cost: Any) -> str | None:
    """'31× the median (C 1e+03, ε 0.01, γ 30)': a grid search's slowest candidate (timings.json's ``search``)."""
    slowest = (cost or {}).get("slowest") if isinstance(cost, dict) else None
    if not slowest or not isinstance(slowest[0].get("ratio"), (int, float)):
        return None
    names = {"epsilon": "ε", "gamma": "γ", "alpha": "α"}
    params = ", ".join(f"{names.get(k, k)} {v:.3g}" if isinstance(v, float) else f"{names.get(k, k)} {v}"
                       for k, v in sorted(slowest[0]["params"].items()))
    return f"{slowest[0]['ratio']:.0f}× the median ({params})"


def decoupled(root: Path, figs: dict[str, bytes], marks: verdicts.Marks | None = None) -> Part:
    part = Part()
    used = part.used
    doc = read(root, f"{DECOUPLED}/metrics.json", used)
    timings = read(root, f"{DECOUPLED}/timings.json", used) or {}
    results = (doc or {}).get("results") if isinstance(doc, dict) else None
    if not isinstance(results, dict):
        return Part()
    rows, failed, curves, marked = [], [], {}, []
    for dof in sorted(results, key=dof_key):
        per_model = results[dof]
        unit = DAMPING_UNIT.get(dof, "")
        for model in sorted(per_model, key=lambda m: (DAMPING_ORDER.index(m) if m in DAMPING_ORDER else 9, m)):
            r = per_model[model]
            if not isinstance(r, dict) or "failed" in r:
                failed.append({"DOF": dof, "model": model, "reason": (r or {}).get("failed") if isinstance(r, dict)
                               else r})
                continue
            cv = r.get("cv", {})
            learned = r.get("learned") or {}
            params = r.get("best_params") or ({"kernel": learned["kernel"]} if "kernel" in learned else {})
            t = timings.get(f"{dof}/{model}", {}) if isinstance(timings, dict) else {}
            rows.append({"DOF": dof, "model": label(model), "MAE unit": unit, "best hyperparameters": params or "—",
                         "search MAE": r.get("search_mae"),
                         "CV test MAE (mean ± sd)": H.mean_sd(cv.get("test_mae_mean"), cv.get("test_mae_sd")),
                         "CV test R² (mean ± sd)": H.mean_sd(cv.get("test_r2_mean"), cv.get("test_r2_sd")),
                         "CV train MAE": cv.get("train_mae_mean"),
                         "fit time [ms]": 1e3 * t["fit_time_s"] if isinstance(t.get("fit_time_s"), float) else None,
                         "search's slowest fit": slowest_candidate(t.get("search")),
                         "verdict": verdicts.verdict(verdicts.damping_train_failed(r), marks, model, dof)})
            bad = verdicts.damping_train_failed(r) or verdicts.failures(marks, model, dof)
            if bad:
                marked.append(f"{label(model)} on {dof}")
            if isinstance(r.get("learning_curve"), dict):
                curves.setdefault(dof, {})[label(model) + (" (failed)" if bad else "")] = r["learning_curve"]
            if verdicts.damping_train_failed(r):
                part.verdicts.append(f"{label(model)} on {dof} (train R² {r['cv']['train_r2_mean']:.3g})")
        part.buoyancy += [buoyancy_line(dof, model, r["net_buoyancy"]) for model, r in per_model.items()
                          if isinstance(r, dict) and isinstance(r.get("net_buoyancy"), dict)]
        best = verdicts.best_damping(per_model, dof, marks)  # least squares, the reference, competes too
        ls = verdicts.number(((per_model.get("ls") or {}).get("cv") or {}).get("test_mae_mean")) if isinstance(
            per_model.get("ls"), dict) else None
        if best is not None:
            part.headline.append({"dof": dof, "model": best[0], "mae": best[1], "ls": ls, "unit": unit})
    parts = [H.table(rows, caption="Table I — the damping study (paper 001): per DOF, each model's search result "
                                   "and its blocked-CV scores on the train_test rows; MAE of the damping d_i(ν_i); "
                                   "the search's slowest fit: its slowest grid candidate against its median one; "
                                   "verdict: train R² below 0, a free run that failed on the DOF (left out of "
                                   "“best”) or a 2σ band outside 90–98 % coverage")]
    parts += [f"<p class='box'>{H.esc(line)}</p>" for line in part.buoyancy]
    if failed:
        part.failed = [{"study": "decoupled", "model": f"{f['DOF']}/{f['model']}", "reason": f["reason"]}
                       for f in failed]
        parts.append("<p class='warn'>Failed, not in Table I (see Quarantine and failures).</p>")
    curve_png = figures.learning_curves(curves, DAMPING_UNIT)
    if curve_png:
        figs["decoupled_learning_curves.png"] = curve_png
        parts.append(H.image(curve_png, "learning curves",
                             "Fig. 2 — learning curves (paper 001): validation (solid) and training (dashed) MAE of "
                             "the damping vs training samples" + ("; “(failed)”: " + ", ".join(marked) if marked
                                                                  else "")))
        used.add(f"{DECOUPLED}/learning_curves.png")  # the report draws it again, with units
    else:
        data = png(root, f"{DECOUPLED}/learning_curves.png", used, figs, "decoupled_learning_curves.png")
        if data:
            parts.append(H.image(data, "learning curves", "Fig. 2 — learning curves (paper 001)"))
    data = png(root, f"{DECOUPLED}/damping.png", used, figs, "decoupled_damping.png")
    if data:
        parts.append(H.image(data, "damping curves", "Fig. 3 — damping curves (paper 001): each model's d_i(ν_i) "
                                                     "over the measured range [N or N·m vs m/s or rad/s], GP with "
                                                     "its 2σ band, the training data in grey"
                             + (f"; failed: {', '.join(marked)}" if marked else "")
                             + "".join(f"; {label(m)}: {n}" for m in sorted(marks or {})
                                       for n in verdicts.notes(marks, m, kind="band")
                                       if m in {k for per in results.values() for k in per})))
    data = png(root, f"{DECOUPLED}/timings.png", used, figs, "decoupled_timings.png")
    if data:
        parts.append(H.image(data, "timings", "Timings (paper 001): fit and predict time per CV fold [s], log scale"))
    rels = [f"{DECOUPLED}/{n}" for n in ("metrics.json", "curves.json", "timings.json", "table.md")]
    used.update(r for r in rels if (root / r).is_file())
    parts.append(H.links([(href(r), Path(r).name) for r in rels if (root / r).is_file()]))
    part.html = "".join(parts)
    return part


def buoyancy_line(dof: str, model: str, b: dict[str, Any]) -> str:
    """The net buoyancy a heave model with a constant found (``decoupled.intercept``; the study's
    ``net_buoyancy``): B − W with its SD when the config's B − W is known, else the constant alone."""
    sd = verdicts.number(b.get("sd_N"))
    pm = "" if sd is None else f" ± {sd:.3f}"
    const = verdicts.number(b.get("intercept_N"))
    const_text = "—" if const is None else f"{const:.3f} N"
    total, configured = verdicts.number(b.get("B_minus_W_N")), verdicts.number(b.get("configured_N"))
    if total is None or configured is None:
        return (f"Net buoyancy ({dof}, {label(model)} with a constant): the fitted constant {const_text}{pm} (1 SD); "
                "B − W unknown: the vehicle config gives no weight and buoyancy to add it to.")
    return (f"Net buoyancy ({dof}, {label(model)} with a constant): B − W = {total:.3f}{pm} N (1 SD), the vehicle "
            f"config's {configured:.3f} N plus the fitted constant {const_text}; positive floats up.")


def dof_key(dof: str) -> tuple[int, str]:
    return ("uvwpqr".find(dof) if len(dof) == 1 and dof in "uvwpqr" else 9, dof)
