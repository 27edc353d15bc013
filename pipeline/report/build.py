"""Collect what the stages wrote under a run directory and assemble the report, metrics and plot data.

Only the paths of ``docs/contracts.md`` are assumed: ``data/signals/<trial>/ingest_report.json``,
``data/signals/quarantine.json``, ``data/synced/<trial>.parquet``, and whatever JSON / Markdown / CSV / PNG
files the model stages put under ``data/evaluation/`` and ``data/simulation/`` (discovered, not named).
"""

from __future__ import annotations

import json
import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from pipeline import __version__, layout
from pipeline.config import Params, Vehicle, config_hash
from pipeline.report import compare, coverage, figures, freeruns, spectra, studies, summary, verdicts
from pipeline.report import html as H
from pipeline.report.names import signal_label
from pipeline.report.plots import model_plots

log = logging.getLogger(__name__)

METRIC_KEY = re.compile(r"(r2|mae|rmse|mse|score|error|diverged)", re.IGNORECASE)
# Wall-clock timings vary run to run: they stay in the report's tables, never in metrics.json (DVC would see a
# change on every run). Train scores stay in the tables too: metrics.json carries the scores that decide.
NOT_METRIC = re.compile(r"(time|fit_s|predict_s|train_|train\.|trace)", re.IGNORECASE)
ID_KEYS = ("window_s", "horizon_s", "fold", "dof", "output")
MAX_METRICS_PER_FILE = 1000
MAX_CSV_ROWS = 40


@dataclass
class Report:
    html: str
    metrics: dict[str, Any]
    plots: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    figures: dict[str, bytes] = field(default_factory=dict)


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        log.warning("report: cannot read %s: %s", path, err)
        return None


def _trials(root: Path) -> list[str]:
    names: set[str] = set()
    sig = root / layout.SIGNALS
    if sig.is_dir():
        names |= {p.name for p in sig.iterdir() if p.is_dir() and not p.name.startswith(".")}
    syn = root / layout.SYNCED
    if syn.is_dir():
        names |= {p.stem for p in syn.glob("*.parquet")}
    return sorted(names)


def _item_label(item: dict[str, Any], index: int) -> str:
    parts = [str(v) for k, v in item.items() if isinstance(v, str)]
    parts += [f"{k}={v}" for k, v in item.items() if k in ID_KEYS and not isinstance(v, str)]
    return "@".join(parts) if parts else str(index)


def _flatten_numbers(obj: Any, prefix: str, out: dict[str, float], depth: int = 0) -> None:
    """Numeric leaves whose key path names a score; list items of records are labelled by their string
    fields (``model``) and id fields (``window_s``), e.g. ``trial03.bridging.gp@window_s=10.0.mean_error_m``."""
    if isinstance(obj, dict) and depth < 6:
        for k, v in sorted(obj.items(), key=lambda kv: str(kv[0])):
            _flatten_numbers(v, f"{prefix}.{k}" if prefix else str(k), out, depth + 1)
    elif isinstance(obj, list) and depth < 6 and obj and all(isinstance(i, dict) for i in obj):
        for index, item in enumerate(obj):
            label = _item_label(item, index)
            rest = {k: v for k, v in item.items() if not isinstance(v, str) and k not in ID_KEYS}
            _flatten_numbers(rest, f"{prefix}.{label}" if prefix else label, out, depth + 1)
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool) and math.isfinite(float(obj)):
        if METRIC_KEY.search(prefix) and not NOT_METRIC.search(prefix):
            out[prefix] = round(float(obj), 6)


# ------------------------------------------------------------------------------------------------ sections

