"""The report's section on extrapolation and excitation: which test trials' predictions are extrapolations, on which
inputs, and what excitation would fix it; read from the tune stage's ``coverage.json``
(:func:`pipeline.studies.coverage.study_coverage`, written before any model is trained).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from pipeline import layout
from pipeline.report import html as H
from pipeline.report import verdicts
from pipeline.skips import read_skip
from pipeline.units import SUFFIXES

log = logging.getLogger(__name__)


def read(root: Path) -> tuple[dict[str, Any] | None, str]:
    """The coverage document of the run (or None) and its run-relative path."""
    path = layout.coverage_path(root)
    rel = path.relative_to(root).as_posix()
    if not path.is_file():
        return None, rel
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        log.warning("report: cannot read %s: %s", path, err)
        return None, rel
    return (doc if isinstance(doc, dict) else None), rel


def unit(column: str) -> str:
    """The unit a column's suffix names (``T_th2_N`` -> ``N``), or "" when none."""
    suffix = column.rsplit("_", 1)[-1] if "_" in column else ""
    return SUFFIXES.get(suffix, ("", ""))[1]


def _num(value: Any) -> str:
    number = verdicts.number(value)
    return "—" if number is None else f"{number:.3g}"


def _q(value: Any, column: str) -> str:
    u = unit(column)
    return f"{_num(value)} {u}".rstrip()


def advice(trial: str, entry: dict[str, Any]) -> list[str]:
    """What excitation would bring a flagged trial inside the training: one sentence per named input, one for a
    combination outside the hull."""
    out = []
    for d in entry.get("inputs") or []:
        if not d.get("extrapolated"):
            continue
        c = d["input"]
        beyond = "" if d.get("max_excess_sd") is None else f", up to {_num(d['max_excess_sd'])} training SDs beyond"
        out.append(f"{c}: {_num(100 * d['share_outside_range'])} % of {trial}'s samples lie outside the training "
                   f"range [{_q(d['train_min'], c)}, {_q(d['train_max'], c)}]{beyond} (the trial reaches "
                   f"{_q(d['test_min'], c)} … {_q(d['test_max'], c)}): add a training trial that drives {c} to "
                   f"{_q(d['test_min'], c)} … {_q(d['test_max'], c)}.")
    hull = entry.get("hull") or {}
    named = set(entry.get("extrapolated_inputs") or [])
    drivers = [d for d in hull.get("drivers") or [] if d not in named]
    if hull.get("outside") and (drivers or not named):
        pairs = "; ".join(f"{p['inputs'][0]} with {p['inputs'][1]}: r = {_num(p['train_r'])} in training, "
                          f"{_num(p['test_r'])} here" for p in hull.get("driver_correlations") or []
                          if not set(p["inputs"]) & named)
        what = ", ".join(drivers) if drivers else "the inputs together"
        out.append(f"{_num(100 * hull.get('share_beyond'))} % of {trial}'s samples combine {what} as no training "
                   f"trial did (beyond the training's {_num(100 * hull.get('quantile'))} % Mahalanobis quantile)"
                   + (f" ({pairs})" if pairs else "")
                   + f": add a training trial that excites {what} together as {trial} does.")
    return out


def which(trial: str, entry: dict[str, Any]) -> str:
    """Which of a flagged trial's predictions are extrapolations: the share and the stretches, in seconds from the
    trial's first sample ("" where none is)."""
    share = verdicts.number(entry.get("extrapolated_share"))
    if not share:
        return ""
    runs = entry.get("stretches") or []
    total = entry.get("stretches_total") or len(runs)
    listed = ", ".join(f"{_num(r['start_s'])}–{_num(r['end_s'])} s" for r in runs)
    where = (f" in {total} stretch{'es' if total != 1 else ''}"
             + (f": {listed}" if listed else "")
             + (f" (the {len(runs)} longest listed)" if total > len(runs) and runs else "")) if total else ""
    return f"The predictions on {_num(100 * share)} % of {trial}'s samples are extrapolations{where}."


def _input_rows(entry: dict[str, Any]) -> list[dict[str, Any]]:
    return [{"input": d["input"],
             "training range": f"{_q(d['train_min'], d['input'])} … {_q(d['train_max'], d['input'])}",
             "trial's range": f"{_q(d['test_min'], d['input'])} … {_q(d['test_max'], d['input'])}",
             "share outside range": d["share_outside_range"],
             "share outside 0.5–99.5 %": d["share_outside_quantiles"],
             "largest excess [training SD]": d["max_excess_sd"], "named": d["extrapolated"]}
            for d in entry.get("inputs") or []]


