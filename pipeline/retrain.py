"""Scheduled retraining: ingest new logs, rebuild, retrain, promote only if better. Idempotent, cron-safe.

One run of :func:`retrain`:

1. takes an exclusive, non-blocking ``fcntl.flock`` on ``ROOT/.retrain.lock``; if another run holds it, returns
   at once (status ``locked``; the CLI exits 0 with a message);
2. removes what a crashed run left (``staging/*``, stores the registry does not name);
3. hashes every log in the inbox (content sha256); logs already in the registry's ``seen_logs`` are skipped;
   symbolic links (and bag directories holding one) are never followed, logs whose name gives no safe trial id
   are not copied: logged and quarantined, left in the inbox;
   no new log and a current model: status ``nothing_new``, nothing is touched;
4. builds the candidate in ``staging/<version>/run``: a hard-linked copy of the current store's raw logs and
   per-trial tables (every stage writes by atomic replace, so the store's files are never modified through the
   links; when the vehicle or params changed since the store was built, the per-trial tables are recomputed),
   the new logs copied into ``data/raw``, then the DAG (ingest of the new logs only, per-trial stages for the
   trials without output, features, tune, train, decoupled, simulate, report), with the current version's
   scores in ``data/evaluation/baseline.json`` so that its report compares the two model by model;
5. scores the candidate on the FIXED holdout (chosen at the first run, recorded in the registry with the
   hashes of its logs; every candidate gets it as ``features.test_trials``), compares with the current model's
   score on the same holdout, promotes only if strictly better;
6. commits: renames the staging run to ``stores/<version>``, copies its models/evaluation/report to
   ``models/<version>``, then writes the registry atomically (the one commit point) and repoints
   ``current``. A crash before the registry write leaves the old registry, store and model in force.
"""

from __future__ import annotations

import logging
import os
import shutil
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from pipeline import __version__, layout, registry
from pipeline.config import Params, config_hash, load_params, load_vehicle, measured_dofs, parse
from pipeline.config.checks import SAFE_NAME, SAFE_NAME_RULE
from pipeline.errors import PipelineError
from pipeline.registry import LOCK_FILE, LockBusy, exclusive_lock
from pipeline.report import compare
from pipeline.tableio import file_sha256

log = logging.getLogger(__name__)

_PARTIAL = (".part", ".tmp", ".partial", ".crdownload", ".lock")
_LINKED = (layout.RAW, layout.SIGNALS, layout.SYNCED, layout.KINEMATICS, layout.DERIVED)
_ARTIFACTS = (layout.MODELS, layout.EVALUATION, layout.SIMULATION, layout.REPORTS, "params.yaml")

Scorer = Callable[[Path, list[str]], dict[str, Any]]


@dataclass
class RetrainOptions:
    root: Path
    inbox: Path
    vehicle_path: Path
    params_path: Path | None = None
    progress_factory: Callable[[str], Any] | None = None
    on_stage: Callable[[str, Any, float], None] | None = None
    scorer: Scorer | None = None  # default: holdout_score
    metric: str = "holdout_r2"
    mode: str = "max"  # "max": higher is better; "min": lower is better
    min_improvement: float = 0.0


@dataclass
class RetrainOutcome:
    status: str  # locked | nothing_new | no_data | promoted | rejected
    message: str
    version: str | None = None
    quarantined: list[dict[str, Any]] = field(default_factory=list)
    metrics: dict[str, Any] = field(default_factory=dict)


# --------------------------------------------------------------------------------------------- inbox, copies