def _ingest_section(root: Path, trials: list[str], metrics: dict[str, Any],
                    plots: dict[str, list[dict[str, Any]]], figs: dict[str, bytes]) -> str:
    parts, rows_rates = [], []
    for trial in trials:
        rep = _read_json(layout.ingest_report_path(root, trial))
        if not rep:
            continue
        streams = rep.get("streams", {})
        parts.append(f"<h3>{H.esc(trial)}</h3><p class='muted'>{H.esc(rep.get('source_file'))} "
                     f"({H.esc(rep.get('format'))}), {H.esc(_source_checksum(rep, 16))}</p>")
        rows = []
        for name, s in streams.items():
            row = {"stream": name, "source": s.get("topic") or s.get("file"), "clock": s.get("clock"),
                   "offset_s": s.get("offset_s"), "messages": s.get("count"), "span_s": s.get("span_s"),
                   "mean_rate_hz": s.get("mean_rate_hz"), "largest_gap_s": s.get("largest_gap_s"),
                   "steps_back": s.get("steps_back")}
            rows.append(row)
            rows_rates.append({"trial": trial, **row})
        parts.append(H.table(rows))
        png = figures.stream_rates(streams, trial)
        if png:
            figs[f"rates_{trial}"] = png
            parts.append(H.image(png, f"sensor rates and gaps of {trial}"))
        if rep.get("salvage"):
            parts.append("<p class='warn'>salvaged (file cut short)</p>" + H.kv_table(rep["salvage"]))
        if rep.get("failed_topics"):
            parts.append("<p class='warn'>topics that failed to decode</p>" + H.kv_table(rep["failed_topics"]))
        topics = rep.get("topics", {})
        if topics:
            parts.append("<details><summary>all topics read</summary>"
                         + H.table([{"topic": t, **{k: v for k, v in d.items() if not isinstance(v, (dict, list))}}
                                    for t, d in topics.items()]) + "</details>")
    metrics["_trials"] = len(trials)
    plots["ingest_rates"] = [{"trial": r["trial"], "stream": r["stream"], "mean_rate_hz": r["mean_rate_hz"],
                              "largest_gap_s": r["largest_gap_s"]} for r in rows_rates]
    return "".join(parts) or "<p class='muted'>No ingest report found (data/signals/*/ingest_report.json).</p>"


def _quarantine_section(root: Path, metrics: dict[str, Any], failed: list[dict[str, Any]]) -> str:
    """Inputs the ingest stage set aside, and models that failed in a study (the others went on)."""
    quarantine = _read_json(root / layout.SIGNALS / "quarantine.json") or {}
    entries = quarantine.get("quarantined", []) if isinstance(quarantine, dict) else []
    metrics["ingest"] = {"trials": metrics.pop("_trials"), "quarantined": len(entries)}
    if entries:
        out = H.table([{k: e.get(k) for k in ("trial", "file", "error", "reason", "topic", "field")}
                       for e in entries], caption="Quarantined inputs: logs (or topics) the ingest stage set aside")
    else:
        out = "<p>No input was quarantined.</p>"
    if failed:
        out += H.table(failed, caption="Failed models: left out of their study's tables; the other models went on")
    else:
        out += "<p>No model failed.</p>"
    return out


def _signals_section(root: Path, trials: list[str], metrics: dict[str, Any],
                     plots: dict[str, list[dict[str, Any]]], figs: dict[str, bytes]) -> str:
    parts, valid_rows = [], []
    for trial in trials:
        path = layout.synced_path(root, trial)
        if not path.exists():
            continue
        frame = pd.read_parquet(path)
        fractions = figures.validity_fractions(frame)
        for signal, frac in fractions.items():
            valid_rows.append({"trial": trial, "signal": signal, "valid_fraction": round(frac, 6)})
        metrics.setdefault("signals", {})[trial] = {"samples": len(frame),
                                                    "usable_fraction": round(fractions.get("segment", 0.0), 6)}
        parts.append(f"<h3>{H.esc(trial)}</h3>")
        png = figures.signal_validity(frame, trial)
        if png:
            figs[f"signals_{trial}"] = png
            parts.append(H.image(png, f"signals and validity of {trial}"))
        segs = frame["segment"] if "segment" in frame.columns else None
        nseg = int(segs[segs >= 0].nunique()) if segs is not None else 0
        parts.append(H.table([{"signal": signal_label(s) if s != "segment" else "in a usable segment",
                               "valid fraction": f} for s, f in fractions.items()])
                     + f"<p class='muted'>{len(frame)} grid samples, {nseg} usable segment(s)</p>")
    plots["valid_fraction"] = valid_rows
    return "".join(parts) or "<p class='warn'>No synced trial found (data/synced/).</p>"


