"""The free runs and DVL-outage bridging as a document: per unseen trial the free-run table (with each model's
verdict: diverged, worse than the mean, a 2σ band outside its coverage), the free-run figure, the rollout
horizons, and the bridging table and figure (drawn again here, a model that diverged in any window marked so).

:func:`simulation_doc` is the one reading of the simulate stage's results that the report and
``reports/headline.json`` share (:func:`pipeline.report.verdicts.simulation_marks` is computed from it).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from pipeline import layout
from pipeline.report import figures, verdicts
from pipeline.report import html as H
from pipeline.report.rollout import bridging_figure
from pipeline.report.studies import VELOCITY_UNIT, Part, dof_key, href, label, png, read, skipped_part


def simulation_doc(root: Path) -> dict[str, Any]:
    """``{trial: {"free_run": [...], "bridging": [...]}}``: the stage's metrics.json, or, without it, each
    trial's free_run.json and bridging.json."""
    base = Path(root) / layout.SIMULATION
    try:
        doc = json.loads((base / "metrics.json").read_text(encoding="utf-8"))
        if isinstance(doc, dict):
            return doc
    except (OSError, ValueError):
        pass
    out: dict[str, Any] = {}
    for trial_dir in sorted(p for p in base.iterdir() if p.is_dir()) if base.is_dir() else []:
        entry = {}
        for name in ("free_run", "bridging"):
            try:
                entry[name] = json.loads((trial_dir / f"{name}.json").read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
        if entry:
            out[trial_dir.name] = entry
    return out


def _coverage_cell(cover: Any) -> str:
    if not isinstance(cover, dict):
        return "—"
    cells = []
    for d in sorted(cover, key=dof_key):
        share = verdicts.number(cover[d])
        if share is not None:
            miss = verdicts.band_verdict(share)
            cells.append(f"{d}: {share:.0%}" + (f" ({miss})" if miss else ""))
    return "; ".join(cells) or "—"


def _free_run_rows(runs: list[dict[str, Any]], marks: verdicts.Marks) -> list[dict[str, Any]]:
    rows = []
    for run in runs:
        metrics = run.get("metrics") or {}
        row: dict[str, Any] = {"model": label(run.get("model")), "status": verdicts.free_run_status(run),
                               "diverged at [s]": run.get("diverged_at_s")}
        for dof in sorted(metrics, key=dof_key):
            m, unit = metrics[dof], VELOCITY_UNIT.get(dof, "")
            row[f"{dof} R²"] = (m or {}).get("r2")
            row[f"{dof} MAE [{unit}]"] = (m or {}).get("mae")
        row["2σ band coverage"] = _coverage_cell(run.get("band_coverage"))
        row["verdict"] = verdicts.verdict(False, marks, str(run.get("model")))
        rows.append(row)
    return rows


def _horizon_rows(doc: dict[str, Any], marks: verdicts.Marks) -> list[dict[str, Any]]:
    rows = []
    for model, per_h in doc.items():
        if not isinstance(per_h, dict):
            continue
        for h in sorted(per_h, key=lambda k: float(k) if k.replace(".", "", 1).isdigit() else 0.0):
            e = per_h[h] or {}
            row: dict[str, Any] = {"model": label(model), "horizon [s]": h, "windows": e.get("n_windows"),
                                   "diverged": e.get("n_diverged")}
            for dof, v in (e.get("mae_end") or {}).items():
                row[f"{dof} MAE at end [{VELOCITY_UNIT.get(dof, '')}]"] = v
            row["verdict"] = verdicts.verdict(False, marks, model)
            rows.append(row)
    return rows


def _bridging_rows(rows: list[dict[str, Any]], marks: verdicts.Marks) -> list[dict[str, Any]]:
    hold = {r.get("window_s"): r.get("mean_error_m") for r in rows if r.get("model") == "hold_last"}
    out = []
    for r in rows:
        base = hold.get(r.get("window_s"))
        mean = r.get("mean_error_m")
        ratio = mean / base if isinstance(mean, (int, float)) and isinstance(base, (int, float)) and base else None
        model = str(r.get("model"))
        out.append({"outage [s]": r.get("window_s"), "model": label(model), "windows": r.get("n_windows"),
                    "diverged": r.get("n_diverged"), "mean error [m]": mean, "median [m]": r.get("median_error_m"),
                    "max [m]": r.get("max_error_m"), "distance travelled [m]": r.get("mean_distance_m"),
                    "vs hold-last": None if ratio is None else f"{ratio:.2f}×",
                    "verdict": "reference" if model == "hold_last" else verdicts.verdict(False, marks, model),
                    "failed": bool(verdicts.disqualified(marks, model)) or bool(r.get("n_diverged"))})
    return out


def section(root: Path, figs: dict[str, bytes], marks: verdicts.Marks | None = None) -> Part:
    """The free runs and bridging of every unseen trial (``marks``: the verdicts on the models' free runs)."""
    marks = marks or {}
    skipped = skipped_part(root, [layout.SIMULATION], "The free runs were")
    if skipped is not None:
        return skipped
    part = Part()
    used = part.used
    base = root / layout.SIMULATION
    if not base.is_dir():
        return part
    parts = []
    for model in sorted(marks):
        part.verdicts += [f"{label(model)} {n}" for n in verdicts.failures(marks, model)]
        part.bands += [f"{label(model)} {n}" for n in verdicts.notes(marks, model, kind="band")]
    for trial_dir in sorted(p for p in base.iterdir() if p.is_dir() and (p / "free_run.json").is_file()):
        trial = trial_dir.name
        rel = f"{layout.SIMULATION}/{trial}"
        runs = read(root, f"{rel}/free_run.json", used)
        runs = [r for r in runs if isinstance(r, dict)] if isinstance(runs, list) else []
        parts.append(f"<h3>{H.esc(trial)} (unseen trial)</h3>")
        if runs:
            parts.append(H.table(_free_run_rows(runs, marks),
                                 caption=f"Free runs on {trial}: each model rolled out from the measured initial "
                                         "velocity over the whole trial; R² and MAE of the velocity; coverage: "
                                         "share of measured samples inside the model's 2σ band (90–98 % expected: "
                                         "below, the band is over-confident; above, too wide); verdict: every "
                                         "mark against the model (a failed one leaves it out of “best”)"))
        banded = [label(r.get("model")) for r in runs if r.get("band_coverage")]
        data = png(root, f"{rel}/free_run.png", used, figs, f"simulation_{trial}_free_run.png")
        if data:
            band = (f"the shaded band is the 2σ band of {', '.join(map(str, banded))} (posterior samples)"
                    if banded else "no model of this run has a band")
            said = [f"{label(r.get('model'))}: {verdicts.verdict(False, marks, str(r.get('model')))}" for r in runs
                    if verdicts.verdict(False, marks, str(r.get("model"))) != "ok"]
            parts.append(H.image(data, f"free runs of {trial}", f"Fig. 4 — free runs (paper 001) on {trial}: "
                                                                f"measured (black) vs predicted velocity "
                                                                f"[m/s, rad/s] over time [s]; {band}; × marks "
                                                                "where a model diverged"
                                 + (f"; marked: {'; '.join(said)}" if said else "")))
        horizons = read(root, f"{rel}/horizons.json", used)
        if isinstance(horizons, dict) and horizons:
            parts.append(H.table(_horizon_rows(horizons, marks), caption="Rollouts from every window start over "
                                                                         "fixed horizons: velocity MAE at the "
                                                                         "horizon's end"))
        bridging = read(root, f"{rel}/bridging.json", used)
        used.add(f"{rel}/bridging.md")
        if isinstance(bridging, list) and bridging:
            raw = [r for r in bridging if isinstance(r, dict)]
            rows = _bridging_rows(raw, marks)
            parts.append(H.table([{k: v for k, v in r.items() if k != "failed"} for r in rows],
                                 caption="DVL-outage bridging: dead reckoning with each damping model's velocity "
                                         "vs holding the last DVL velocity; position error at the end of the "
                                         "outage; a model that diverged in any window is failed (its mean covers "
                                         "only the windows it survived)"))
            for r in rows:
                if r["model"] != label("hold_last") and isinstance(r["mean error [m]"], (int, float)):
                    part.headline.append({"trial": trial, **r})
            failed = {str(r.get("model")): "; ".join(verdicts.failures(marks, str(r.get("model"))))
                      for r in raw if verdicts.failures(marks, str(r.get("model")))}
            fig_png = figures.png_bytes(bridging_figure(raw, failed))
            figs[f"simulation_{trial}_bridging.png"] = fig_png
            used.add(f"{rel}/bridging.png")  # drawn again here, with the verdicts
            parts.append(H.image(fig_png, "bridging error", "Bridging: mean position error at the end of the "
                                                            "outage [m, log scale] vs outage length [s]; dotted, "
                                                            "hollow: failed (never the best)"))
        rels = [f"{rel}/{n}" for n in ("free_run.json", "horizons.json", "bridging.json")]
        parts.append(H.links([(href(r), Path(r).name) for r in rels if (root / r).is_file()]))
    if (base / "metrics.json").is_file():
        used.add(f"{layout.SIMULATION}/metrics.json")
        parts.append(H.links([(href(f"{layout.SIMULATION}/metrics.json"), "metrics.json")]))
    part.html = "".join(parts)
    return part