def inbox_logs(inbox: Path, skipped: list[dict[str, Any]] | None = None) -> list[Path]:
    """Logs in the inbox: files and bag/CSV directories, hidden and partial files left out, in name order.

    Symbolic links are never followed (docs/security.md): a link in the inbox, or a bag directory holding one,
    could make the run copy any file the cron user can read (``/etc/shadow``, another user's data) into the
    store. A log whose name gives no safe trial id (``trial 01.mcap``) is refused here too: copied into the
    store, ingest would quarantine it on every later rebuild. Each is logged and, when ``skipped`` is given,
    appended to it as a quarantine entry; the inbox file is left as it is.
    """
    from pipeline.ingest import trial_id

    if not inbox.is_dir():
        raise PipelineError("inbox is not a directory", file=inbox)
    logs = []
    for p in sorted(inbox.iterdir()):
        if p.name.startswith(".") or p.name.endswith(_PARTIAL) or p.name.endswith(".dvc"):
            continue
        if not SAFE_NAME.match(trial := trial_id(p)):
            reason = (f"its name gives trial id {trial!r}, not a safe name ({SAFE_NAME_RULE}); "
                      "not copied: rename the log in the inbox")
        elif p.is_symlink():
            reason = "a symbolic link in the inbox; not followed (copy the log itself into the inbox)"
        elif p.is_dir() and any(q.is_symlink() for q in p.rglob("*")):
            reason = "a log directory holding a symbolic link; not followed (copy the files themselves)"
        elif not (p.is_file() or p.is_dir()):
            reason = "not a regular file or directory (a FIFO, socket or device); skipped"
        else:
            logs.append(p)
            continue
        log.warning("inbox: %s is %s", p, reason)
        if skipped is not None:
            skipped.append({"file": str(p), "stage": "retrain", "reason": reason})
    return logs


def _link_tree(src: Path, dst: Path) -> None:
    def link(s: str, d: str) -> None:
        try:
            os.link(s, d)
        except OSError:
            shutil.copy2(s, d)

    shutil.copytree(src, dst, copy_function=link, dirs_exist_ok=True)


def _copy_log(src: Path, raw: Path, sha: str) -> Path:
    target = raw / src.name
    if target.exists():  # same name, other content: keep both
        stem, dot, suffix = src.name.partition(".")
        target = raw / f"{stem}-{sha[:8]}{dot}{suffix}"
    tmp = raw / f".{target.name}.incoming"
    if src.is_dir():
        shutil.copytree(src, tmp, symlinks=True)  # never follow a link (inbox_logs refused them already)
    else:
        shutil.copy2(src, tmp, follow_symlinks=False)
    os.replace(tmp, target)
    return target


# ----------------------------------------------------------------------------------------------- scoring

def _numeric_leaves(obj: Any, path: tuple[str, ...] = ()) -> Iterator[tuple[tuple[str, ...], float]]:
    if isinstance(obj, dict):
        for key, value in obj.items():
            yield from _numeric_leaves(value, (*path, str(key).lower()))
    elif isinstance(obj, (int, float)) and not isinstance(obj, bool):
        yield path, float(obj)


def _mean(values: list[float]) -> float | None:
    import math

    values = [v for v in values if v is not None and math.isfinite(v)]
    return sum(values) / len(values) if values else None


def holdout_score(run_root: Path, holdout: list[str]) -> dict[str, Any]:
    """Score of a built run on the holdout: the coupled model that the blocked CV ranks best (mean CV test R²
    over the outputs) and its mean R² on the final check, i.e. on the holdout trial(s) no stage has seen.

    Reads ``data/evaluation/coupled/metrics.json`` (``{model: {output: {cv_test_r2, final_r2}}}``, written by
    the train stage). Without a holdout (``final_r2`` null) the CV score stands in. Other layouts: the mean of
    every ``*r2*`` leaf under a ``test``/``holdout``/``final`` key in ``data/evaluation/**.json``.
    """
    import json

    path = run_root / layout.EVALUATION / "coupled" / "metrics.json"
    if path.exists():
        doc = json.loads(path.read_text())
        ranked = []
        for model, outputs in sorted(doc.items()):
            if not isinstance(outputs, dict):
                continue
            cv = _mean([o.get("cv_test_r2") for o in outputs.values() if isinstance(o, dict)])
            final = _mean([o.get("final_r2") for o in outputs.values() if isinstance(o, dict)])
            if cv is not None:
                ranked.append((cv, model, final))
        if ranked:
            cv, model, final = max(ranked)
            return {"holdout_r2": final if final is not None else cv, "cv_test_r2": cv, "model": model,
                    "scored_on": "holdout" if final is not None else "cv"}
    values = []
    for json_path in sorted((run_root / layout.EVALUATION).rglob("*.json")):
        try:
            doc = json.loads(json_path.read_text())
        except (OSError, ValueError):
            continue
        for keys, value in _numeric_leaves(doc):
            last = keys[-1] if keys else ""
            if "r2" in last and not any(w in last for w in ("train", "sd", "std")) \
                    and any(w in k for k in keys for w in ("test", "holdout", "final")):
                values.append(value)
    score = _mean(values)
    if score is None:
        raise PipelineError("no holdout R² found under data/evaluation", file=run_root)
    return {"holdout_r2": score, "scored_on": "generic"}