def _estimation_section(root: Path, trials: list[str], metrics: dict[str, Any], figs: dict[str, bytes]) -> str:
    """Per trial: the noise of each signal, the smoother's process noise and gating, how much became usable,
    and measured vs estimated velocity with the 2-sigma band (the differentiate stage's report and table)."""
    parts = []
    for trial in trials:
        rep = _read_json(layout.estimation_report_path(root, trial)) if layout.estimation_report_path(
            root, trial).exists() else None
        if not rep:
            continue
        metrics.setdefault("estimation", {})[trial] = {
            "usable_fraction": round(float(rep.get("usable_fraction", 0.0)), 6),
            "synced_segment_fraction": round(float(rep.get("synced_segment_fraction", 0.0)), 6)}
        parts.append(f"<h3>{H.esc(trial)}</h3>")
        parts.append(H.kv_table({
            "method": rep.get("method"),
            "usable fraction of the grid": rep.get("usable_fraction"),
            "fraction in sync's segments (without bridging)": rep.get("synced_segment_fraction"),
            "segments": rep.get("segments")}))
        noise = [{"signal": name, "noise SD": v.get("sd"), "outlier rate": v.get("outlier_rate"),
                  "residuals": v.get("samples"), "source": v.get("source")}
                 for name, v in sorted(rep.get("noise", {}).items())]
        if noise:
            parts.append(H.table(noise, caption="Noise per signal (in the signal's unit)"))
        dofs = [{"DOF": d, "process noise q": v.get("process_noise"), "chosen by": v.get("process_noise_source"),
                 "measurements": v.get("measurements"), "rejected (gate)": v.get("gated"),
                 "median velocity SD": v.get("median_velocity_sd"),
                 "median acceleration SD": v.get("median_acceleration_sd")}
                for d, v in rep.get("dofs", {}).items()]
        if dofs:
            parts.append(H.table(dofs, caption="Kalman/RTS smoother per degree of freedom"))
        parts.extend(_model_tables(rep))
        if rep.get("widths_s"):
            parts.append(H.kv_table(rep["widths_s"], key="velocity", value="filter width [s]"))
        kin_path = layout.kinematics_path(root, trial)
        if kin_path.exists():
            png = figures.estimated_velocities(pd.read_parquet(kin_path), trial)
            if png:
                figs[f"estimation_{trial}"] = png
                parts.append(H.image(png, f"measured vs estimated velocity of {trial}"))
    return "".join(parts) or "<p class='muted'>No estimation report found (data/kinematics/*.estimation.json).</p>"