def section(root: Path) -> tuple[str, str, set[str]]:
    """The section's HTML, the headline's warning (or ""), and the file used."""
    doc, rel = read(root)
    skipped = read_skip(layout.coverage_path(root).parent) if doc is None else None
    if skipped is not None:
        return (f"<p class='muted'>No extrapolation diagnostics: the coupled study was skipped: "
                f"{H.esc(skipped['skipped'])}.</p>", "", set())
    if doc is None:
        return ("<p class='muted'>No extrapolation diagnostics (data/evaluation/coupled/coverage.json: the tune "
                "stage writes it).</p>", "", set())
    parts = [f"<p>Written by the tune stage before any model is trained: the {H.esc(doc.get('training_rows'))} "
             f"rows the final models are fitted on (trials {H.esc(', '.join(doc.get('training_trials') or []))}) "
             "against each test trial. An input is named when more than "
             f"{_num(100 * (doc.get('thresholds') or {}).get('range_share', 0))} % of the trial's samples leave "
             "its training range; a trial is outside the hull when more than "
             f"{_num(100 * (doc.get('thresholds') or {}).get('hull_share', 0))} % of its samples lie beyond the "
             "training's own Mahalanobis quantile (docs/models.md, \"Extrapolation and excitation\").</p>"]
    flagged = doc.get("flagged") or {}
    headline = ""
    if flagged:
        listed = "; ".join(f"{t} ({', '.join(v) if v else 'the combination of inputs'})"
                           for t, v in sorted(flagged.items()))
        said = f"the predictions on {H.esc(listed)} are extrapolations beyond the training data"
        headline = (f"<p class='warn'><b>Extrapolation:</b> {said} (see <a href='#extrapolation'>Extrapolation "
                    "and excitation</a>).</p>")
        parts.append(f"<p class='warn'><b>Extrapolation:</b> {said}.</p>")
    elif doc.get("test_trials"):
        parts.append("<p>Every test trial lies inside the training data on every model's inputs.</p>")
    else:
        parts.append("<p class='muted'>No test trial: nothing to compare.</p>")
    for group in doc.get("groups") or []:
        models = ", ".join(verdicts.label(m) for m in group.get("models") or [])
        parts.append(f"<h3>{H.esc(models)}</h3>")
        rows, details = [], []
        for trial, entry in sorted((group.get("trials") or {}).items()):
            hull = entry.get("hull") or {}
            rows.append({"test trial": trial, "samples": entry.get("rows"),
                         "inputs beyond the training range": ", ".join(entry.get("extrapolated_inputs") or []) or
                         "none", "share outside the hull": hull.get("share_beyond"),
                         "hull drivers": ", ".join(hull.get("drivers") or []) or "—",
                         "extrapolation": bool(entry.get("outside")),
                         "share of predictions extrapolated": entry.get("extrapolated_share")})
            if entry.get("outside"):
                said = which(trial, entry)
                details.append(H.table(_input_rows(entry), caption=f"{trial}: each input against the training rows")
                               + (f"<p>{H.esc(said)}</p>" if said else "")
                               + "".join(f"<p class='warn'>{H.esc(a)}</p>" for a in advice(trial, entry)))
        if rows:
            parts.append(H.table(rows, caption="Test trials against the training rows"))
        parts.extend(details)
        exc = group.get("excitation") or {}
        ex_rows = [{"input": c, "training span (0.5–99.5 %)": _q(v.get("train_span"), c),
                    "test trials' span": _q(v.get("test_span"), c), "ratio": v.get("ratio"),
                    "least excited": c in (exc.get("least_excited") or [])}
                   for c, v in (exc.get("inputs") or {}).items()]
        if ex_rows:
            least = exc.get("least_excited") or []
            note = (f"Least excited in training: {', '.join(least)} (training span below "
                    f"{_num(100 * (doc.get('thresholds') or {}).get('excitation_ratio', 0))} % of the test trials')"
                    if least else f"Lowest ratio: {exc.get('lowest') or '—'}; none below the threshold")
            parts.append(H.table(ex_rows, caption="Excitation: the training's span of each input over the test "
                                                  "trials'") + f"<p>{H.esc(note)}.</p>")
    return "".join(parts), headline, {rel}