# -------------------------------------------------------------------------------------------------- the run

def _cleanup(root: Path, data: dict[str, Any]) -> None:
    staging = root / "staging"
    if staging.exists():
        shutil.rmtree(staging, ignore_errors=True)
    keep = data.get("store")
    stores = root / "stores"
    if stores.is_dir():
        for item in stores.iterdir():
            if f"stores/{item.name}" != keep:
                log.info("removing unreferenced store %s (left by an interrupted run)", item)
                shutil.rmtree(item, ignore_errors=True)


def _params_with_holdout(params: Params, holdout: list[str]) -> Params:
    doc = params.model_dump(mode="json")
    doc["features"]["test_trials"] = list(holdout)
    return parse(Params, doc, "retrain params")


def _better(score: float, best: float | None, mode: str, margin: float) -> bool:
    if best is None:
        return True
    return score > best + margin if mode == "max" else score < best - margin


def retrain(options: RetrainOptions) -> RetrainOutcome:
    """One idempotent retraining run (see the module docstring)."""
    root = Path(options.root)
    try:
        with exclusive_lock(root):
            return _retrain_locked(options, root)
    except LockBusy:
        return RetrainOutcome("locked", f"another retrain holds {root / LOCK_FILE}; nothing done")


def _retrain_locked(options: RetrainOptions, root: Path) -> RetrainOutcome:
    from pipeline.ingest import trial_id
    from stages import common

    data = registry.load(root)
    _cleanup(root, data)
    vehicle = load_vehicle(options.vehicle_path)
    params_path = options.params_path or (root / "params.yaml" if (root / "params.yaml").exists() else None)
    params = measured_dofs(vehicle, load_params(params_path), params_path)

    skipped: list[dict[str, Any]] = []
    hashes = {p: file_sha256(p) for p in inbox_logs(options.inbox, skipped)}
    new = {p: h for p, h in hashes.items() if h not in data["seen_logs"]}
    new = {p: h for p, h in new.items() if h not in list(new.values())[: list(new).index(p)]}  # dup content once
    if not new:
        if data["current"]:
            return RetrainOutcome("nothing_new", f"no new logs in {options.inbox}; current model "
                                                 f"{data['current']} stays", quarantined=skipped)
        if not data["store"]:
            return RetrainOutcome("no_data", f"no logs in {options.inbox} and no model yet", quarantined=skipped)

    name = registry.next_version(data)
    staging = root / "staging" / name
    work = staging / "run"
    work.mkdir(parents=True)
    store = root / data["store"] if data["store"] else None
    vhash, phash = config_hash(vehicle), config_hash(params)
    prev = registry.version(data, data["store"].split("/")[-1]) if data["store"] else None
    same_config = bool(prev) and prev["lineage"].get("vehicle_hash") == vhash \
        and prev["lineage"].get("params_hash") == phash
    if store is not None:
        for sub in _LINKED if same_config else (layout.RAW,):
            if (store / sub).is_dir():
                _link_tree(store / sub, work / sub)
    raw = work / layout.RAW
    raw.mkdir(parents=True, exist_ok=True)
    new_raw = {_copy_log(p, raw, h): h for p, h in new.items()}

    # The fixed holdout: chosen once, from the first data, recorded with its logs' hashes.
    if data["holdout"] is None:
        trials = sorted(trial_id(p) for p in raw.iterdir() if not p.name.startswith("."))
        chosen = list(params.features.test_trials) or (trials[-1:] if len(trials) >= 2 else [])
        logs_by_trial = {trial_id(p): h for p, h in new_raw.items()}
        data["holdout"] = {"trials": chosen, "logs": {t: logs_by_trial.get(t) for t in chosen},
                           "metric": options.metric, "mode": options.mode}
    holdout = list(data["holdout"]["trials"])
    params = _params_with_holdout(params, holdout)
    (work / "params.yaml").write_text(yaml.safe_dump(params.model_dump(mode="json"), sort_keys=False))
    if data["current"] and (root / "models" / data["current"]).is_dir():  # the report compares, model by model
        compare.write_baseline(work, root / "models" / data["current"], data["current"])

    # Build: ingest only what is new (all raw if the config changed), per-trial work only where missing.
    ingest_logs = sorted(new_raw) if same_config else sorted(p for p in raw.iterdir() if not p.name.startswith("."))
    results = []
    for stage in common.STAGE_ORDER:
        kwargs: dict[str, Any] = {}
        if stage == "ingest":
            if not ingest_logs:
                continue
            kwargs["logs"] = ingest_logs
        elif stage in common.PER_TRIAL:
            kwargs["trials"] = [t for t in common.trials_for(stage, work)
                                if not common.trial_output(stage, work, t).exists()]
        if options.on_stage:
            options.on_stage(stage, None, 0.0)
        start = time.perf_counter()
        results.append(common.run_stage(stage, work, vehicle, params, progress=_progress(options, stage), **kwargs))
        if options.on_stage:
            options.on_stage(stage, results[-1], time.perf_counter() - start)
    quarantined = skipped + [q for r in results for q in r.quarantined]

    scorer = options.scorer or holdout_score
    metrics = scorer(work, holdout)
    score = metrics[options.metric]
    best = registry.current(data)
    best_score = best["holdout_score"] if best else None
    promote = _better(score, best_score, options.mode, options.min_improvement)
    if best is None:
        reason = "first model"
    else:
        verb = "beats" if promote else "does not beat"
        reason = f"{options.metric} {score:.4g} {verb} current {best['version']} ({best_score:.4g}) on the holdout"

    # Commit: everything lands beside the old state, then one atomic registry write switches over.
    models_dir = root / "models" / name
    tmp_models = staging / "models"
    for sub in _ARTIFACTS:
        src = work / sub
        if src.is_dir():
            shutil.copytree(src, tmp_models / sub)
        elif src.is_file():
            tmp_models.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, tmp_models / sub)
    tmp_models.mkdir(parents=True, exist_ok=True)
    (root / "models").mkdir(exist_ok=True)
    (root / "stores").mkdir(exist_ok=True)
    if models_dir.exists():  # left by a crash after this step, before the registry write
        shutil.rmtree(models_dir)
    os.replace(tmp_models, models_dir)
    os.replace(work, root / "stores" / name)

    now = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
    trials_now = sorted({trial_id(p) for p in (root / "stores" / name / layout.RAW).iterdir()
                         if not p.name.startswith(".")})
    entry = {
        "version": name, "created_at": now, "status": "promoted" if promote else "rejected", "reason": reason,
        "metrics": metrics, "holdout_score": score, "parent": data["current"],
        "lineage": {"new_logs": [{"name": p.name, "sha256": h} for p, h in sorted(new_raw.items())],
                    "trials": trials_now, "holdout": holdout, "vehicle_hash": vhash, "params_hash": phash,
                    "package_version": __version__, "quarantined": quarantined},
    }
    old_store = data["store"]
    data = {**data, "versions": [*data["versions"], entry], "store": f"stores/{name}",
            "current": name if promote else data["current"]}
    for p, h in new_raw.items():
        data["seen_logs"][h] = {"name": p.name, "trial": trial_id(p), "version": name, "seen_at": now}
    registry.save(root, data)  # <- the commit point
    if promote:
        registry.point_current(root, name)
    if old_store and (root / old_store).exists():
        shutil.rmtree(root / old_store, ignore_errors=True)
    shutil.rmtree(root / "staging", ignore_errors=True)
    status = "promoted" if promote else "rejected"
    log.info("retrain %s: %s (%s)", name, status, reason)
    return RetrainOutcome(status, f"{name} {status}: {reason}; {len(new_raw)} new log(s)", version=name,
                          quarantined=quarantined, metrics=metrics)


def _progress(options: RetrainOptions, stage: str) -> Any:
    return options.progress_factory(stage) if options.progress_factory else None