def _model_tables(rep: dict[str, Any]) -> list[str]:
    """The smoother's passes with the vehicle's model (log-likelihood per DOF, the one each DOF kept), the sensor
    errors estimated from the trial, and how much of the thrust-driven acceleration the velocity sensor resolves."""
    parts = []
    model = rep.get("model") or {}
    chosen = model.get("chosen_pass", {})
    passes = [{"pass": p.get("pass"), "model": p.get("model"),
               **{f"log-likelihood {d}" + (" (kept)" if chosen.get(d) == p.get("pass") else ""): v
                  for d, v in p.get("loglik", {}).items()}}
              for p in model.get("passes", [])]
    if len(passes) > 1:
        parts.append(H.table(passes, caption="Smoother passes: 0 is the kinematic smoother, then the vehicle's "
                                             "model as its input; each DOF keeps the pass marked (kept)"))
    errors = [{"sensor error": f"{v.get('signal', d)} bias", "estimate": v.get("bias_radps"),
               "SD": v.get("sd_radps"), "unit": "rad/s", "subtracted": v.get("subtracted", v.get("identifiable")),
               "note": v.get("reason", "")}
              for d, v in sorted((rep.get("rate_bias") or {}).items())]
    errors += [{"sensor error": f"accelerometer bias {d}", "estimate": v, "SD": None, "unit": "m/s^2",
                "subtracted": True, "note": ""}
               for d, v in sorted(((rep.get("accelerometer") or {}).get("bias_mps2") or {}).items())]
    mis = rep.get("velocity_misalignment")
    if mis:
        errors.append({"sensor error": "velocity sensor yaw misalignment (trial alone)",
                       "estimate": mis.get("estimate_deg"), "SD": mis.get("sd_deg"), "unit": "deg",
                       "subtracted": False, "note": mis.get("reason") or ""})
        errors.append({"sensor error": "velocity sensor yaw misalignment (with the mount's prior)",
                       "estimate": mis.get("posterior_deg"), "SD": mis.get("posterior_sd_deg"), "unit": "deg",
                       "subtracted": mis.get("applied"), "note": "undone" if mis.get("applied") else
                       "kept as configured; its error widens u's and v's bands"})
    clock = rep.get("actuator_clock_offset")
    if clock:
        errors.append({"sensor error": "actuator clock offset (trial alone)", "estimate": clock.get("estimate_s"),
                       "SD": clock.get("sd_s"), "unit": "s", "subtracted": False, "note": clock.get("reason") or ""})
        errors.append({"sensor error": "actuator clock offset (with the configured offset's prior)",
                       "estimate": clock.get("posterior_s"), "SD": clock.get("posterior_sd_s"), "unit": "s",
                       "subtracted": clock.get("applied"), "note": "thrust read that much later" if
                       clock.get("applied") else "kept as configured"})
    if errors:
        parts.append(H.table(errors, caption="Sensor errors estimated from the trial"))
    excitation = [{"DOF": d, "band the velocity sensor resolves [Hz]": v.get("resolved_band_hz"),
                   "share of the thrust's acceleration power above it": v.get("power_above_band")}
                  for d, v in (rep.get("excitation") or {}).items()]
    if excitation:
        parts.append(H.table(excitation, caption="Excitation against the velocity sensor: a large share above "
                                                 "the band means the trial outruns its sensor, and the targets "
                                                 "lean on the vehicle's model there"))
    return parts


def _collect_metrics(root: Path, base: str, metrics: dict[str, Any]) -> None:
    """metrics.json goes by the files a stage calls metrics (metrics*.json / summary*.json); failing those, every
    JSON but timings. Per-fold scores and search traces stay in the report's tables."""
    directory = root / base
    if not directory.is_dir():
        return
    jsons = sorted(p.name for p in directory.rglob("*.json"))
    metric_files = {n for n in jsons if n.startswith(("metrics", "summary"))} or \
        {n for n in jsons if "timing" not in n and "fold" not in n and "trace" not in n}
    for path in sorted(directory.rglob("*.json")):
        if path.name not in metric_files:
            continue
        doc = _read_json(path)
        found: dict[str, float] = {}
        _flatten_numbers(doc, "", found)
        if found:
            rel = path.relative_to(directory).as_posix()
            metrics[f"{base.split('/')[-1]}/{rel[: -len('.json')]}"] = dict(list(found.items())[:MAX_METRICS_PER_FILE])


def _artifact_section(root: Path, base: str, figs: dict[str, bytes], used: set[str] = frozenset()) -> str:
    """The files of ``base`` no study renderer used: PNGs, Markdown tables, JSON (as tables, when it has no
    Markdown twin of the same name), CSV heads; each once, JSON also as a download link."""
    directory = root / base
    if not directory.is_dir():
        return f"<p class='warn'>Nothing under {H.esc(base)}/ (stage not run?).</p>"
    parts = []
    order = {".md": 0, ".png": 1, ".json": 2, ".csv": 3}
    files = sorted((p for p in directory.rglob("*") if p.is_file() and not p.name.startswith(".")
                    and p.relative_to(root).as_posix() not in used),
                   key=lambda p: (p.relative_to(directory).parent.as_posix(), order.get(p.suffix.lower(), 9), p.name))
    for path in files:
        rel = path.relative_to(directory).as_posix()
        href = "../" + path.relative_to(root).as_posix()
        suffix = path.suffix.lower()
        if suffix == ".png":
            data = path.read_bytes()
            figs[f"{base.split('/')[-1]}_{rel}"] = data
            parts.append(f"<h4>{H.esc(rel)}</h4>" + H.image(data, rel))
        elif suffix == ".json":
            twin = path.with_suffix(".md")
            if twin.is_file() and H.markdown_tables(twin.read_text(encoding="utf-8", errors="replace")):
                continue  # shown as its Markdown table; the JSON is linked there
            doc = _read_json(path)
            if doc is not None:
                parts.append(f"<h4>{H.esc(rel)}</h4>" + "".join(H.json_tables(doc)) + H.links([(href, path.name)]))
        elif suffix == ".md":
            tables = H.markdown_tables(path.read_text(encoding="utf-8", errors="replace"))
            twin = path.with_suffix(".json")
            if tables:
                parts.append(f"<h4>{H.esc(rel)}</h4>" + "".join(tables) + (
                    H.links([("../" + twin.relative_to(root).as_posix(), twin.name)]) if twin.is_file() else ""))
        elif suffix == ".csv":
            try:
                frame = pd.read_csv(path, nrows=MAX_CSV_ROWS)
            except (ValueError, OSError):
                continue
            parts.append(f"<h4>{H.esc(rel)} <span class='muted'>(first {MAX_CSV_ROWS} rows)</span></h4>"
                         + H.table(frame.to_dict("records")) + H.links([(href, path.name)]))
    return "".join(parts)


def _source_checksum(rep: dict[str, Any], digits: int | None = None) -> str:
    """The raw log's sha256 from its ingest report (the first ``digits``), or why there is none."""
    sha = rep.get("source_sha256")
    if sha is None:
        return ("no checksum (ingested with ingest.checksum: none)" if rep.get("checksum") == "none"
                else "no checksum recorded")
    return f"sha256 {sha[:digits]}…" if digits else str(sha)


def _provenance_section(root: Path, vehicle: Vehicle, params: Params, trials: list[str]) -> str:
    inputs = []
    for trial in trials:
        rep = _read_json(layout.ingest_report_path(root, trial)) or {}
        if rep:
            inputs.append({"trial": trial, "file": rep.get("source_file"), "sha256": _source_checksum(rep)})
    info = {"auvid version": __version__, "vehicle": vehicle.name, "vehicle config hash": config_hash(vehicle),
            "params hash": config_hash(params)}
    return (H.kv_table(info) + "<h3>Inputs</h3>" + H.table(inputs, ["trial", "file", "sha256"])
            + "<h3>Params</h3><details><summary>every parameter of the run</summary>"
            + H.kv_table(_flat_params(params.model_dump(mode="json")), key="parameter") + "</details>")


def _flat_params(obj: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in sorted(obj.items()) if isinstance(obj, dict) else []:
        if isinstance(v, dict) and v:
            out.update(_flat_params(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def _evidence(root: Path, trials: list[str], metrics: dict[str, Any]) -> summary.Evidence:
    """The size of the evidence: synced trials, their minutes, the usable share (the smoother's, or sync's
    segments), weighted by grid samples; the unseen trials as the tune stage recorded them."""
    minutes, weighted, samples = 0.0, 0.0, 0
    for trial in trials:
        path = layout.synced_path(root, trial)
        if not path.exists():
            continue
        t_ns = pd.read_parquet(path, columns=["t_ns"])["t_ns"].to_numpy()
        if len(t_ns) > 1:
            minutes += (int(t_ns[-1]) - int(t_ns[0])) / 60e9
        sig = metrics.get("signals", {}).get(trial, {})
        est = metrics.get("estimation", {}).get(trial, {})
        usable = est.get("usable_fraction", sig.get("usable_fraction"))
        if usable is not None:
            weighted += usable * len(t_ns)
            samples += len(t_ns)
    doc, _ = coverage.read(root)
    return summary.Evidence(trials=len(metrics.get("signals", {})), minutes=minutes,
                            usable=weighted / samples if samples else None,
                            test_trials=list((doc or {}).get("test_trials") or sorted(freeruns.simulation_doc(root))))


def build(root: str | Path, vehicle: Vehicle, params: Params) -> Report:
    """The report of the run in ``root``: HTML, metrics (for ``dvc metrics``), plot data, figures."""
    root = Path(root)
    trials = _trials(root)
    metrics: dict[str, Any] = {"package_version": __version__}
    plots: dict[str, list[dict[str, Any]]] = {}
    figs: dict[str, bytes] = {}
    bases = {"coupled": studies.COUPLED, "decoupled": studies.DECOUPLED, "simulation": layout.SIMULATION}
    other = root / layout.EVALUATION
    extra = sorted(p.name for p in other.iterdir() if p.is_dir() and p.name not in ("coupled", "decoupled")) \
        if other.is_dir() else []
    for base in [*bases.values(), *(f"{layout.EVALUATION}/{n}" for n in extra)]:
        _collect_metrics(root, base, metrics)
    ingest = _ingest_section(root, trials, metrics, plots, figs)
    signals = _signals_section(root, trials, metrics, plots, figs)
    estimation = _estimation_section(root, trials, metrics, figs) + spectra.section(root, trials, metrics)
    marks = verdicts.simulation_marks(freeruns.simulation_doc(root))
    parts = {"coupled": studies.coupled(root, figs, marks), "decoupled": studies.decoupled(root, figs, marks),
             "simulation": freeruns.section(root, figs, marks)}
    failed = parts["coupled"].failed + parts["decoupled"].failed
    quarantine = _quarantine_section(root, metrics, failed)
    extrapolation, extrapolation_note, used = coverage.section(root)
    parts["coupled"].used |= used
    bodies = {}
    for name, base in bases.items():
        rest = _artifact_section(root, base, figs, parts[name].used)
        if parts[name].html and rest and not rest.startswith("<p class='warn'>"):
            rest = "<h3>Other files</h3>" + rest
        bodies[name] = (parts[name].html + rest) if parts[name].html else (
            rest or f"<p class='muted'>No readable file under {H.esc(base)}/.</p>")
    sections = [
        ("summary", "Summary", extrapolation_note + summary.headline(
            parts["coupled"], parts["decoupled"], parts["simulation"], metrics["ingest"]["quarantined"], len(failed),
            parts["coupled"].protocol, _evidence(root, trials, metrics)) + compare.section(root)),
        ("quarantine", "Quarantine and failures", quarantine),
        ("ingest", "Ingest and sensor rates", ingest),
        ("signals", "Signals and validity", signals),
        ("estimation", "Motion estimation: noise, smoother, usable data", estimation),
        ("extrapolation", "Extrapolation and excitation: test trials against the training data", extrapolation),
        ("coupled", "Coupled models, paper 000: Tables II and III, Fig. 4", bodies["coupled"]),
        ("decoupled", "Damping study, paper 001: Table I, learning curves, damping curves", bodies["decoupled"]),
        ("simulation", "Free runs and DVL-outage bridging", bodies["simulation"]),
    ]
    for sub in extra:
        sections.append((sub, f"Evaluation: {sub}", _artifact_section(root, f"{layout.EVALUATION}/{sub}", figs)
                         or f"<p class='muted'>No readable file under {H.esc(sub)}/.</p>"))
    sections.append(("provenance", "Provenance", _provenance_section(root, vehicle, params, trials)))
    plots.update(model_plots(root))  # for `dvc plots`: every name always, empty where its stage did not run
    text = H.page(f"auvid report: {vehicle.name}", sections,
                  subtitle=f"auvid {__version__} · config {config_hash(vehicle)[:12]} · params "
                           f"{config_hash(params)[:12]}")
    return Report(html=text, metrics=metrics, plots=plots, figures=figs)
